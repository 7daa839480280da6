"""The page of the emulator check (:mod:`analysis.studies.emulator_check`)."""
from __future__ import annotations

from analysis.report.markdown import frame_table_lines

_COLS = ["output", "n", "rmse", "rel_rmse_pct", "coverage95", "mean_z2"]


def emulator_check_page(leave_out, heldout, *, n_runs, n_points, replicates, dataset,
                        heldout_dir, fake=False, n_planned=None, by_role=None,
                        by_effect=None):
    """README.md of the study folder."""
    lines = ["# The one emulator of the twin against real twin runs", ""]
    if fake:
        lines += ["**FAKE: made by the analytic stand-in (`--fake`), not the twin.**", ""]
    lines += [
        "Made by `python -m analysis.studies.emulator_check` (`make emulator-check`): wave 0 of "
        "the design (a Latin hypercube over restitution, stroke and both frictions; half of its "
        "%d points with one DEM candidate effect on at a strength drawn from its range) at the "
        "conditions of `%s`, one seed per point and condition, plus the reference point with "
        "%d seeds: %d twin runs%s. One GP per observable (inputs: the base parameters, the "
        "effects' strengths, frequency and ball; the chaos pooled per condition from the "
        "replicates)." % (n_points, dataset, replicates, n_runs,
                          "" if not n_planned or n_planned == n_runs else
                          " (of the %d planned: the study was analysed as far as it got, "
                          "`--cached-only`)" % n_planned), "",
        "## Leave-out of whole design points", "",
        "Every run of a point (all its conditions) left out together; the 95 % interval is "
        "that of a new twin run (emulator + chaos). `mean_z2` is 1 when the stated "
        "uncertainty is right.", ""]
    lines += frame_table_lines(leave_out, [c for c in _COLS if c in leave_out.columns])
    if heldout is not None:
        hcols = ["observable", "n", "rmse", "coverage95", "mean_z2"]
        lines += ["", "## Twin runs the emulator never saw", "",
                  "The loop's committed runs at the same conditions (`%s/model_runs.csv`: its "
                  "anchor, one-at-a-time base responses and effect levels), predicted one by "
                  "one." % heldout_dir, ""]
        lines += frame_table_lines(heldout, hcols)
        if by_role is not None:
            lines += ["", "By the loop's role of the run (`anchor`: the loop's start point; "
                      "`base`: one base parameter a step away; `effect`: one effect on at the "
                      "anchor; `heldout_by_role.csv`):", ""]
            lines += frame_table_lines(by_role, ["observable", "role"] + hcols[1:])
        if by_effect is not None:
            lines += ["", "The effect runs by effect (every observable):", ""]
            lines += frame_table_lines(by_effect, ["name"] + hcols[1:])
        lines += ["", "![held-out runs](emulator_check.png)"]
    return "\n".join(lines) + "\n"


