"""Does the loop's one model of the twin predict real twin runs, with an uncertainty that covers them?

Wave 0 of the design (:func:`analysis.history_matching.initial_design`: a Latin hypercube over
the base parameters' priors, half of its points with one candidate effect switched on at a
strength drawn from its range) is run at a dataset's conditions, one seed per point and
condition (the same seed across conditions), plus the reference point with ``--replicates``
seeds (the twin's chaos per condition). The model is the loop's own
(:class:`analysis.emulated_twin.EmulatedTwin`: one GP per observable and motion mode, a
classifier of the mode; a new run's value is their mixture), checked

* by K-fold leave-out of whole design points (all conditions of a point left out together,
  ``--folds`` folds, the model refitted without them): per observable the RMSE of the
  mixture's mean, the coverage of the mixture's 95 % interval of a new run (its CDF at the
  run, the PIT, within [0.025, 0.975]) and the mean z^2 of z = Phi^-1(PIT) (1 when the stated
  uncertainty is right); per motion mode the classifier's mean p of the run's own mode; and
  the same for one GP across the modes (the model fitted without the runs' modes);
* on twin runs it never saw: another loop's ``model_runs.csv`` at the same conditions
  (``--heldout``: its waves, focus points and reruns), predicted one by one by the model fitted
  to every study run.

Writes ``--out`` (default ``results/studies/emulator_check/``): ``design_runs.csv`` (every run:
point, condition, seed, run id, inputs, observables, motion mode), ``leave_out.csv`` and
``heldout.csv`` (per model and observable: n, rmse, coverage95, mean_z2), ``modes.csv`` (per
mode: runs, mean p of the own mode, share classified right), ``heldout_runs.csv`` (per
held-out run and observable: twin, mixture mean, z), ``emulator_check.png``, ``README.md``.
Twin runs are cached by run id (``results/runs/``): a killed study resumes.

Example::

    python -m analysis.studies.emulator_check --points 24 --workers 2
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import pandas as pd
from tqdm.auto import tqdm

from analysis.config import RESULTS_DIR
from analysis.emulated_twin import REFERENCE_SEED0, EmulatedTwin
from analysis.history_matching import DesignSpace, design_runs, initial_design

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


def make_model(conditions, space, frame, seed=0, flights=True):
    """The loop's model at the study's conditions, with ``flights`` the impact observables
    emulated at every one."""
    return EmulatedTwin(conditions, space, velocity_frame=frame, seed=seed,
                        flight_conditions=list(conditions["condition_id"]) if flights else ())


def new_run_scores(model, runs) -> pd.DataFrame:
    """Per run (in a motion mode the model emulates) and observable: the twin's value, the
    mode, p of that mode, the mixture's mean, its CDF at the value (PIT) and z =
    Phi^-1(PIT) - the mixture of each mode's new-run normal (emulator + chaos), weighted by
    the classifier."""
    from scipy import stats
    modes = list(model.mode_classifier_.modes_)
    raw = (runs["motion_mode"].astype(str).to_numpy() if "motion_mode" in runs
           else np.full(len(runs), "any"))
    keep = np.isin(raw, modes) if len(modes) > 1 else np.ones(len(runs), bool)
    runs, raw = runs[keep].reset_index(drop=True), raw[keep]
    X = model.inputs_of(runs)
    P = model.mode_classifier_.predict_proba(X)
    own = (P[np.arange(len(runs)), [modes.index(k) for k in raw]] if len(modes) > 1
           else np.where(raw == modes[0], 1.0, np.nan))
    out = []
    for o, ems in model.emulators_.items():
        y = runs[o].to_numpy(float) if o in runs else np.full(len(runs), np.nan)
        parts = [ems[k].predict_parts(X) for k in modes]
        M = np.column_stack([q.mean[:, 0] for q in parts])
        S = np.column_stack([q.sd(1)[:, 0] for q in parts])
        pit = np.sum(P * stats.norm.cdf((y[:, None] - M) / S), axis=1)
        ok = np.isfinite(y)
        out.append(pd.DataFrame({
            "observable": o, "run": np.flatnonzero(ok), "point": runs["point"].to_numpy()[ok],
            "condition_id": runs["condition_id"].to_numpy()[ok], "mode": raw[ok],
            "p_mode": own[ok], "twin": y[ok], "predicted": np.sum(P * M, axis=1)[ok],
            "pit": pit[ok],
            "z": stats.norm.ppf(np.clip(pit[ok], 1e-12, 1 - 1e-12))}))
    return pd.concat(out, ignore_index=True)


def fold_scores(make, runs, n_folds, seed=0) -> pd.DataFrame:
    """:func:`new_run_scores` of every run by a model (``make()``, unfitted) fitted without
    its fold: the design points dealt into ``n_folds`` folds at random (``seed``), every run
    of a point in one fold."""
    pts = np.unique(runs["point"].to_numpy())
    fold = dict(zip(np.random.default_rng(seed).permutation(pts), np.arange(len(pts)) % n_folds))
    k = runs["point"].map(fold).to_numpy()
    out = []
    for f in tqdm(range(n_folds), desc="leave-out folds", unit="fold", file=sys.stdout):
        test = runs[k == f].reset_index(drop=True)
        m = make().fit(runs[k != f].reset_index(drop=True))
        out.append(new_run_scores(m, test).assign(fold=f))
    return pd.concat(out, ignore_index=True)


def summarise(per_run, by=("observable",)) -> pd.DataFrame:
    """n, rmse, coverage95 and mean z^2 per group of scored runs."""
    g = per_run.groupby(list(by))
    return pd.DataFrame({
        "n": g.size(),
        "rmse": g.apply(lambda d: float(np.sqrt(np.mean((d.twin - d.predicted) ** 2)))),
        "coverage95": g.apply(lambda d: float(np.mean(np.abs(d.z) <= 1.96))),
        "mean_z2": g.apply(lambda d: float(np.mean(d.z ** 2)))}).reset_index()


def mode_table(per_run) -> pd.DataFrame:
    """Per motion mode: runs, the classifier's mean p of the own mode, the share with p > 0.5."""
    d = per_run.drop_duplicates("run" if "fold" not in per_run else ["fold", "run"])
    g = d.groupby("mode")["p_mode"]
    return pd.DataFrame({"runs": g.size(), "mean_p_own": g.mean(),
                         "share_p_own_above_half": g.apply(lambda p: float(np.mean(p > 0.5)))
                         }).reset_index()


def heldout_runs(folder, design_ids):
    """Another loop's runs (``model_runs.csv``) that the study's design does not hold."""
    runs = pd.read_csv(Path(folder) / "model_runs.csv")
    return runs[~runs["run_id"].isin(set(design_ids))].reset_index(drop=True)


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
                   "the same conditions: its runs the study's design does not hold are "
                   "predicted one by one (default: none)")
    p.add_argument("--folds", type=int, default=8, help="leave-out folds of whole design "
                   "points [-] (default %(default)s)")
    add_design_options(p)
    p.add_argument("--cached-only", action="store_true", help="start no twin run: analyse "
                   "the study's runs already in the cache")
    p.add_argument("--out", default=str(DEFAULT_OUT), help="output folder")
    a = p.parse_args(argv)
    from analysis.atomic_dir import OutputError, check_out_dir, output_dir
    from analysis.measurements import DatasetError, load_dataset
    try:
        if a.points < 2 or a.replicates < 2 or a.workers < 1 or not 2 <= a.folds <= a.points:
            raise ValueError("--points and --replicates must be >= 2, --workers >= 1, "
                             "--folds between 2 and --points")
        if a.heldout and not (Path(a.heldout) / "model_runs.csv").is_file():
            raise ValueError("--heldout %s holds no model_runs.csv" % a.heldout)
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
    from analysis.flights import FLIGHT_OBSERVABLES
    flights = bool(runs.reindex(columns=list(FLIGHT_OBSERVABLES)).notna().all(axis=1).any())
    make = lambda: make_model(ds.conditions, space, ds.velocity_frame, a.seed,  # noqa: E731
                              flights)
    pooled = lambda: _Pooled(make())                                         # noqa: E731
    per = pd.concat([fold_scores(mk, runs, a.folds, a.seed).assign(model=name)
                     for name, mk in (("mixture", make), ("one GP", pooled))],
                    ignore_index=True)
    leave_out = summarise(per, ("model", "observable"))
    modes = mode_table(per[per.model == "mixture"])
    heldout = per_ho = None
    if a.heldout:
        ho = heldout_runs(a.heldout, runs["run_id"])
        if len(ho):
            per_ho = new_run_scores(make().fit(runs), ho)
            heldout = summarise(per_ho)
    from analysis.plotting.emulator_plots import emulator_check_figure
    from analysis.report.emulator_pages import emulator_check_page
    with output_dir(a.out, protected=(a.dataset,)) as tmp:
        runs.drop(columns=["config"]).to_csv(tmp / "design_runs.csv", index=False)
        leave_out.to_csv(tmp / "leave_out.csv", index=False, float_format="%.5g")
        modes.to_csv(tmp / "modes.csv", index=False, float_format="%.4g")
        if heldout is not None:
            heldout.to_csv(tmp / "heldout.csv", index=False, float_format="%.5g")
            per_ho.to_csv(tmp / "heldout_runs.csv", index=False, float_format="%.6g")
        emulator_check_figure(per, tmp / "emulator_check.png", fake=a.fake)
        (tmp / "README.md").write_text(emulator_check_page(
            leave_out, modes, heldout, n_runs=len(runs), n_planned=n_planned,
            n_points=a.points, replicates=a.replicates, folds=a.folds,
            dataset=rel_path(a.dataset),
            heldout_dir=rel_path(a.heldout) if a.heldout else None, fake=a.fake))
    print(leave_out.to_string(index=False))
    print(modes.to_string(index=False))
    if heldout is not None:
        print(heldout.to_string(index=False))
    return 0


class _Pooled:
    """A model fitted without its runs' motion modes: one GP per observable across them."""

    def __init__(self, model):
        self.model = model

    def fit(self, runs):
        return self.model.fit(runs.drop(columns=["motion_mode"], errors="ignore"))


if __name__ == "__main__":
    sys.exit(main())
