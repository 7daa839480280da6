"""The loop on blind datasets whose truth is known: does it find what was hidden, and only that?

Runs :func:`analysis.loop.run_loop` on every dataset folder in the ``--datasets`` folders
(default: results/open_world/nulls, effects, pairs and chain - 20 no-effect, 12 one-effect,
6 two-effect and 10 measurement-chain datasets; each with its truth in
``<datasets>/truth/<name>.truth.json``, as :mod:`analysis.studies.open_world_data` and
:mod:`analysis.hidden` write them), one output
folder per dataset, the folders taken in turn (a dataset whose loop.json exists is not rerun:
the suite resumes, and one stopped early has scored datasets of every kind), then scores the
verdicts against the truth:

* no effect hidden: "nothing missing";
* effects hidden: each named (significant), no other significant beside them, and each fitted
  strength's 95 % interval covering the truth;
* chi2/dof after the last add (the model's) and of the twin rerun.

Writes ``summary.csv`` (one row per dataset), ``sigma_check.csv`` (per observable, the mean
z^2 of the no-effect datasets' residuals: do the stated sigmas match the scatter?),
``open_suite.png`` (fitted strengths against the truth; chi2/dof per dataset) and
``README.md`` (the goal lines with their counts) into ``--out``. ``--score-only`` scores the
loops already in ``--out`` without running any; a ``NOTES.md`` there (written by hand) is
appended to the README. ``--out`` and every loop folder the suite would write in it follow the
project's folder rule before any loop runs (:func:`analysis.atomic_dir.check_out_dir`: never a
dataset, never a folder holding files this project did not write); its own files are written
atomically and the folder is marked.

Example::

    python -m analysis.open_suite --datasets results/open_world/effects \\
        --out results/open_world/full_loop --only eff_p01
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import pandas as pd
from scipy import stats

from analysis.config import RESULTS_DIR
from analysis.plotting.open_suite_plots import write_open_suite_figure
from analysis.report import open_suite_page

OUT_DIR = RESULTS_DIR / "open_world" / "full_loop"
#: the suite's figure in ``--out``: strengths against the truth, chi2/dof per dataset
FIGURE = "open_suite.png"
#: a hand-written note in ``--out`` (how the loops were run, what the misses mean), appended to
#: the README each time the suite is scored again
NOTES = "NOTES.md"
#: the blind suite: no-effect, one-effect, two-effect and measurement-chain datasets (made by
#: analysis.studies.open_world_data --nulls / --effects / --pairs / --chain)
DATASETS_DIRS = tuple(RESULTS_DIR / "open_world" / k
                      for k in ("nulls", "effects", "pairs", "chain"))
#: the suite's loop settings beside the loop's defaults: the demo's blind loop's (its folder
#: results/demo/blind_loop is the suite's eff_p01 loop, from the same runs)
SUITE_PER_WAVE, SUITE_NULL_DRAWS = 6, 10
SIGMA_CHECK_NAME = "sigma_check.csv"
#: the catalog kinds a hidden effect of the suite's datasets shows in the observables (the DEM
#: effects and the measurement chain; kinetics acts on the yields' line)
OBSERVED_KINDS = ("dem", "observation")


def truth_strengths(truth) -> dict:
    """effect -> true strength in the diagnose coordinate (catalog parameter converted)."""
    from analysis.catalog import candidates
    cands = candidates()
    out = {}
    for name, params in (truth.get("effects") or {}).items():
        c = cands.get(name)
        if c is None or c.param not in params:
            continue
        out[name] = c.strength_of(float(params[c.param]))
    return out


def strength_ranges() -> dict:
    """effect -> top of its diagnose range (the figure's unit of strength): the DEM effects and
    the measurement chain."""
    from analysis.catalog import candidates
    return {k: c.s_max for k, c in candidates().items() if c.kind in OBSERVED_KINDS}


def _interval(parameters, name):
    """(lo, hi) of ``name``'s profile interval in a loop's parameters.csv, or None."""
    if parameters is None or "profile_lo" not in parameters:
        return None
    r = parameters[parameters["name"] == name]
    if not len(r) or not np.isfinite(float(r["profile_lo"].iloc[0])):
        return None
    return float(r["profile_lo"].iloc[0]), float(r["profile_hi"].iloc[0])


def score(name, loop_info, diagnosis, staircase, truth, parameters=None) -> dict:
    """One summary row: what was hidden, what was found, whether the intervals cover it."""
    true = truth_strengths(truth)
    sig = diagnosis[diagnosis["significant"].astype(bool)].sort_values("rank")
    found = list(sig["effect"])
    row = {"dataset": name, "hidden": "+".join(true) or "none", "found": "+".join(found) or
           "none", "n_hidden": len(true), "status": loop_info.get("status")}
    from analysis.catalog import candidates
    chain = {k for k, c in candidates().items() if c.kind == "observation"}
    row["chain_hidden"] = any(k in chain for k in true)
    row["chain_found"] = any(k in chain for k in found)
    row["chain_in_catalog"] = bool(diagnosis["effect"].isin(chain).any())
    row["nothing_missing_ok"] = (not true) and not found
    row["all_named"] = bool(true) and all(k in found for k in true)
    row["no_other"] = all(k in true for k in found)
    row["first_named"] = bool(true) and bool(found) and found[0] in true
    cov = []
    for k, s in true.items():
        r = sig[sig["effect"] == k]
        if len(r):
            est, se = float(r["strength"].iloc[0]), float(r["strength_se"].iloc[0])
            row["%s_true" % k], row["%s_fit" % k], row["%s_se" % k] = s, est, se
            iv = _interval(parameters, k) or (est - 1.96 * se, est + 1.96 * se)
            row["%s_lo" % k], row["%s_hi" % k] = iv
            cov.append(iv[0] <= s <= iv[1])
    row["covered"] = all(cov) if cov else np.nan
    for k, v in (truth.get("base_config") or {}).items():
        iv = _interval(parameters, k)
        if iv is not None:
            row["%s_base_covered" % k] = bool(iv[0] <= float(v) <= iv[1])
    stages = staircase.drop_duplicates("stage", keep="last").set_index("stage")
    st = stages["chi2_dof"]
    model_stages = [s for s in st.index if s != "twin rerun"]
    row["chi2_dof_calibrated"] = float(st.get("calibrated", np.nan))
    row["chi2_dof_last"] = float(st[model_stages[-1]])
    row["chi2_dof_twin_rerun"] = float(st.get("twin rerun", np.nan))
    # the staircase falls from calibrated to final, or stays within a chi2/dof's noise there
    # (2 sds of a chi2/dof: 2 sqrt(2 / dof))
    if "calibrated" in st.index:
        dof = float(stages["dof"][model_stages[-1]]) if "dof" in stages else 0.0
        noise = 2.0 * np.sqrt(2.0 / dof) if dof > 0 else 0.0
        row["final_not_above_calibrated"] = bool(
            row["chi2_dof_last"] <= row["chi2_dof_calibrated"] + noise)
    # the emulator's prediction at the last rerun's point against that rerun's means, before
    # they joined it (the loop's p; >= 0.01: within the emulator's stated uncertainty)
    vs = ((loop_info.get("reruns") or [{}])[-1].get("emulator_vs_twin") or {})
    row["emulator_vs_twin_p"] = float(vs.get("p", np.nan))
    row["new_runs"] = loop_info.get("new_runs")
    row["wall_s"] = loop_info.get("wall_s")
    return row


#: an effect is detectable when it explains at least this chi2 of the twin's own values at the
#: truth (:func:`detectable_chi2`): the issue's bar - a chi2_1 gain with this non-centrality
#: exceeds the first step's Bonferroni threshold (about 10.3 at alpha 0.01 over 15 candidates)
#: with 90 % power ((sqrt(10.3) + 1.28)^2 = 20.2)
DETECTABLE_CHI2 = 21.0


def loop_model(dataset, loop_dir, runs=None):
    """The loop's final model (the emulator refitted to every run in ``loop_dir``'s
    model_runs.csv, or to ``runs``, a part of that table; no run starts) and its observations;
    (None, None) without the table."""
    from analysis.loop import LoopSettings, fit_observations, read_stage
    runs_csv = Path(loop_dir) / "model_runs.csv"
    if runs is None and not runs_csv.is_file():
        return None, None
    st = read_stage(dataset, LoopSettings(), track=False, log=lambda _: None)
    m = st.model.fit(pd.read_csv(runs_csv) if runs is None else runs)
    return m, fit_observations(st.obs0, m)


def rerun_own_mode(dataset, loop_dir, loop_info) -> dict:
    """The emulator against the loop's last twin rerun, each run against its OWN motion mode.

    The final emulator is refitted without that rerun's runs (those of the waves before it in
    ``loop_dir``'s model_runs.csv); per (condition, mode, observable) of the rerun
    z = (the mode's mean - the mean of the rerun's runs in that mode) /
    sqrt(the emulator's sd in the mode^2 + the chaos sd^2 / n runs). The loop's own test
    (``emulator_vs_twin``) scores the mixture over modes, whose sd holds the modes' spread: where
    a condition's mode is uncertain it passes whatever the twin did. Diagonal (the emulator's
    correlations across conditions left out). Returns {"rerun_mode_chi2", "rerun_mode_n",
    "rerun_mode_p", "rerun_mode_max_abs_z"}; NaN without a rerun or its table."""
    from analysis.catalog import candidates
    from analysis.emulated_twin import SPEED_COLUMN
    out = {"rerun_mode_chi2": np.nan, "rerun_mode_n": 0, "rerun_mode_p": np.nan,
           "rerun_mode_max_abs_z": np.nan}
    runs_csv = Path(loop_dir) / "model_runs.csv"
    reruns = loop_info.get("reruns") or []
    if not reruns or not runs_csv.is_file():
        return out
    runs = pd.read_csv(runs_csv)
    wave = "confirm %d" % int(reruns[-1]["round"])
    last = runs["wave"].astype(str) == wave
    if not last.any():
        return out
    m, _ = loop_model(dataset, loop_dir, runs[~last])
    cands = candidates()
    point = reruns[-1]["point"]
    theta = {k: float(v) for k, v in point.items() if k not in cands}
    dem = {k: float(v) for k, v in point.items() if k in cands and cands[k].kind == "dem"}
    mc = m.mode_components(theta, dem)
    chaos = m.chaos_sd(theta, dem)
    keys = pd.Index(mc.keys)
    observables = (SPEED_COLUMN[m.velocity_frame], "f_col_hz") + tuple(m.flight_obs)
    z = []
    for (cid, mode), grp in runs[last].groupby(["condition_id", "motion_mode"]):
        if mode not in mc.modes:
            continue
        k = mc.modes.index(mode)
        for o in observables:
            if (cid, o) not in keys or o not in grp:
                continue
            i = keys.get_loc((cid, o))
            var = mc.cov[k][i, i] + float(chaos.get((cid, o), 0.0)) ** 2 / len(grp)
            z.append((mc.mean[k, i] - grp[o].mean()) / np.sqrt(var))
    z = np.asarray(z, float)
    z = z[np.isfinite(z)]
    if not len(z):
        return out
    chi2 = float(np.sum(z ** 2))
    return {"rerun_mode_chi2": chi2, "rerun_mode_n": int(len(z)),
            "rerun_mode_p": float(stats.chi2.sf(chi2, len(z))),
            "rerun_mode_max_abs_z": float(np.max(np.abs(z)))}


def truth_observations(obs, truth) -> pd.DataFrame:
    """``obs`` with every value replaced by the twin's own at the truth, without the
    measurement noise: the run means the dataset was made from (``twin_means``), the impact
    observables of those runs (``twin_flights``) and the true yields; rows the truth does not
    hold are dropped (the priors' pseudo-observations are kept as they are)."""
    kin = truth.get("kinetics") or {}
    vals = {}
    for cid, d in (truth.get("twin_means") or {}).items():
        vals.update({(cid, k): v for k, v in d.items()})
    for cid, d in (truth.get("twin_flights") or {}).items():
        vals.update({(cid, k): v for k, v in d.items()})
    for cid, ys in (kin.get("yields_true") or {}).items():
        vals.update({(cid, "yield_pct@%gmin" % t): y
                     for t, y in zip(kin.get("yield_times_min") or (), ys)})
    # a hidden measurement chain (analysis.studies.open_world_data.make_chain): the factor it
    # applied to each observable at each condition
    chain = (truth.get("observation") or {}).get("factor") or {}
    vals = {(c, o): v * chain.get(c, {}).get(o, 1.0) for (c, o), v in vals.items()}
    own = obs["condition_id"].isin({c for c, _ in vals})
    new = [vals.get((c, o), np.nan) for c, o in zip(obs["condition_id"], obs["observable"])]
    out = obs.assign(value=np.where(own, new, obs["value"]))
    return out[np.isfinite(out["value"].to_numpy(float))].reset_index(drop=True)


def _leftover_chi2(m, obs, truth, held) -> float:
    """chi2 of the base parameters fitted, with the effects ``held`` on at their true
    strengths, to the twin's own noise-free data at the truth (the better of two fits: from the
    true base point and from the model's reference) (:func:`truth_observations`:
    every hidden effect on, the twin's runs, not the emulator - which can be wrong in an
    effect's corner the loop never needed), with the dataset's sds."""
    from analysis.diagnose import BaseParameter, calibrate_base
    theta = dict(m.theta_ref, **{k: float(v) for k, v in (truth.get("base_config") or {}).items()
                                 if k in m.theta_ref})
    kin = truth.get("kinetics") or {}
    for k in ("slope_pct_per_kj", "intercept_pct"):
        if k in kin:
            theta[k] = float(kin[k])
    data = truth_observations(obs, truth)
    best = np.inf
    for at_truth in (True, False):      # the fit is local: from the truth and from the reference
        start = [BaseParameter(p.name, float(np.clip(theta.get(p.name, p.value), p.lower,
                                                     p.upper)) if at_truth else p.value,
                               p.lower, p.upper) for p in m.base_params()]
        _, cal = calibrate_base(m.predict, data, start, model_se=m.model_se(),
                                fixed_effects=dict(held) or None)
        best = min(best, float(cal.chi2))
    return best


def _true_hidden(truth) -> dict:
    """The hidden effects the observables see (DEM and measurement chain; not kinetics)."""
    from analysis.catalog import candidates
    return {k: v for k, v in truth_strengths(truth).items()
            if candidates()[k].kind in OBSERVED_KINDS}


#: the fit with every hidden effect on at its true strength, against the twin's own values at
#: the truth, is one realisation's chaos when the model is right there; above this chi2
#: quantile (of as many dof as values) the model is wrong at the truth - the loop never ran
#: near it - and what the effects explain there is not measured
TRUTH_FIT_P = 1e-3


def detectability(dataset, truth, loop_dir, each=False) -> tuple:
    """(the chi2 the hidden effects explain, {effect: the chi2 it explains beyond the others},
    the chi2 of the fit with all of them on) on one fit of the loop's final model (see
    :func:`detectable_chi2` and :func:`detectable_each`; the second {} unless ``each``). The
    first two NaN when that last fit fails :data:`TRUTH_FIT_P`; all NaN when no DEM or chain
    effect is hidden or there is no model."""
    nan = float("nan")
    true = _true_hidden(truth)
    if not true:
        return nan, {}, nan
    m, obs = loop_model(dataset, loop_dir)
    if m is None:
        return nan, {}, nan
    with_all = _leftover_chi2(m, obs, truth, true)
    if with_all > stats.chi2.isf(TRUTH_FIT_P, len(truth_observations(obs, truth))):
        return nan, {k: nan for k in true} if each else {}, with_all
    total = _leftover_chi2(m, obs, truth, {}) - with_all
    if not each:
        return total, {}, with_all
    if joint_runs(loop_dir, true):
        return total, {k: _leftover_chi2(m, obs, truth, _others(true, k)) - with_all
                       for k in true}, with_all
    # the fit with all on would be an extrapolation; the fit with the others on is measured
    # where the loop ran them, and what an effect explains beyond them is at most its chi2
    return total, {k: _beyond_bound(m, obs, truth, loop_dir, _others(true, k))
                   for k in true}, with_all


def _others(true, k) -> dict:
    return {j: s for j, s in true.items() if j != k}


def _beyond_bound(m, obs, truth, loop_dir, others) -> float:
    """Where no run had every hidden effect on: the chi2 of the fit with only ``others`` on
    (an upper bound on what the remaining effect explains beyond them, the fit with all on
    having chi2 >= 0) when the loop ran ``others`` together and the bound is under
    :data:`DETECTABLE_CHI2` - the effect cannot be told from the base parameters beside the
    others; NaN (not measured) otherwise."""
    if not joint_runs(loop_dir, others):
        return float("nan")
    bound = _leftover_chi2(m, obs, truth, others)
    return bound if bound < DETECTABLE_CHI2 else float("nan")


def joint_runs(loop_dir, effects) -> int:
    """How many of ``loop_dir``'s twin runs (model_runs.csv) had every DEM effect of
    ``effects`` on together: with none, the emulator's response to them together is an
    extrapolation from each one alone (or from none), and what each explains beyond the
    others is not measured. No DEM effect: every run counts."""
    from analysis.catalog import candidates
    runs = pd.read_csv(Path(loop_dir) / "model_runs.csv")
    dem = ["effect:%s" % k for k in effects if candidates()[k].kind == "dem"]
    if not set(dem) <= set(runs.columns):
        return 0
    return int((runs[dem].fillna(0.0) > 0).all(axis=1).sum())


def detectable_chi2(dataset, truth, loop_dir) -> float:
    """The chi2 the hidden effects (DEM or measurement chain) explain: the twin's own values at
    the truth (:func:`truth_observations`, observed through the hidden chain; one twin
    realisation, so its chaos stays in) fitted by the loop's final model
    (:func:`loop_model`) without the effects, less the same fitted with them on at their true
    strengths - the gain the selection's test sees, without the measurement noise (the
    realisation's chaos, in both fits, cancels; the chi2 without the effects alone counts it
    as signal: 16-29 of 66 observations on no-effect datasets). With the dataset's sds. NaN
    when no such effect is hidden or there is no model."""
    return detectability(dataset, truth, loop_dir)[0]


def detectable_each(dataset, truth, loop_dir) -> dict:
    """effect -> the chi2 each hidden effect explains beyond the others (as
    :func:`detectable_chi2`): the base parameters fitted with every OTHER hidden effect on at
    its true strength, less fitted with all of them on. An effect under
    :data:`DETECTABLE_CHI2` here cannot be told from a shift of the base parameters once the
    other is found. {} when no such effect is hidden or a run is missing."""
    return detectability(dataset, truth, loop_dir, each=True)[1]


def _dataset_names(datasets_dir):
    return sorted(p.name for p in Path(datasets_dir).iterdir()
                  if p.is_dir() and (p / "dataset.json").exists())


def suite_datasets(datasets_dirs) -> list:
    """[(folder, name)] of every dataset in ``datasets_dirs`` (one folder or several), taken
    in turn from each folder (its first, the next folder's first, ...): a suite stopped early
    has scored some datasets of every kind. ValueError when a name occurs in two folders (the
    loop folders in --out are named by the dataset)."""
    dirs = [Path(datasets_dirs)] if isinstance(datasets_dirs, (str, Path)) else \
        [Path(d) for d in datasets_dirs]
    lists = [[(d, n) for n in _dataset_names(d)] if d.is_dir() else [] for d in dirs]
    out, seen = [], {}
    for i in range(max((len(x) for x in lists), default=0)):
        for x in lists:
            if i < len(x):
                d, n = x[i]
                if n in seen:
                    raise ValueError("dataset %s is in both %s and %s" % (n, seen[n], d))
                seen[n] = d
                out.append((d, n))
    return out


#: the files the suite writes (and reads: NOTES.md) in ``--out`` beside the loop folders
SUITE_FILES = ("summary.csv", SIGMA_CHECK_NAME, FIGURE, "README.md", NOTES)


def _suite_folder(folder) -> bool:
    from analysis.atomic_dir import MARKER
    return all((p.is_dir() and not p.is_symlink() and (p / MARKER).is_file())
               or (p.is_file() and p.name in SUITE_FILES) for p in Path(folder).iterdir())


def check_outputs(datasets_dirs=DATASETS_DIRS, out_dir=OUT_DIR, only=None, score_only=False):
    """The folder rule for ``--out`` and every loop folder the suite would write there, before
    any loop runs (raises :class:`analysis.atomic_dir.OutputError`)."""
    from analysis.atomic_dir import OutputError, check_out_dir
    dirs = [Path(datasets_dirs)] if isinstance(datasets_dirs, (str, Path)) else \
        [Path(d) for d in datasets_dirs]
    out_dir = Path(out_dir)
    for d in dirs:
        if not d.is_dir():
            raise OutputError("--datasets %s is not a folder of datasets" % d)
    pairs = suite_datasets(dirs)
    if only:
        pairs = [(d, n) for d, n in pairs if n in only]
    if not pairs:
        raise ValueError("--datasets %s holds no dataset folder (dataset.json)%s"
                         % (" ".join(map(str, dirs)), " named by --only" if only else ""))
    try:
        check_out_dir(out_dir, dirs)
    except OutputError as exc:
        # an unmarked folder holding nothing but the suite's loop folders (each marked) and
        # its own files: the suite's earlier output from before the folder was marked
        if "did not write" not in str(exc) or not _suite_folder(out_dir):
            raise
    if score_only and not any((out_dir / n / "loop.json").exists() for _, n in pairs):
        raise ValueError("--score-only: --out %s holds no loop of these datasets to score"
                         % out_dir)
    for d, name in pairs:
        dest = out_dir / name
        if score_only or (dest / "loop.json").exists():
            continue
        check_out_dir(dest, [d / name])


def run_suite(datasets_dirs=DATASETS_DIRS, out_dir=OUT_DIR, only=None, log=print,
              score_only=False, settings=None, workers=2):
    """Run the loop (``settings``: :class:`analysis.loop.LoopSettings`, its frame 'auto') on
    every dataset of ``datasets_dirs`` (:func:`suite_datasets`'s order; resuming) and return
    the summary table; ``score_only``: score the datasets whose loop already ran, run none."""
    from analysis.loop import run_loop, write_loop
    from analysis.twin_runs import TwinRuns
    from analysis.measurements import load_dataset
    out_dir = Path(out_dir)
    check_outputs(datasets_dirs, out_dir, only, score_only)
    rows = []
    for datasets_dir, name in suite_datasets(datasets_dirs):
        if only and name not in only:
            continue
        truth = json.loads((datasets_dir / "truth" / ("%s.truth.json" % name)).read_text())
        dest = out_dir / name
        if not (dest / "loop.json").exists():
            if score_only:
                continue
            ds = load_dataset(datasets_dir / name)
            log("== %s" % name)
            res = run_loop(ds, settings, log=log, base_config={"frame": "auto"},
                           twin=TwinRuns(workers=workers))
            write_loop(res, dest, ds, protected=[datasets_dir / name])
        info = json.loads((dest / "loop.json").read_text())
        row = score(name, info, pd.read_csv(dest / "diagnosis.csv"),
                    pd.read_csv(dest / "staircase.csv"), truth,
                    pd.read_csv(dest / "parameters.csv")
                    if (dest / "parameters.csv").is_file() else None)
        ds = load_dataset(datasets_dir / name)
        if row["n_hidden"]:
            pair = row["n_hidden"] >= 2
            row["detectable_chi2"], each, row["truth_fit_chi2"] = detectability(
                ds, truth, dest, each=pair)
            if pair:
                for k, v in each.items():
                    row["%s_beyond_chi2" % k] = v
                row["detectable_min_chi2"] = (float(np.min(list(each.values()))) if each
                                              else np.nan)
                row["joint_runs"] = joint_runs(dest, _true_hidden(truth))
        row.update(rerun_own_mode(ds, dest, info))
        rows.append(row)
    return pd.DataFrame(rows)


#: the per-observable check of the stated sigmas, written beside summary.csv
SIGMA_CHECK = SIGMA_CHECK_NAME


def sigma_check(out_dir, summ) -> pd.DataFrame:
    """Do the stated sigmas match the scatter? Over the datasets with NO effect hidden (where
    the twin without effects is the right model), per observable: how many residuals, and the
    mean z^2 of the data against the loop's final fit (``z_final``) and against the final twin
    rerun (``z_twin_rerun``) from each loop's comparison.csv - 1 where sigma is right, below 1
    where it is stated too large (power lost), above where too small (false alarms).
    Empty without no-effect datasets."""
    names = list(summ.loc[summ["n_hidden"] == 0, "dataset"])
    parts = []
    for n in names:
        f = Path(out_dir) / n / "comparison.csv"
        if f.is_file():
            parts.append(pd.read_csv(f).assign(dataset=n))
    cols = ["observable", "n", "datasets", "mean_z2_final", "mean_z2_twin_rerun"]
    if not parts:
        return pd.DataFrame(columns=cols)
    d = pd.concat(parts, ignore_index=True)
    if "z_twin_rerun" not in d:
        d["z_twin_rerun"] = np.nan
    g = d.groupby("observable", sort=True)
    return pd.DataFrame({
        "n": g["z_final"].count(), "datasets": g["dataset"].nunique(),
        "mean_z2_final": g["z_final"].apply(lambda z: float(np.nanmean(z ** 2))),
        "mean_z2_twin_rerun": g["z_twin_rerun"].apply(
            lambda z: float(np.nanmean(z ** 2)) if z.notna().any() else np.nan),
    }).reset_index()[cols]


def sigma_line(check) -> str | None:
    """The goal line of :func:`sigma_check` (None when empty): the range of mean z^2 over the
    observables, and the observables whose mean z^2 lies outside what its count allows (a
    chi-square's 95 % band for n residuals)."""
    from scipy import stats
    c = check[check["n"] > 0]
    if not len(c):
        return None
    z = c["mean_z2_final"].to_numpy(float)
    n = c["n"].to_numpy(int)
    lo, hi = stats.chi2.ppf(0.025, n) / n, stats.chi2.ppf(0.975, n) / n
    out = [("%s %.2f" % (o, v)) for o, v, a, b in zip(c["observable"], z, lo, hi)
           if not a <= v <= b]
    return ("stated sigmas on the no-effect datasets: mean z^2 against the final fit per "
            "observable %.2f-%.2f (1 where sigma is right); outside its 95 %% band: %s"
            % (np.nanmin(z), np.nanmax(z), ", ".join(out) or "none"))


def goal_lines(summ) -> list:
    """The goals with their counts."""
    null = summ[summ["n_hidden"] == 0]
    chain = (summ["chain_hidden"].astype(bool) if "chain_hidden" in summ
             else pd.Series(False, index=summ.index))
    one = summ[(summ["n_hidden"] == 1) & ~chain]   # one DEM effect (the chain: its own line)
    two = summ[summ["n_hidden"] >= 2]
    eff = summ[summ["n_hidden"] >= 1]
    cov = eff["covered"].dropna()
    last = summ["chi2_dof_last"]
    from analysis.catalog import DECOYS
    decoy = summ["found"].astype(str).apply(lambda f: any(d in f.split("+") for d in DECOYS))
    L = []
    L.append("no effect hidden -> 'nothing missing': %d / %d (goal >= 95 %% of >= 20)"
             % (null["nothing_missing_ok"].sum(), len(null)))
    det = one
    if "detectable_chi2" in one:
        det = one[~(one["detectable_chi2"] < DETECTABLE_CHI2)]    # NaN (not computed) kept
    L.append("one effect hidden that explains a noise-free chi2 >= %g (%d of %d) "
             "-> named first and significant: %d / %d (goal >= 90 %%); no other significant "
             "beside it: %d / %d (goal >= 80 %%)"
             % (DETECTABLE_CHI2, len(det), len(one),
                det["first_named"].sum() if "first_named" in det else det["all_named"].sum(),
                len(det),
                (det["all_named"] & det["no_other"]).sum(), len(det)))
    if "chain_in_catalog" in summ and summ["chain_in_catalog"].astype(bool).any():
        ch = summ[summ["chain_hidden"].astype(bool)]
        looked = null[null["chain_in_catalog"].astype(bool)]
        nch = looked[~looked["chain_found"].astype(bool)]
        if len(ch):
            cc = ch["covered"].dropna()
            L.append("a measurement chain hidden (smoothing window, scale) -> named first and "
                     "significant: %d / %d (goal >= 90 %%); its 95 %% interval covers the "
                     "truth: %d / %d (goal >= 90 %%)"
                     % (ch["first_named"].sum(), len(ch), cc.sum(), len(cc)))
        L.append("no effect hidden -> no measurement-chain effect named: %d / %d (goal >= 95 %%)"
                 % (len(nch), len(looked)))
    L.append("two effects hidden -> both named: %d / %d (goal >= 80 %%)"
             % (two["all_named"].sum(), len(two)))
    if "detectable_min_chi2" in two and len(two):
        both = two[~(two["detectable_min_chi2"] < DETECTABLE_CHI2)]
        unmeasured = int(both["detectable_min_chi2"].isna().sum())
        L.append("  of them, each effect explaining a noise-free chi2 >= %g beyond the other "
                 "(%d of %d%s) -> both named: %d / %d"
                 % (DETECTABLE_CHI2, len(both), len(two),
                    "; %d not measured - the loop never ran its effects together - and "
                    "counted in" % unmeasured if unmeasured else "",
                    both["all_named"].sum(), len(both)))
    L.append("95 %% interval covers the true strength: %d / %d (goal >= 90 %%)"
             % (cov.sum(), len(cov)))
    base = [c for c in summ.columns if c.endswith("_base_covered")]
    if base:
        L.append("95 % profile interval covers the true base parameter (goal >= 90 % each): "
                 + ", ".join("%s %d / %d" % (c[:-len("_base_covered")],
                                            summ[c].dropna().astype(bool).sum(),
                                            summ[c].notna().sum()) for c in base))
    L.append("chi2/dof after the last add: median %.2f (goal 0.8-1.2), <= 1.5 in %d / %d "
             "(goal >= 90 %%)" % (last.median(), (last <= 1.5).sum(), len(last)))
    L.append("a decoy (%s) named: %d / %d (goal never)" % (", ".join(DECOYS), decoy.sum(),
                                                          len(summ)))
    L.append("twin rerun chi2/dof: median %.2f" % summ["chi2_dof_twin_rerun"].median())
    if "emulator_vs_twin_p" in summ:
        p = summ["emulator_vs_twin_p"].dropna()
        L.append("the emulator at the final point agrees with the twin rerun there (p >= 0.01, "
                 "its stated uncertainty): %d / %d (goal every dataset; the loop's test, on "
                 "the mixture over motion modes: weak where a condition's mode is uncertain)"
                 % ((p >= 0.01).sum(), len(p)))
    if "rerun_mode_p" in summ:
        own = summ[summ["rerun_mode_n"] > 0]
        L.append("the same, each rerun run against its own motion mode (the emulator refitted "
                 "without the rerun): p >= 0.01 in %d / %d, sum z^2 / n median %.2f (goal every "
                 "dataset; 1 when the stated uncertainty is right)"
                 % ((own["rerun_mode_p"] >= 0.01).sum(), len(own),
                    (own["rerun_mode_chi2"] / own["rerun_mode_n"]).median()))
    if "final_not_above_calibrated" in summ:
        f = summ["final_not_above_calibrated"].dropna().astype(bool)
        L.append("the staircase falls from calibrated to final (or stays within 2 sqrt(2 / dof) "
                 "of it): %d / %d (goal every dataset)" % (f.sum(), len(f)))
    return L


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 epilog="example: python -m analysis.open_suite")
    ap.add_argument("--datasets", action="append", default=None,
                    help="a folder of datasets, each with its truth in <folder>/truth "
                    "(repeatable; default: %s)" % " ".join(
                        str(d.relative_to(RESULTS_DIR.parent)) for d in DATASETS_DIRS))
    ap.add_argument("--out", default=str(OUT_DIR), help="folder of the loop outputs")
    ap.add_argument("--only", action="append", help="only this dataset (repeatable)")
    ap.add_argument("--workers", type=int, default=2,
                    help="parallel processes: twin runs and bootstrap draws [processes]")
    ap.add_argument("--no-rerun", action="store_true", help="skip each loop's twin rerun")
    ap.add_argument("--null-draws", type=int, default=SUITE_NULL_DRAWS,
                    help="bootstrap draws per diagnosis step [datasets] (0: nominal threshold "
                    "only; default %(default)s)")
    ap.add_argument("--per-wave", type=int, default=SUITE_PER_WAVE,
                    help="design points per refinement wave of each loop [points] (default "
                    "%(default)s)")
    ap.add_argument("--waves", type=int, default=None,
                    help="refinement waves of each loop [waves] (default: the loop's)")
    ap.add_argument("--focus-points", type=int, default=None,
                    help="focus-wave points of each loop (0: none) [points] (default: the "
                    "loop's)")
    ap.add_argument("--with-effect", action="append", default=[], metavar="NAME",
                    help="an optional catalog entry every loop diagnoses too (repeatable; "
                    "e.g. the measurement chain: apparent_scale, smoothing_window, frame_rate, "
                    "camera_plane, collision_count)")
    ap.add_argument("--score-only", action="store_true",
                    help="score the datasets whose loop already ran in --out, run no loop")
    a = ap.parse_args(argv)
    from analysis.atomic_dir import MARKER, OutputError, atomic_file
    from analysis.loop import LoopSettings
    dirs = [Path(d) for d in (a.datasets or DATASETS_DIRS)]
    try:
        from analysis.loop import optional_effects
        opts = {k: v for k, v in (("waves", a.waves), ("focus_points", a.focus_points))
                if v is not None}
        settings = LoopSettings(rerun=not a.no_rerun, null_draws=a.null_draws,
                                per_wave=a.per_wave, n_jobs=a.workers,
                                extra_effects=tuple(optional_effects(a.with_effect,
                                                                     {"frame": "auto"})),
                                **opts).check()
        check_outputs(dirs, a.out, a.only, a.score_only)
    except (OutputError, ValueError, OSError) as exc:
        print("analysis.open_suite: error: %s" % exc, file=sys.stderr)
        return 2
    out = Path(a.out)
    summ = run_suite(dirs, a.out, only=a.only, score_only=a.score_only, workers=a.workers,
                     settings=settings, log=lambda s: print(s, file=sys.stderr))
    out.mkdir(parents=True, exist_ok=True)
    if not (out / MARKER).exists():
        (out / MARKER).write_text("written by the mill twin project; a rerun may replace "
                                  "this folder\n")
    with atomic_file(out / "summary.csv") as tmp:
        summ.to_csv(tmp, index=False)
    lines = goal_lines(summ)
    check = sigma_check(out, summ) if len(summ) else pd.DataFrame()
    if len(check):
        with atomic_file(out / SIGMA_CHECK) as tmp:
            check.to_csv(tmp, index=False)
        line = sigma_line(check)
        if line:
            lines.append(line)
    import os
    from analysis.config import REPO_ROOT
    rel = ", ".join(os.path.relpath(d.resolve(), REPO_ROOT) for d in dirs)
    if len(summ):
        with atomic_file(out / FIGURE) as tmp:
            write_open_suite_figure(summ, strength_ranges(), tmp)
    notes = out / NOTES
    with atomic_file(out / "README.md") as tmp:
        tmp.write_text(open_suite_page(summ, lines, rel, FIGURE if len(summ) else None,
                                       notes.read_text() if notes.is_file() else "",
                                       detectable_chi2=DETECTABLE_CHI2))
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
