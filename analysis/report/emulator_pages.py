"""The page of the emulator check (:mod:`analysis.studies.emulator_check`)."""
from __future__ import annotations

from analysis.report.markdown import frame_table_lines


def emulator_check_page(leave_out, modes, heldout, *, n_runs, n_points, replicates, folds,
                        dataset, heldout_dir, fake=False, n_planned=None):
    """README.md of the study folder."""
    lines = ["# The loop's model of the twin against real twin runs", ""]
    if fake:
        lines += ["**FAKE: made by the analytic stand-in (`--fake`), not the twin.**", ""]
    lines += [
        "Made by `python -m analysis.studies.emulator_check` (`make emulator-check`): wave 0 of "
        "the design (a Latin hypercube over restitution, stroke and both frictions; half of its "
        "%d points with one DEM candidate effect on at a strength drawn from its range) at the "
        "conditions of `%s`, one seed per point and condition, plus the reference point with "
        "%d seeds: %d twin runs%s. The model is the loop's (`analysis.emulated_twin."
        "EmulatedTwin`): one GP per observable and motion mode, a Gaussian-process classifier "
        "of the mode; a new run's value is their mixture." % (
            n_points, dataset, replicates, n_runs,
            "" if not n_planned or n_planned == n_runs else
            " (of the %d planned: the study was analysed as far as it got, `--cached-only`)"
            % n_planned), "",
        "## Leave-out of whole design points", "",
        "%d folds of design points (every run of a point in one fold), the model refitted "
        "without each. The 95 %% interval is the mixture's of a new twin run (each mode's "
        "emulator + chaos, weighted by the classifier): covered when its CDF at the run (the "
        "PIT) lies in [0.025, 0.975]; z = Phi^-1(PIT), `mean_z2` 1 when the stated uncertainty "
        "is right. `one GP`: the same runs fitted without their modes (one GP across them)."
        % folds, ""]
    lines += frame_table_lines(leave_out, [c for c in ("model", "observable", "n", "rmse",
                                                       "coverage95", "mean_z2")
                                           if c in leave_out.columns])
    lines += ["", "The classifier on the runs left out (`modes.csv`): per motion mode, its mean "
              "p of the run's own mode and the share of runs it gives p > 0.5.", ""]
    lines += frame_table_lines(modes, list(modes.columns))
    if heldout is not None:
        lines += ["", "## Twin runs the study never made", "",
                  "The runs of `%s/model_runs.csv` that the study's design does not hold (its "
                  "waves, focus points and reruns), predicted one by one by the model fitted "
                  "to every study run." % heldout_dir, ""]
        lines += frame_table_lines(heldout, ["observable", "n", "rmse", "coverage95",
                                             "mean_z2"])
    lines += ["", "![left-out runs](emulator_check.png)"]
    return "\n".join(lines) + "\n"
