"""The twin as diagnose's model at ANY dataset's conditions, built from runs made there.

:mod:`analysis.twin_model` reads a library of runs at the paper's 8 conditions. A researcher's
dataset is at other frequencies, other balls, perhaps another stroke: this model is built from
twin runs at the dataset's own conditions (matched by physics, :mod:`analysis.conditions`), all
cached by run id, so a second build costs nothing and a killed build resumes:

* **anchor**: the twin at the anchor parameters ``theta_ref`` (default the calibration's
  posterior mean), every effect off, ``replicates`` seeds per condition (default 3);
* **base parameters** (restitution, stroke, static and rolling friction): the twin at
  ``theta_ref`` +- ``BASE_STEPS`` on both sides (kept inside the run config's bounds: near a
  bound the levels are clipped or both put on one side, :func:`response_levels`), with the first ``diff_replicates`` of the
  anchor's seeds (the frictions, whose response is weak beside the twin's chaos, with all
  ``replicates`` of them: :data:`NOISY_BASE`); the response is the quadratic through the three
  points, extended linearly beyond them. Every base parameter is fitted: the frictions with
  their calibration prior (a weak response measured with noise is regularised by the prior,
  not frozen - a friction held at the anchor while the data's differs leaves a misfit that a
  candidate effect absorbs: 7 of 11 no-effect datasets named one that way). The chi-square
  z of each response against the twin's noise is kept in :attr:`response_z_`. Where a dataset
  states the stroke of a condition (``amplitude_mm``), that condition runs at it and the
  stroke is not fitted there;
* **DEM effects**: each candidate of the catalog at ``EFFECT_LEVELS`` of its diagnose range,
  ``diff_replicates`` seeds, piecewise linear in its strength coordinate
  (:func:`analysis.twin_model.interp_levels`), with its interpolation error
  (:func:`analysis.twin_model.interp_sd`) and the level means' own noise in ``effect_se``;
* **observables**: v_mean in the dataset's velocity frame (``v_mean_jar_m_s`` of the recording
  for a 'jar' dataset), f_col, the impact observables of :mod:`analysis.flights` where the
  dataset has jar tracks, yields through the powder line or a kinetics effect (exact) - from the
  lab-frame speed, whatever the frame of the measured speed.

The build is staged so that no run is wasted: :meth:`OpenTwinModel.fit` with ``stage='base'``
runs the anchor and the base responses only (enough to calibrate), ``stage='all'`` adds the
effect responses. :meth:`plan` lists every run with its cached state, for a cost estimate before
anything starts.

The model's noise (``model_se``) is the anchor mean's standard error, the replicate sd pooled
over every group of seeds at the condition (floored as in the library model); diagnose is told
``crn_correlation = 0`` (chaos decorrelates two runs of 0.5 s even from one start).
"""
from __future__ import annotations

import math
import time
import warnings
from pathlib import Path

import numpy as np
import pandas as pd

from analysis.conditions import physics_table
from analysis.parameter_space import BASE_STEPS
from analysis.run_configs import condition_config, stated_amplitude_m
from analysis.twin_model import (CANDIDATES, F_COL_SD_FLOOR_HZ, FLIGHT_SD_FLOORS,
                                 OPTIONAL_CANDIDATES,
                                 V_REL_SD_FLOOR, TwinModel, candidates, curvatures, interp_levels,
                                 interp_sd, reference_parameters)

# BASE_STEPS: the base parameters the open model can calibrate and the step of their response
# runs, declared in analysis.parameter_space (imported above, re-exported here)
#: base parameters whose response is weak beside the twin's chaos: their response runs use
#: every anchor seed (``replicates``), the others the first ``diff_replicates``
NOISY_BASE = ("static_friction", "rolling_friction")
DEFAULT_BASE = ("restitution", "amplitude_m", "static_friction", "rolling_friction")
#: observables whose base responses are measured and combined in log space (relative
#: changes that multiply): the ball's transverse rms speed triples from its anchor value when
#: the rolling friction drops one step and again when the static friction rises one, and the
#: two together multiply (measured: 0.0065 -> 0.012 and 0.012 alone, 0.023 together), which a
#: sum of separate changes misses by a third
LOG_RESPONSE = ("vy_rms_m_s",)
#: DEM effect levels, as fractions of each candidate's diagnose range
EFFECT_LEVELS = (0.5, 1.0)
#: how far beyond its measured response points (in steps) the model may extrapolate linearly
#: before the loop re-anchors it
EXTRAPOLATE_STEPS = 0.5
#: wall time of one default twin run on one core [s] (the planner's estimate; measured 21 s)
RUN_WALL_S = 21.0
#: the same in the jar frame (run config frame 'jar' / 'auto': measured 1.7-1.9x faster)
RUN_WALL_S_JAR = 12.0


#: a response level clipped onto a bound must stay this many steps from the anchor; one that
#: would lie closer goes beyond the other level instead (both levels on one side)
MIN_LEVEL_STEPS = 0.5
#: an open bound (restitution's 0: the config needs C_R > 0) is kept this many steps inside
OPEN_BOUND_STEPS = 0.01


def _level_ok(p, v) -> bool:
    """The run config accepts ``v`` for base parameter ``p`` (its bounds and its own checks,
    e.g. restitution in (0, 1])."""
    from yade_scripts.twin_config import ConfigError, complete_config
    try:
        complete_config({p: v})
    except ConfigError:
        return False
    return True


def response_levels(p, ref, step=None) -> tuple:
    """The two response levels of base parameter ``p`` about the anchor value ``ref``.

    ``ref -+ step`` (default :data:`BASE_STEPS`), rounded to 4 digits, kept inside the run
    config's bounds (``yade_scripts/twin_config.py`` PARAMETERS; an open bound is kept
    :data:`OPEN_BOUND_STEPS` steps inside): a level beyond a bound is clipped onto it, and one
    that then lies closer than :data:`MIN_LEVEL_STEPS` steps to the anchor moves one step
    beyond the other level (an anchor on a bound: levels at +1 and +2 steps). The response is
    the quadratic through the three real points (:func:`_poly_response` takes them as they are,
    asymmetric or on one side), so no config outside the bounds is ever built.

    Raises ValueError when ``ref`` itself lies outside the bounds or the bounds leave no room
    for two levels.
    """
    from yade_scripts.twin_config import PARAMETERS
    step = float(BASE_STEPS[p] if step is None else step)
    ref = float(ref)
    lo_b, hi_b = PARAMETERS[p][1], PARAMETERS[p][2]
    lo = lo_b if _level_ok(p, lo_b) else lo_b + OPEN_BOUND_STEPS * step
    hi = hi_b if _level_ok(p, hi_b) else hi_b - OPEN_BOUND_STEPS * step
    if not _level_ok(p, ref):
        raise ValueError("the anchor's %s = %g lies outside the run config's bounds [%g, %g]"
                         % (p, ref, lo_b, hi_b))
    lo, hi = min(lo, ref), max(hi, ref)
    gap = MIN_LEVEL_STEPS * step
    down = max(ref - step, lo)
    up = min(ref + step, hi)
    down = down if ref - down >= gap else None
    up = up if up - ref >= gap else None
    if down is None and up is not None:
        down, up = up, min(ref + 2.0 * step, hi)
        if up - down < gap:
            up = None
    elif up is None and down is not None:
        down, up = max(ref - 2.0 * step, lo), down
        if up - down < gap:
            down = None
    if down is None or up is None:
        raise ValueError("the run config's bounds [%g, %g] of %s leave no room for two response "
                         "levels %g apart about %g" % (lo_b, hi_b, p, gap, ref))
    return tuple(min(max(float("%.4g" % v), lo), hi) for v in (down, up))


def run_wall_s(base_config=None, runs_dir=None) -> float:
    """The planner's wall time per run for runs with ``base_config`` (its frame): the median
    of this machine's own latest runs in that frame (:func:`analysis.sweep.cached_wall_s`:
    the machine, its load and the scene as they are now), else the committed constants."""
    from analysis.sweep import cached_wall_s
    jar = (base_config or {}).get("frame") in ("jar", "auto")
    measured = cached_wall_s("jar" if jar else "lab", runs_dir)
    if measured is not None:
        return measured
    return RUN_WALL_S_JAR if jar else RUN_WALL_S


#: base parameters fitted with a Gaussian prior (the Table-3 calibration's posterior mean and
#: sd): material constants of steel on PMMA whose response in a mill is weak and noisy, so that
#: without a prior a fit pushes them to their bounds on noise
PRIOR_PARAMS = ("static_friction", "rolling_friction")
#: the pseudo-condition under which a prior enters the observations
PRIOR_ID = "prior"


def calibration_prior(calibration_dir=None) -> dict:
    """{name: (mean, sd)} of :data:`PRIOR_PARAMS` from the calibration's summary.json."""
    import json
    from analysis.config import CALIBRATION_DIR
    s = json.loads((Path(calibration_dir or CALIBRATION_DIR) / "summary.json").read_text())
    return {k: (float(s["params"][k]), float(s["stderr"][k])) for k in PRIOR_PARAMS}


class BudgetError(RuntimeError):
    """The build needs more twin runs than the budget allows (the message says how many)."""


def known_run_table(results_dir=None) -> pd.DataFrame:
    """Results of real twin runs committed in the repository, indexed by run id: the signature
    library's runs and every ``model_runs.csv`` / ``rerun_runs.csv`` under results/ (the loop
    writes them per dataset). The FAKE twin's runs (motion_mode 'fake') are left out."""
    from analysis.config import RESULTS_DIR
    root = Path(results_dir or RESULTS_DIR)
    files = [root / "signatures" / "signature_runs.csv"]
    skip = (root / "runs", root / "runs_fake")
    files += sorted(p for pat in ("**/model_runs.csv", "**/rerun_runs.csv")
                    for p in root.glob(pat) if not any(q in p.parents for q in skip))
    parts = []
    for f in files:
        if f.is_file():
            try:
                d = pd.read_csv(f)
            except (OSError, pd.errors.ParserError, pd.errors.EmptyDataError):
                continue
            if "run_id" in d.columns and "v_mean_m_s" in d.columns:
                parts.append(d)
    if not parts:
        return pd.DataFrame()
    d = pd.concat(parts, ignore_index=True)
    if "motion_mode" in d.columns:
        d = d[d["motion_mode"].astype(str) != "fake"]
    d = d.drop_duplicates("run_id", keep="last").set_index("run_id")
    from analysis.flights import FLIGHT_OBSERVABLES
    keep = [c for c in ("v_mean_m_s", "v_mean_jar_m_s", "f_col_hz", "motion_mode",
                        *FLIGHT_OBSERVABLES) if c in d.columns]
    return d[keep]


def condition_configs(phys, theta, seed, base_config=None, effects=None):
    """Run config of one condition: ``base_config``, the base parameters ``theta``, the
    condition's frequency, ball and (when stated) stroke, the seed and the effects
    (:func:`analysis.run_configs.condition_config`, ball in mm, the stated stroke honoured)."""
    return condition_config(phys, theta, seed, base_config, effects, stated_stroke=True)


class OpenTwinModel(TwinModel):
    """predict(theta, effects) for diagnose from twin runs at the dataset's own conditions.

    Follows the estimator contract: ``__init__`` stores, :meth:`fit` runs (cached) and assembles;
    fitted state ends in ``_``. The prediction, model_se and yield logic are those of
    :class:`analysis.twin_model.TwinModel` (the same observables and keys); what differs is where
    the numbers come from.

    Parameters
    ----------
    conditions : DataFrame - the dataset's conditions (condition_id, frequency_hz,
        ball_diameter_mm [, amplitude_mm, n_balls])
    yield_times_min : dict condition_id -> yield times [min]
    theta_ref : dict - anchor parameters (default: the calibration's posterior mean)
    base : names of the base parameters to calibrate (subset of :data:`DEFAULT_BASE`)
    velocity_frame : {'lab', 'jar'} - the frame of the measured v_mean
    flight_conditions : condition ids with a jar track (impact observables predicted there)
    replicates : anchor seeds per condition
    diff_replicates : seeds per base / effect level (the anchor's first seeds: common starts)
    noisy_replicates : seeds per level of the :data:`NOISY_BASE` parameters (default
        ``replicates``; the loop's scout build uses fewer)
    effect_names : DEM candidates to build (default: all of the catalog)
    base_config : dict - further run-config keys of every run (e.g. record_s, a jar STL)
    runner, workers, backend, runs_dir, progress, scheduler, slurm : passed to
        :func:`analysis.sweep.run_sweep`
    budget_runs : int or None - refuse a build that needs more new runs than this
    seed0 : int - first seed (seeds seed0 .. seed0 + replicates - 1)
    known_runs : DataFrame indexed by run_id, None, or 'auto' - results of runs made before
        (committed tables, :func:`known_run_table`): a planned run found there is not rerun.
        'auto': the committed tables with the real twin, none with another runner.
    priors : dict {name: (mean, sd)}, None or 'auto' - Gaussian priors of base parameters,
        entered as pseudo-observations (condition :data:`PRIOR_ID`, see
        :meth:`prior_observations`); 'auto': :func:`calibration_prior` (the frictions)
    """

    def __init__(self, conditions, yield_times_min=None, theta_ref=None, base=DEFAULT_BASE,
                 velocity_frame="lab", flight_conditions=(), replicates=3, diff_replicates=2,
                 noisy_replicates=None, effect_names=None, base_config=None, runner=None, workers=2, backend="local",
                 runs_dir=None, progress=True, scheduler=None, slurm=None, budget_runs=None,
                 seed0=0, known_runs="auto", priors="auto"):
        if velocity_frame not in ("lab", "jar"):
            raise ValueError("velocity_frame must be 'lab' or 'jar', got %r" % (velocity_frame,))
        unknown = set(base) - set(BASE_STEPS)
        if unknown:
            raise ValueError("unknown base parameter(s) %s (known: %s)"
                             % (sorted(unknown), ", ".join(BASE_STEPS)))
        if int(replicates) < 1 or int(diff_replicates) < 1:
            raise ValueError("replicates and diff_replicates must be >= 1")
        self.phys = physics_table(conditions)
        self.conditions = conditions.reset_index(drop=True)
        self.yield_times_min = {k: list(v) for k, v in (yield_times_min or {}).items()}
        self.theta_ref = dict(theta_ref or reference_parameters())
        self.base_requested = tuple(base)
        self.velocity_frame = velocity_frame
        cids = list(self.conditions["condition_id"])
        unknown = set(flight_conditions or ()) - set(cids)
        if unknown:
            raise ValueError("flight conditions %s are not among the conditions" % sorted(unknown))
        self.flight_conditions = [c for c in cids if c in set(flight_conditions or ())]
        self.replicates = int(replicates)
        self.diff_replicates = min(int(diff_replicates), int(replicates))
        self.noisy_replicates = (self.replicates if noisy_replicates is None
                                 else min(int(noisy_replicates), self.replicates))
        if self.noisy_replicates < 1:
            raise ValueError("noisy_replicates must be >= 1")
        dem = candidates("dem")
        names = (list(effect_names) if effect_names is not None
                 else [c.name for c in CANDIDATES if c.kind == "dem"])
        bad = [n for n in names if n not in dem]
        if bad:
            raise ValueError("unknown DEM candidate(s) %s" % bad)
        self.effect_names = tuple(names)
        self.base_config = dict(base_config or {})
        self.sweep_kw = dict(runner=runner, workers=workers, backend=backend, runs_dir=runs_dir,
                             progress=progress, scheduler=scheduler, slurm=slurm)
        self.budget_runs = budget_runs
        self.seed0 = int(seed0)
        if isinstance(known_runs, str) and known_runs == "auto":
            known_runs = known_run_table() if runner is None else None
        self.known_runs = known_runs
        self.priors = calibration_prior() if isinstance(priors, str) else dict(priors or {})
        self.patterns = {}

    # ------------------------------------------------------------------ the plan
    def _stated_amplitude(self, i):
        return stated_amplitude_m(self.phys.iloc[i]) is not None

    def base_seeds(self, p) -> int:
        """Seeds per response level of base parameter ``p`` (:data:`NOISY_BASE`:
        ``noisy_replicates``, by default all ``replicates``; the others ``diff_replicates``)."""
        return self.noisy_replicates if p in NOISY_BASE else self.diff_replicates

    def plan(self, stage="all") -> pd.DataFrame:
        """Every run the model needs: role ('anchor', 'base', 'effect'), name, value (parameter
        value or effect strength), condition_id, seed, config; one row per run."""
        rows = []
        ref = self.theta_ref
        for i, ph in enumerate(self.phys.to_dict("records")):
            cid = ph["condition_id"]
            for k in range(self.replicates):
                rows.append(("anchor", "", 0.0, cid, self.seed0 + k,
                             condition_configs(ph, ref, self.seed0 + k, self.base_config)))
            for p in self.base_requested:
                if p == "amplitude_m" and self._stated_amplitude(i):
                    continue
                for v in response_levels(p, ref[p]):
                    for k in range(self.base_seeds(p)):
                        rows.append(("base", p, v, cid, self.seed0 + k, condition_configs(
                            ph, dict(ref, **{p: v}), self.seed0 + k, self.base_config)))
            if stage == "all":
                for name in self.effect_names:
                    c = candidates("dem")[name]
                    for fr in EFFECT_LEVELS:
                        s = fr * c.s_max
                        for k in range(self.diff_replicates):
                            rows.append(("effect", name, s, cid, self.seed0 + k,
                                         condition_configs(ph, ref, self.seed0 + k,
                                                           self.base_config, c.spec(s))))
        return pd.DataFrame(rows, columns=["role", "name", "value", "condition_id", "seed",
                                           "config"])

    def plan_summary(self, stage="all", plan=None) -> dict:
        """{'runs': n, 'cached': n, 'new': n, 'est_wall_s': s} of :meth:`plan`, the wall time
        estimated for the sweep's workers at :func:`run_wall_s` per run."""
        from analysis.config import RUNS_DIR
        from analysis.sweep import prepare_configs
        plan = self.plan(stage) if plan is None else plan
        _, ids = prepare_configs(list(plan["config"]))
        root = Path(self.sweep_kw["runs_dir"] or RUNS_DIR)
        uniq = dict.fromkeys(ids)
        known = set(self._known_for(pd.DataFrame({"run_id": ids, "condition_id":
                                                  list(plan["condition_id"])})).index)
        cached = sum((r in known) or (root / r / "meta.json").exists() for r in uniq)
        new = len(uniq) - cached
        w = max(int(self.sweep_kw["workers"] or 1), 1)
        return {"runs": len(uniq), "cached": cached, "new": new,
                "est_wall_s": math.ceil(new / w) * run_wall_s(self.base_config, root)}

    # ------------------------------------------------------------------ build
    def fit(self, stage="all"):
        """Run what :meth:`plan` lists (cached runs are read, not rerun) and assemble the model.

        Raises
        ------
        BudgetError
            more new runs than ``budget_runs`` (nothing is run)
        RuntimeError
            a twin run failed (its id and error in the message; finished runs stay cached)
        """
        from analysis.flights import FLIGHT_OBSERVABLES
        from analysis.sweep import prepare_configs, run_sweep
        from analysis.twin_model import run_flights
        plan = self.plan(stage)
        ps = self.plan_summary(stage, plan)
        if self.budget_runs is not None and ps["new"] > self.budget_runs:
            raise BudgetError("the model needs %d new twin runs (%d cached of %d), the budget "
                              "is %d: raise --budget-runs or cut conditions / replicates"
                              % (ps["new"], ps["cached"], ps["runs"], self.budget_runs))
        t0 = time.time()
        _, ids = prepare_configs(list(plan["config"]))
        runs = plan.drop(columns=["config"]).copy()
        runs["run_id"] = ids
        known = self._known_for(runs)
        todo = ~runs["run_id"].isin(known.index)
        cols = ["v_mean_m_s", "v_mean_jar_m_s", "f_col_hz", "motion_mode"]
        for c in cols + list(FLIGHT_OBSERVABLES):
            runs[c] = np.nan
        runs["motion_mode"] = runs["motion_mode"].astype(object)
        if len(known):
            k = known.reindex(runs.loc[~todo, "run_id"])
            for c in cols + list(FLIGHT_OBSERVABLES):
                if c in k.columns:
                    runs.loc[~todo, c] = k[c].to_numpy()
        if todo.any():
            res = run_sweep(list(plan.loc[todo, "config"]), **self.sweep_kw)
            if not res.ok:
                raise RuntimeError("%d twin run(s) failed:\n%s" % (
                    res.n_failed, res.failed()[["run_id", "error"]].to_string()))
            t = res.table.reset_index(drop=True)
            for c in cols:
                if c in t.columns:
                    runs.loc[todo, c] = t[c].to_numpy()
            at = todo & runs["condition_id"].isin(self.flight_conditions)
            if at.any():
                fl = run_flights(list(runs.loc[at, "run_id"]), self.sweep_kw["runs_dir"])
                for c in FLIGHT_OBSERVABLES:
                    runs.loc[at, c] = fl[c].to_numpy(float)
        self.runs_ = runs
        self.n_new_ = int(ps["new"])
        self.n_known_ = int((~todo).sum())
        self.build_s_ = time.time() - t0
        self.stage_ = stage
        self._assemble_model(runs)
        return self

    def _known_for(self, runs) -> pd.DataFrame:
        """Known results of planned runs (indexed by run id) from ``known_runs``, usable only
        where they hold every column this model needs (the jar-frame speed for a 'jar'
        dataset, the impact observables at a condition with a jar track)."""
        k = self.known_runs
        if k is None or not len(k):
            return pd.DataFrame()
        k = k[k.index.isin(runs["run_id"])]
        need = ["v_mean_m_s", "f_col_hz"] + (["v_mean_jar_m_s"] if self.velocity_frame == "jar"
                                             else [])
        ok = pd.Series(True, index=k.index)
        for c in need:
            ok &= k[c].notna() if c in k.columns else False
        if self.flight_conditions:
            from analysis.flights import FLIGHT_OBSERVABLES
            at = set(runs.loc[runs["condition_id"].isin(self.flight_conditions), "run_id"])
            has = (k[list(FLIGHT_OBSERVABLES)].notna().any(axis=1)
                   if all(c in k.columns for c in FLIGHT_OBSERVABLES)
                   else pd.Series(False, index=k.index))
            # a run in another motion mode has no impact observables: NaN is its value there
            has |= k.get("motion_mode", pd.Series("", index=k.index)).ne("end_to_end")
            ok &= ~k.index.isin(list(at)) | has
        return k[ok]

    # ------------------------------------------------------------------ assembly
    def _assemble_model(self, runs):
        from analysis.flights import FLIGHT_OBSERVABLES
        cids = list(self.conditions["condition_id"])
        vcol = "v_mean_m_s" if self.velocity_frame == "lab" else "v_mean_jar_m_s"
        if runs[vcol].isna().all():
            raise ValueError("the twin runs carry no %s: the jar-frame speed needs recordings "
                             "with it" % vcol)
        self.dem_cols = ["v_mean_m_s", "f_col_hz", "v_mean_jar_m_s"]
        self.flight_obs = tuple(FLIGHT_OBSERVABLES)
        cols = self.dem_cols + (list(self.flight_obs) if self.flight_conditions else [])
        key = ["role", "name", "value", "condition_id"]
        # replicate sd per condition: pooled (weighted by dof) over the groups of >= 2 seeds
        # of the anchor and the base responses there - not the effect levels, whose strong
        # effects can make the flight bistable (one jar-compliance level at 28 Hz scattered
        # v_in by 2.3 m/s and, pooled in, made every impact observable there uninformative)
        own = runs[runs["role"].isin(["anchor", "base"])]
        g = own.groupby(key, sort=False)[cols]
        dof = (g.count() - 1).clip(lower=0)
        ss = (g.var().fillna(0.0) * dof)
        pooled = (ss.groupby(level="condition_id").sum()
                  / dof.groupby(level="condition_id").sum().replace(0, np.nan)).reindex(cids)
        anc = runs[runs["role"] == "anchor"].groupby("condition_id")[cols].mean().reindex(cids)
        if anc[["v_mean_m_s", "f_col_hz"]].isna().any().any():
            raise RuntimeError("the anchor has no usable run at some condition")
        self.anchor_ = anc[cols].to_numpy(float)
        self.anchor = self.anchor_[:, :2]              # lab v, f_col (TwinModel's contract)
        self.n_rep = float(self.replicates)
        v_rel = np.sqrt(pooled[vcol].to_numpy(float)) / anc[vcol].to_numpy(float)
        self.v_rel_sd_cond = np.fmax(np.nan_to_num(v_rel), V_REL_SD_FLOOR)
        self.v_rel_sd = float(np.sqrt(np.mean(self.v_rel_sd_cond ** 2)))
        self.f_col_sd_hz = np.fmax(np.nan_to_num(np.sqrt(pooled["f_col_hz"].to_numpy(float))),
                                   F_COL_SD_FLOOR_HZ)
        sd = np.sqrt(np.nan_to_num(pooled[cols].to_numpy(float)))
        floors = np.array([F_COL_SD_FLOOR_HZ if c == "f_col_hz" else
                           FLIGHT_SD_FLOORS.get(c, 0.0) for c in cols])
        self.col_sd_ = np.fmax(sd, floors)
        self.col_sd_[:, 0] = self.v_rel_sd_cond * anc["v_mean_m_s"].to_numpy(float)
        self.col_sd_[:, 2] = self.v_rel_sd_cond * anc["v_mean_jar_m_s"].to_numpy(float)
        self.cols_ = cols
        if self.flight_conditions:
            self.fl_sd_cond = self.col_sd_[:, 3:]
        # same-seed differences from the anchor (common starts)
        anc_by_seed = runs[runs["role"] == "anchor"].set_index(["condition_id", "seed"])[cols]

        self.log_cols_ = np.array([c in LOG_RESPONSE for c in cols])

        def diff_means(role, name):
            """{(value, condition): (mean change from the anchor's same seeds, n)}; for a base
            parameter the :data:`LOG_RESPONSE` columns change in log (relative) terms."""
            d = runs[(runs["role"] == role) & (runs["name"] == name)]
            out = {}
            for (val, cid), grp in d.groupby(["value", "condition_id"], sort=True):
                base = anc_by_seed.loc[[(cid, s) for s in grp["seed"]]].to_numpy(float)
                lev = grp[cols].to_numpy(float)
                ch = lev - base
                if role == "base" and self.log_cols_.any():
                    L = self.log_cols_
                    with np.errstate(divide="ignore", invalid="ignore"):
                        ch[:, L] = np.log(np.fmax(lev[:, L], 1e-12) / np.fmax(base[:, L], 1e-12))
                with warnings.catch_warnings():     # a column no run of the group has: NaN
                    warnings.simplefilter("ignore", RuntimeWarning)
                    out[(float(val), cid)] = (np.nanmean(ch, axis=0), len(grp))
            return out

        cid_has_flights = [c in self.flight_conditions for c in cids]
        # the motion mode most of the anchor's runs move in, and per group of runs the share
        # moving in it: a level where fewer than half do lies across a bifurcation
        mm = runs.assign(motion_mode=runs["motion_mode"].fillna(""))
        anchor_mode = (mm[mm["role"] == "anchor"].groupby("condition_id")["motion_mode"]
                       .agg(lambda m: m.value_counts().index[0]).to_dict())
        share = mm.assign(same=[m == anchor_mode.get(c, "") for m, c in
                                zip(mm["motion_mode"], mm["condition_id"])]).groupby(
            ["role", "name", "value", "condition_id"], sort=False)["same"].mean()

        def mode_jumps(key):
            return bool(share.get(key, 1.0) < 0.5)

        # base responses: per parameter, per condition points (x - ref, change)
        self.base_resp_ = {}
        self.held_ = {}
        self.response_z_ = {}
        for p in self.base_requested:
            dm = diff_means("base", p)
            pts = []
            for i, cid in enumerate(cids):
                xs = sorted(v for (v, c) in dm if c == cid)
                if not xs:
                    pts.append(None)           # stroke stated at this condition: not fitted
                    continue
                x = np.array([0.0] + [v - self.theta_ref[p] for v in xs])
                ds = np.vstack([np.zeros(len(cols))] + [dm[(v, cid)][0] for v in xs])
                o = np.argsort(x)
                # a level whose runs move in another motion mode than the anchor's: the
                # response jumps somewhere between them (a bifurcation), not smoothly
                jump = np.array([False] + [mode_jumps(("base", p, v, cid)) for v in xs])
                pts.append((x[o], ds[o], jump[o]))
            # how far the response stands out of the twin's noise: a chi-square over every
            # condition and observable of the measured changes against the noise of a
            # difference of two means of the level's seeds, z = (T - n) / sqrt(2 n)
            T, n = 0.0, 0
            for i, pt in enumerate(pts):
                if pt is None:
                    continue
                noise = self.col_sd_[i] * math.sqrt(2.0 / self.base_seeds(p))
                noise = np.where(self.log_cols_, noise / np.abs(self.anchor_[i]), noise)
                used = [2 if self.velocity_frame == "jar" else 0, 1] + list(
                    range(3, len(cols)) if cid_has_flights[i] else [])
                with np.errstate(divide="ignore", invalid="ignore"):   # noise-free columns
                    r = pt[1][pt[0] != 0][:, used] / noise[used]
                r = r[np.isfinite(r)]
                T += float(np.sum(r ** 2))
                n += r.size
            self.response_z_[p] = (T - n) / math.sqrt(2.0 * n) if n else float("nan")
            if all(pt is None for pt in pts):
                self.held_[p] = "stated by the dataset at every condition"
            else:
                self.base_resp_[p] = pts
        self.base_names = tuple(p for p in self.base_requested if p in self.base_resp_)
        # effect responses, in the strength coordinate, through (0, 0)
        self.sig_all_ = {}
        self.sig_noise_ = {}
        for name in self.effect_names:
            dm = diff_means("effect", name)
            if not dm:
                continue
            sig, nse = [], []
            for i, cid in enumerate(cids):
                xs = sorted(v for (v, c) in dm if c == cid)
                sig.append((np.array([0.0] + xs),
                            np.vstack([np.zeros(len(cols))] + [dm[(v, cid)][0] for v in xs])))
                nse.append(np.array([0.0] + [math.sqrt(2.0 / dm[(v, cid)][1]) for v in xs]))
            self.sig_all_[name] = sig
            self.sig_noise_[name] = nse
        self.sig_curv_ = {k: [curvatures(xs, ds) for xs, ds in v]
                          for k, v in self.sig_all_.items()}
        # TwinModel's attributes that predict / model_se read
        self.sig = {k: None for k in self.sig_all_}
        self._init_keys()
        self._gp_cache = {}

    @property
    def held(self) -> dict:
        """Base parameters held at the anchor, with the reason."""
        return dict(self.held_)

    # ------------------------------------------------------------------ evaluation
    def _base_points(self, theta):
        """(condition index, response points (xs, changes, jump flags), offset dx, parameter)
        of every base parameter moved from the anchor in ``theta``, at every condition where
        it acts."""
        for p, pts in self.base_resp_.items():
            dx = float(theta.get(p, self.theta_ref[p])) - self.theta_ref[p]
            if dx == 0.0:
                continue
            for i, pt in enumerate(pts):
                if pt is not None:
                    yield i, pt, dx, p

    def _base_change(self, theta):
        y = np.zeros_like(self.anchor_)
        for i, pt, dx, _ in self._base_points(theta):
            y[i] += _response(pt, pt[1], dx)
        return y

    def _base_outputs(self, theta):
        """(n_cond, n_cols) the model without effects at ``theta``: the anchor plus the base
        responses (times their exp for the :data:`LOG_RESPONSE` columns)."""
        bc = self._base_change(theta)
        y = self.anchor_ + bc
        L = self.log_cols_
        if L.any():
            y[:, L] = self.anchor_[:, L] * np.exp(bc[:, L])
        return y

    def outputs(self, theta, effects=None):
        """(n_cond, n_cols) all model columns (lab v, f_col, frame v, impact observables)."""
        y = self._base_outputs(theta)
        for name, s in (effects or {}).items():
            if name in self.sig_all_ and s:
                y = y + interp_levels(self.sig_all_[name], float(s))
        return y

    def dem_outputs(self, theta, effects=None):
        return self.outputs(theta, effects)[:, :2]

    def flight_outputs(self, theta, effects=None):
        return self.outputs(theta, effects)[:, 3:]

    def predict(self, theta, effects=None):
        out = super().predict(theta, effects)
        if self.velocity_frame == "jar":
            v = self.outputs(theta, effects)[:, 2]
            for i, cid in enumerate(self.conditions["condition_id"]):
                out[(cid, "v_mean_m_s")] = v[i]
        return self._with_priors(out, {p: float(theta.get(p, self.theta_ref[p]))
                                       for p in self.prior_names})

    @property
    def prior_names(self):
        """Fitted base parameters that carry a prior."""
        return [p for p in getattr(self, "base_names", ()) if p in self.priors]

    def _with_priors(self, series, values):
        if not self.prior_names:
            return series
        extra = pd.Series([values.get(p, 0.0) for p in self.prior_names],
                          index=pd.MultiIndex.from_tuples([(PRIOR_ID, p)
                                                           for p in self.prior_names],
                                                          names=series.index.names))
        return pd.concat([series, extra])

    def prior_observations(self) -> pd.DataFrame:
        """The priors as observations (condition_id 'prior', observable = the parameter,
        value = the prior mean, sd = the prior sd): a fit with them maximises the posterior."""
        return pd.DataFrame({"condition_id": PRIOR_ID, "observable": self.prior_names,
                             "value": [self.priors[p][0] for p in self.prior_names],
                             "sd": [self.priors[p][1] for p in self.prior_names]})

    def model_se(self, theta=None):
        """The anchor mean's standard error per key and, away from the anchor, the noise the
        measured base responses carry there (their level means are means of diff_replicates
        runs: the quadratic's weights on them times their noise), in quadrature; 0 for the
        priors' pseudo-observations."""
        return self._with_priors(self._model_se(theta), {})

    def _model_se(self, theta=None):
        se = super().model_se(theta)
        if self.velocity_frame == "jar":
            for i, cid in enumerate(self.conditions["condition_id"]):
                se[(cid, "v_mean_m_s")] = self.col_sd_[i, 2] / math.sqrt(self.n_rep)
        if theta is None:
            return se
        # the prediction is A_R + sum_k w_k (L_k - A_n(k)): the anchor mean of R seeds plus
        # each response level's mean of n(k) runs minus the anchor's mean over the same first
        # n(k) seeds (the chaos of 0.5 s decorrelates same-seed runs, so these are noise, not
        # common numbers). Its variance per unit run variance, beyond the anchor's 1 / R:
        #   sum_k w_k^2 / n(k) + sum_p,q W_p W_q / max(n_p, n_q) - 2 sum_p W_p / R
        # (W_p: the summed weights of parameter p's levels); it is below zero where the
        # levels' own runs replace part of the anchor's noise
        n = len(self.conditions)
        sq = np.zeros(n)
        wsum = [dict() for _ in range(n)]
        jump = np.zeros((n, len(self.cols_)))
        for i, pt, dx, p in self._base_points(theta):
            xs = pt[0]
            w = _response(pt, np.eye(len(xs)), dx)               # weight of each point
            w = np.where(xs == 0.0, 0.0, w)                      # the anchor's own: in se
            k = self.base_seeds(p)
            sq[i] += float(np.sum(w ** 2)) / k
            wsum[i][k] = wsum[i].get(k, 0.0) + float(np.sum(w))
            jump[i] += _jump_var(pt, dx)
        c = sq.copy()
        for i in range(n):
            for ka, wa in wsum[i].items():
                c[i] -= 2.0 * wa / self.n_rep
                for kb, wb in wsum[i].items():
                    c[i] += wa * wb / max(ka, kb)
        # a log-space column's changes are relative: scale its run sd (and its jumps, which are
        # log changes) to the prediction there
        y = self._base_outputs(theta)
        L = self.log_cols_
        sd_run = self.col_sd_.copy()
        if L.any():
            ratio = np.abs(y[:, L]) / np.abs(self.anchor_[:, L])
            sd_run[:, L] = sd_run[:, L] * np.nan_to_num(ratio, nan=1.0)
            jump[:, L] = jump[:, L] * y[:, L] ** 2
        unit = self._series(sd_run) ** 2                         # one run's variance per key
        cond = unit.index.get_level_values(0)
        ci = pd.Series(c, index=list(self.conditions["condition_id"]))
        extra = unit * ci.reindex(cond).to_numpy() + self._series(np.sqrt(jump)) ** 2
        var = se ** 2 + extra.reindex(se.index).fillna(0.0)
        return np.sqrt(np.maximum(var, 0.0))

    def _series(self, sd):
        """A per-key Series from per-(condition, column) sds, propagated to the yields through
        E_tot = m v^2 f_col t / 2 at the anchor (as model_se does)."""
        from analysis.kinetics import PAPER_SLOPE_PCT_PER_KJ as slope
        out = []
        vi = 2 if self.velocity_frame == "jar" else 0
        for i, cid in enumerate(self.conditions["condition_id"]):
            v, f = self.anchor_[i, :2]
            out += [sd[i, vi], sd[i, 1]]
            m = self.mass_kg[i]
            for t in self.yield_times_min.get(cid, []):
                out.append(abs(slope) * t * 60.0 / 1000.0
                           * math.hypot(m * v * f * sd[i, 0], 0.5 * m * v * v * sd[i, 1]))
            if cid in self.flight_conditions:
                out += list(sd[i, 3:])
        return pd.Series(out, index=self.keys)

    def resolution_se(self, effects):
        """Interpolation error between the effect levels plus the level means' own noise (a
        level is a mean of ``diff_replicates`` runs minus the anchor's same seeds), summed in
        quadrature over the effects on; propagated to the yields as the model_se is."""
        n = len(self.conditions)
        var = np.zeros((n, len(self.cols_)))
        for name, st in (effects or {}).items():
            if name not in self.sig_all_ or not st:
                continue
            st = float(st)
            var += interp_sd(self.sig_all_[name], self.sig_curv_[name], st) ** 2
            w = _level_weights(self.sig_all_[name], st)
            for i in range(n):
                nv = float(np.sum((w[i] * self.sig_noise_[name][i]) ** 2))
                var[i] += nv * self.col_sd_[i] ** 2
        return self._with_priors(self._series(np.sqrt(var)), {})

    def base_params(self):
        """diagnose BaseParameters: the fitted DEM base parameters (those not held) and, with
        yields, the powder line's slope and intercept."""
        return super().base_params()

    def effects(self):
        """diagnose Effects: the built DEM candidates, and the kinetics ones with yields."""
        from analysis.diagnose import Effect
        out = []
        for c in CANDIDATES + OPTIONAL_CANDIDATES:
            if c.kind == "kinetics" and not self.has_yields:
                continue
            if c.kind == "dem" and c.name not in self.sig_all_:
                continue
            out.append(Effect(c.name, 0.0, c.s_max, null=0.0, kind=c.kind,
                              description="strength = %s" % c.strength_label))
        return out

    def outside(self, theta) -> dict:
        """{parameter: offset from the anchor in steps} of the base parameters in ``theta``
        that lie more than :data:`EXTRAPOLATE_STEPS` beyond the measured response points
        (where the model would extrapolate further: re-anchor there)."""
        out = {}
        for p, pts in self.base_resp_.items():
            dx = float(theta.get(p, self.theta_ref[p])) - self.theta_ref[p]
            xs = [pt[0] for pt in pts if pt is not None]
            tol = EXTRAPOLATE_STEPS * BASE_STEPS[p]
            lo = min(x[0] for x in xs) - tol
            hi = max(x[-1] for x in xs) + tol
            if dx < lo - 1e-12 or dx > hi + 1e-12:
                out[p] = dx / BASE_STEPS[p]
        return out

    def flight_run_sd(self):
        rows, vals = [], []
        for i, cid in enumerate(self.conditions["condition_id"]):
            if cid in self.flight_conditions:
                rows += [(cid, k) for k in self.flight_obs]
                vals += list(self.col_sd_[i, 3:])
        return pd.Series(vals, index=pd.MultiIndex.from_tuples(
            rows, names=["condition_id", "observable"]), dtype=float)


def _jump_side(pt, dx):
    """Index of the response point on ``dx``'s side of the anchor when that level lies in
    another motion mode (a jump between them), else None."""
    xs, _, jump = pt
    k = 0 if dx < 0 else len(xs) - 1
    return k if (xs[k] != 0.0 and np.sign(xs[k]) == np.sign(dx) and jump[k]) else None


def _response(pt, ds, dx):
    """Change at offset ``dx`` from response points ``pt`` = (xs, changes, jump) with the rows
    ``ds``: :func:`_poly_response` where the levels move in the anchor's motion mode. Towards
    a level in another mode the response is a jump at an unknown place between them: its
    mean, the jump times the chance it happened by ``dx`` (uniform between the anchor and the
    level: linear up to the level, flat beyond); the other side is then the line through the
    anchor and its own level (the jumped level must not bend it)."""
    xs, _, jump = pt
    if not np.any(jump):
        return _poly_response(xs, ds, dx)
    k = _jump_side(pt, dx)
    if k is not None:
        return ds[k] * min(dx / xs[k], 1.0)
    other = [j for j in range(len(xs)) if xs[j] != 0.0 and np.sign(xs[j]) == np.sign(dx)]
    if not other:
        return 0.0 * ds[0]
    return ds[other[0]] * (dx / xs[other[0]])


def _jump_var(pt, dx):
    """Variance the unknown place of a jump adds at ``dx`` (a Bernoulli of probability
    p = dx / x_level times the jump: D^2 p (1 - p)); 0 where no jump lies on dx's side."""
    k = _jump_side(pt, dx)
    if k is None:
        return 0.0
    q = min(dx / pt[0][k], 1.0)
    return np.nan_to_num(pt[1][k] ** 2) * q * (1.0 - q)


def _poly_response(xs, ds, dx):
    """Change at offset ``dx`` from points (xs ascending, ds rows): the quadratic through three
    points (the line through two) inside [xs[0], xs[-1]], extended linearly with its end slope."""
    if len(xs) == 2:
        return ds[1] * (dx / xs[1]) if xs[1] != 0 else ds[0] * (dx / xs[0])
    x0, x1, x2 = xs
    lo, hi = x0, x2

    def quad(x):
        l0 = (x - x1) * (x - x2) / ((x0 - x1) * (x0 - x2))
        l1 = (x - x0) * (x - x2) / ((x1 - x0) * (x1 - x2))
        l2 = (x - x0) * (x - x1) / ((x2 - x0) * (x2 - x1))
        return l0 * ds[0] + l1 * ds[1] + l2 * ds[2]

    def slope(x):
        d0 = (2 * x - x1 - x2) / ((x0 - x1) * (x0 - x2))
        d1 = (2 * x - x0 - x2) / ((x1 - x0) * (x1 - x2))
        d2 = (2 * x - x0 - x1) / ((x2 - x0) * (x2 - x1))
        return d0 * ds[0] + d1 * ds[1] + d2 * ds[2]

    if dx < lo:
        return quad(lo) + slope(lo) * (dx - lo)
    if dx > hi:
        return quad(hi) + slope(hi) * (dx - hi)
    return quad(dx)


def _level_weights(sig, s):
    """(n_cond, k) weights of each level in :func:`interp_levels` at strength ``s``."""
    out = []
    for xs, _ in sig:
        w = np.zeros(len(xs))
        if len(xs) == 1:
            w[0] = 1.0
        elif s >= xs[-1]:
            t = (s - xs[-2]) / (xs[-1] - xs[-2])
            w[-2], w[-1] = 1.0 - t, t
        else:
            k = int(np.clip(np.searchsorted(xs, s) - 1, 0, len(xs) - 2))
            t = (s - xs[k]) / (xs[k + 1] - xs[k])
            w[k], w[k + 1] = 1.0 - t, t
        out.append(w)
    return out
