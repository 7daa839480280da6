"""Does the one emulator of the twin predict real twin runs, with an uncertainty that covers them?

Wave 0 of the design (:func:`analysis.history_matching.initial_design`: a Latin hypercube over
the base parameters' priors, half of its points with one candidate effect switched on at a
strength drawn from its range) is run at a dataset's conditions, one seed per point and
condition (the same seed across conditions), plus the reference point with ``--replicates``
seeds (the twin's chaos per condition). One GP emulator per observable
(:class:`analysis.emulator.GPEmulator`: inputs the base parameters, the effects' strengths and
the conditions' frequency and ball; the chaos pooled per condition from the replicates) is fitted
to every run and checked

* by leave-out of whole design points (all conditions of a point left out together): the RMSE,
  the coverage of the 95 % interval of a new run and its mean z^2 (1 when the stated
  uncertainty is right);
* on twin runs it never saw: the runs the loop committed for the same dataset
  (``model_runs.csv`` of ``--heldout``: its anchor, its one-at-a-time base responses and
  effect levels), predicted one by one.

Writes ``--out`` (default ``results/studies/emulator_check/``): ``design_runs.csv`` (every run:
point, condition, seed, run id, inputs, observables), ``leave_out.csv`` and ``heldout.csv``
(per observable: n, rmse, coverage95, mean_z2), ``heldout_runs.csv`` (per held-out run: twin,
prediction, sd, z), ``emulator_check.png``, ``README.md``. Twin runs are cached by run id
(``results/runs/``): a killed study resumes.

Example::

    python -m analysis.studies.emulator_check --points 40 --workers 2
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from analysis.config import RESULTS_DIR
from analysis.emulated_twin import REFERENCE_SEED0
from analysis.emulator import GPEmulator
from analysis.history_matching import (DesignSpace, design_runs, effect_input,
                                       initial_design)

#: observables checked: the speed in both frames, the collision rate, the impact observables
OBSERVABLES = ("v_mean_m_s", "v_mean_jar_m_s", "f_col_hz", "e_app", "v_in_m_s",
               "impact_phase_rad", "jar_amplitude_m", "vy_rms_m_s")
#: observables emulated in log space (relative changes that multiply)
LOG_OBSERVABLES = ("vy_rms_m_s",)
#: the conditions' inputs of the emulator
CONDITION_INPUTS = ("frequency_hz", "ball_diameter_m")
DEFAULT_DATASET = RESULTS_DIR / "open_world" / "effects" / "eff_p01"
DEFAULT_OUT = RESULTS_DIR / "studies" / "emulator_check"


def design_space():
    from analysis.loop import DEFAULT_BASE
    from analysis.catalog import CANDIDATES
    return DesignSpace.of(DEFAULT_BASE, tuple(c for c in CANDIDATES if c.kind == "dem"))


def plan(space, conditions, n_points, seed, replicates, base_config=None):
    """The study's runs: wave 0 at one seed per point, the reference point at ``replicates``."""
    from analysis.parameter_space import reference_parameters
    pts = initial_design(space, n_points, seed)
    runs = design_runs(space, pts, conditions, seeds=(seed,), base_config=base_config)
    ref = dict(reference_parameters(), **{n: 0.0 for n in space.effect_names})
    ref_pt = pd.DataFrame([dict(point=-1, **{n: ref[n] for n in space.names})])
    rep = design_runs(space, ref_pt, conditions,
                      seeds=range(REFERENCE_SEED0, REFERENCE_SEED0 + replicates),
                      base_config=base_config)
    # the replicates first (the chaos), then the points alternating between the halves of the
    # design without and with an effect: a study stopped early holds a usable prefix
    half = (n_points + 1) // 2
    order = [k for pair in zip(range(half), range(half, n_points)) for k in pair]
    order += [k for k in range(n_points) if k not in order]
    runs["_order"] = runs["point"].map({p: i for i, p in enumerate(order)})
    runs = runs.sort_values(["_order", "condition_id"], kind="stable").drop(columns="_order")
    return pd.concat([rep, runs], ignore_index=True)


def run_plan(runs, workers, fake=False, cached_only=False):
    """Run (or read cached) every planned config; add run_id and the observables
    (:class:`analysis.twin_runs.TwinRuns`). With ``cached_only`` no run starts: the runs
    already in the cache are read (a study still running elsewhere is analysed as far as it
    got)."""
    from analysis.sweep import prepare_configs
    from analysis.twin_runs import TwinRuns
    twin = (TwinRuns(runner="analysis.fake_twin:run_fake_twin", runs_dir=RESULTS_DIR /
                     "runs_fake", workers=workers) if fake else TwinRuns(workers=workers))
    if cached_only:
        ids = prepare_configs(list(runs["config"]))[1]
        done = np.array([(twin.runs_dir / i / "meta.json").is_file() or i in twin.table.index
                         for i in ids])
        runs = runs[done].reset_index(drop=True)
        if not len(runs):
            raise RuntimeError("no run of the study is in the cache yet")
    return twin(runs)


def training_inputs(runs, space):
    """Emulator inputs of runs: the base parameters as run (from each config, so a stated
    stroke is the one run), the effects' strengths, the conditions' physics."""
    X = pd.DataFrame({n: runs[n].to_numpy(float) for n in space.effect_names})
    for n in space.base_names + list(CONDITION_INPUTS):
        X[n] = [float(c[n]) for c in runs["config"]]
    return X


def emulator_bounds(space, X):
    b = space.bounds()
    for c in CONDITION_INPUTS:
        lo, hi = float(X[c].min()), float(X[c].max())
        pad = 0.05 * (hi - lo) if hi > lo else 0.05 * abs(lo)
        b[c] = (lo - pad, hi + pad)
    return b


def fit_emulators(X, runs, bounds, observables=OBSERVABLES, seed=0):
    """{observable: fitted GPEmulator} on the runs where it is finite."""
    out = {}
    for o in observables:
        ok = np.isfinite(runs[o].to_numpy(float)) if o in runs else np.zeros(len(runs), bool)
        if ok.sum() < len(bounds) + 2:
            continue
        em = GPEmulator(bounds, outputs=(o,), nu=2.5, trend=True,
                        log_outputs=tuple(x for x in LOG_OBSERVABLES if x == o),
                        noise_keys=CONDITION_INPUTS, n_restarts_optimizer=1, random_state=seed)
        out[o] = (em.fit(X[ok], runs.loc[ok, [o]]), np.flatnonzero(ok))
    return out


def heldout_runs(folder, space):
    """The loop's committed runs of a dataset (``model_runs.csv`` + ``loop.json``) as rows with
    the emulator's inputs: the anchor, each base parameter's response levels, each effect's."""
    folder = Path(folder)
    info = json.loads((folder / "loop.json").read_text())
    runs = pd.read_csv(folder / "model_runs.csv")
    cond = {c["condition_id"]: c for c in info["conditions"]}
    anchor = info["anchor"]
    X = []
    for r in runs.itertuples():
        row = {n: float(anchor[n]) for n in space.base_names}
        row.update({n: 0.0 for n in space.effect_names})
        if r.role == "base":
            row[r.name] = float(r.value)
        elif r.role == "effect":
            if effect_input(r.name) not in space.effect_names:
                X.append(None)
                continue
            row[effect_input(r.name)] = float(r.value)
        c = cond[r.condition_id]
        row["frequency_hz"] = float(c["frequency_hz"])
        row["ball_diameter_m"] = float(c["ball_diameter_mm"]) * 1e-3
        X.append(row)
    keep = [x is not None for x in X]
    return pd.DataFrame([x for x in X if x is not None]), runs[keep].reset_index(drop=True)


def check(ems, X_ho, runs_ho, bounds):
    """Per held-out run and observable: twin, prediction, sd of a new run, z."""
    inside = np.all([(X_ho[k] >= lo) & (X_ho[k] <= hi) for k, (lo, hi) in bounds.items()],
                    axis=0)
    rows = []
    for o, (em, _) in ems.items():
        if o not in runs_ho:
            continue
        y = runs_ho[o].to_numpy(float)
        ok = np.isfinite(y) & inside
        if not ok.any():
            continue
        p = em.predict_parts(X_ho[ok])
        m, s = p.mean[:, 0], p.sd(1)[:, 0]
        for i, yi, mi, si in zip(np.flatnonzero(ok), y[ok], m, s):
            rows.append({"observable": o, "row": int(i), "role": runs_ho.loc[i, "role"],
                         "name": runs_ho.loc[i, "name"], "condition_id":
                         runs_ho.loc[i, "condition_id"], "twin": yi, "predicted": mi, "sd": si,
                         "z": (yi - mi) / si})
    return pd.DataFrame(rows)


def summarise(per_run, by=("observable",)):
    """n, rmse, coverage95 and mean z^2 per group of held-out runs."""
    g = per_run.groupby(list(by))
    return pd.DataFrame({"n": g.size(),
                         "rmse": g.apply(lambda d: float(np.sqrt(np.mean((d.twin - d.predicted)
                                                                         ** 2)))),
                         "coverage95": g.apply(lambda d: float(np.mean(np.abs(d.z) <= 1.96))),
                         "mean_z2": g.apply(lambda d: float(np.mean(d.z ** 2)))})


def add_design_options(p):
    """The wave-0 design's options, shared with the loop's (``python -m analysis.loop``: the
    same defaults make the same runs: the second study reads the first's from the cache)."""
    p.add_argument("--points", type=int, default=24, help="wave-0 design points [-] "
                   "(default %(default)s)")
    p.add_argument("--replicates", type=int, default=3, help="seeds of the reference point "
                   "[-] (default %(default)s)")
    p.add_argument("--seed", type=int, default=0, help="design seed [-] (default %(default)s)")
    p.add_argument("--workers", type=int, default=2, help="parallel twin runs [-]")
    p.add_argument("--frame", default="auto", choices=("lab", "jar", "auto"),
                   help="the scene's frame (default %(default)s: the jar frame, 1.7-1.9x "
                        "faster, unless an effect needs the lab's)")
    p.add_argument("--fake", action="store_true", help="the analytic stand-in (FAKE), for tests")


def rel_path(path):
    """A path as the repository sees it (no absolute paths on a committed page)."""
    from analysis.config import REPO_ROOT
    p = Path(path).resolve()
    try:
        return str(p.relative_to(Path(REPO_ROOT).resolve()))
    except ValueError:
        return Path(path).name


def main(argv=None):
    p = argparse.ArgumentParser(prog="python -m analysis.studies.emulator_check",
                                description=__doc__.split("\n\n")[0],
                                epilog="example: python -m analysis.studies.emulator_check "
                                       "--points 24 --workers 2 (or, while it runs, "
                                       "--cached-only to analyse what it has made)")
    p.add_argument("--dataset", default=str(DEFAULT_DATASET), help="dataset whose conditions "
                   "the design runs at (default %(default)s)")
    p.add_argument("--heldout", default=None, help="a loop folder with model_runs.csv at "
                   "the same conditions, whose runs the emulator never saw (default: none)")
    add_design_options(p)
    p.add_argument("--cached-only", action="store_true", help="start no twin run: analyse "
                   "the study's runs already in the cache")
    p.add_argument("--out", default=str(DEFAULT_OUT), help="output folder")
    a = p.parse_args(argv)
    from analysis.atomic_dir import OutputError, check_out_dir, output_dir
    from analysis.measurements import DatasetError, load_dataset
    try:
        if a.points < 2 or a.replicates < 2 or a.workers < 1:
            raise ValueError("--points and --replicates must be >= 2, --workers >= 1")
        ds = load_dataset(a.dataset)
        check_out_dir(a.out, protected=(a.dataset,))
    except (OutputError, DatasetError, ValueError, OSError) as exc:
        print("analysis.studies.emulator_check: error: %s" % exc, file=sys.stderr)
        return 2
    space = design_space()
    base_config = None if a.frame == "lab" else {"frame": a.frame}
    runs = plan(space, ds.conditions, a.points, a.seed, a.replicates, base_config)
    print("emulator check: %d twin runs (%d points + the reference point x %d seeds, %d "
          "conditions)" % (len(runs), a.points, a.replicates, len(ds.conditions)))
    n_planned = len(runs)
    runs = run_plan(runs, a.workers, a.fake, a.cached_only)
    if len(runs) < n_planned:
        print("emulator check: %d of the %d planned runs are in the cache (--cached-only)"
              % (len(runs), n_planned))
    X = training_inputs(runs, space)
    bounds = emulator_bounds(space, X)
    ems = fit_emulators(X, runs, bounds, seed=a.seed)
    lo_rows = []
    for o, (em, idx) in ems.items():
        rep = em.loo_report(groups=runs["point"].to_numpy()[idx]).reset_index()
        lo_rows.append(rep)
    leave_out = pd.concat(lo_rows, ignore_index=True)
    heldout, per_run, by_role, by_effect = None, None, None, None
    if a.heldout and (Path(a.heldout) / "model_runs.csv").is_file():
        X_ho, runs_ho = heldout_runs(a.heldout, space)
        per_run = check(ems, X_ho, runs_ho, bounds)
        heldout = summarise(per_run).reset_index() if len(per_run) else None
        if heldout is not None:
            eff = per_run[per_run["role"] == "effect"]
            by_role = summarise(per_run, ("observable", "role")).reset_index()
            by_effect = summarise(eff, ("name",)).reset_index() if len(eff) else None
    from analysis.plotting.emulator_plots import emulator_check_figure
    from analysis.report.emulator_pages import emulator_check_page
    with output_dir(a.out, protected=(a.dataset,)) as tmp:
        runs.drop(columns=["config"]).to_csv(tmp / "design_runs.csv", index=False)
        leave_out.to_csv(tmp / "leave_out.csv", index=False, float_format="%.5g")
        if heldout is not None:
            heldout.to_csv(tmp / "heldout.csv", index=False, float_format="%.5g")
            per_run.to_csv(tmp / "heldout_runs.csv", index=False, float_format="%.6g")
            by_role.to_csv(tmp / "heldout_by_role.csv", index=False, float_format="%.5g")
        emulator_check_figure(per_run, tmp / "emulator_check.png", fake=a.fake)
        (tmp / "README.md").write_text(emulator_check_page(
            leave_out, heldout, n_runs=len(runs), n_planned=n_planned, n_points=a.points,
            replicates=a.replicates, dataset=rel_path(a.dataset), heldout_dir=rel_path(a.heldout) if a.heldout else None,
            fake=a.fake, by_role=by_role if heldout is not None else None,
            by_effect=by_effect if heldout is not None else None))
    print(leave_out.to_string(index=False))
    if heldout is not None:
        print(heldout.to_string(index=False))
    return 0


if __name__ == "__main__":
    sys.exit(main())
