"""The whole loop on a researcher's own dataset: compare, diagnose, add (iterated), twin rerun.

    python -m analysis.loop --dataset DIR --out DIR [--budget-runs N] [--dry-run]

1. **Read** the dataset (``docs/dataset_format.md``; a bad file is one error naming file, row and
   column). Conditions are matched by physics (frequency, ball, stroke where stated), never by
   their ids; the velocity frame is honoured (a 'jar' dataset is compared with the twin's
   jar-frame speed); tracks that carry the jar (``jar_x_m``) add the impact observables.
2. **Build the model at the dataset's conditions** (:class:`analysis.open_model.OpenTwinModel`):
   the plan (runs, how many are cached, estimated wall time) is printed first and checked
   against ``--budget-runs``; twin runs are cached by run id, so a killed loop resumes.
3. **Calibrate** the base parameters (restitution, stroke, the frictions where they move the
   observables) on the dataset. Where the calibrated point lies beyond the model's measured
   responses, **re-anchor** there (new anchor and responses) and calibrate again. The anchor
   is settled on a scout build (anchor and base responses with fewer seeds, the first seeds
   of the whole build's) before the effect responses (about half of the model's runs) are
   built, so these are built once; a final point that leaves the responses after effects
   were added re-anchors the whole model.
4. **Diagnose and add, forward selection**: rank every candidate effect; when one is
   significant, add it (its strength becomes a fitted parameter beside the base ones) and
   diagnose again with the rest, until nothing more is significant (``--max-effects``).
5. **Twin rerun**: the real twin at the final parameters with the effects found switched on
   (fresh seeds), its chi2/dof beside the model's.
6. **Write** one folder (atomically; only a folder this project wrote is ever replaced):

   ========================  ==================================================================
   ``report.md``             the verdict in words, the staircase, the parameters, figures
   ``diagnosis.csv``         one row per candidate: effect, kind, rank, significant, strength,
                             strength_se, delta_chi2, p_bonferroni, identifiable, step
   ``staircase.csv``         stage, chi2, dof, chi2_dof (baseline, calibrated, + each effect,
                             twin rerun)
   ``steps.csv``             every diagnosis step's full ranking (column ``step``)
   ``parameters.csv``        name, role (base / effect / held), value, se
   ``comparison.csv``        per observable: measured, sd, calibrated, final, twin rerun, z
   ``model_runs.csv``        every twin run the model used (role, name, value, condition, seed,
                             run_id, observables); ``rerun_runs.csv`` the twin rerun's
   ``loop.json``             verdict, status, effects found, run counts, wall times
   ``tracking.csv``,         (a dataset with films) each film's tracking quality: frames,
   ``tracks/<id>.csv``       lost frames, re-acquisitions, scale; the tracks made from them
   ``staircase.png``, ``ranking.png``
   ========================  ==================================================================

Example::

    python -m analysis.loop --dataset data/measurements/paper_table3 \\
        --out results/loop/paper_table3 --budget-runs 400
"""
from __future__ import annotations

import os
import signal
import sys

if __name__ == "__main__" and signal.getsignal(signal.SIGINT) is not signal.SIG_IGN:
    # Ctrl-C while the imports below load (seconds): one line and exit 130, no traceback;
    # main() hands Ctrl-C back to Python (KeyboardInterrupt, caught there) once they are in
    def _interrupted_early(signum, frame):
        sys.stderr.write("analysis.loop: interrupted before anything started; nothing "
                         "written\n")
        sys.stderr.flush()
        os._exit(128 + signum)
    signal.signal(signal.SIGINT, _interrupted_early)

import argparse
import dataclasses
import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
from scipy import stats

from analysis.atomic_dir import OutputError, check_out_dir, output_dir
from analysis.conditions import ConditionError, label, physics_table
from analysis.diagnose import BaseParameter, calibrate_base, diagnose
from analysis.measurements import DatasetError, load_dataset
from analysis.open_model import BudgetError, OpenTwinModel, run_wall_s
from analysis.sweep import parse_key_value
from analysis.twin_model import (CANDIDATES, candidates, dataset_observations,
                                 reference_parameters,
                                 with_run_sd, yield_times_of)

#: candidate effects beyond this many are not added (a guard against chasing noise)
MAX_EFFECTS = 3
#: re-anchorings of the model at a calibrated point beyond its measured responses
MAX_REANCHOR = 2
#: the scout build that settles the anchor before the whole model is built: anchor seeds and
#: seeds per response level (the first seeds of the whole build's, so none is wasted when the
#: anchor stays)
SCOUT_REPLICATES, SCOUT_DIFF_REPLICATES = 2, 1
#: twin-corrected refits after the first twin rerun (each moved point gets its own rerun)
MAX_POLISH = 2
#: a twin-corrected refit that moves no parameter by more than this many of its standard
#: errors ends the refits
POLISH_TOL_SE = 0.5
#: the secant of two reruns corrects the model's slope only over a move longer than this many
#: standard errors (over a shorter one the difference of two rerun means is mostly their noise:
#: with 2 seeds a 1-se move turned a visco-elastic strength back from 0.43 to 0.40, truth 0.49)
SECANT_MIN_MOVE_SE = 2.0
#: two candidates whose -2 log L gains differ by less than this are "about as good"
TIE_DELTA_CHI2 = 2.0


@dataclass
class LoopResult:
    """What the loop found (see the module docstring for the files it writes)."""

    status: str                      # 'nothing_missing', 'effects', 'unexplained'
    verdict: str
    effects: dict                    # name -> (strength, se), in the order added
    staircase: pd.DataFrame
    diagnosis: pd.DataFrame
    steps: pd.DataFrame
    parameters: pd.DataFrame
    comparison: pd.DataFrame
    model_runs: pd.DataFrame
    info: dict = field(default_factory=dict)
    diagnoses: list = field(default_factory=list, repr=False)
    tracks: dict = field(default_factory=dict, repr=False)   # tracks made from films
    rerun_runs: pd.DataFrame | None = None                   # the twin rerun's runs


# --------------------------------------------------------------------------- pieces

def fit_observations(obs, model):
    """The observations the model is fitted to: a track is one realisation of a chaotic
    motion, so the sd of its impact observables is at least one twin run's scatter
    (:func:`analysis.twin_model.with_run_sd`); and the priors of the model's base parameters
    as pseudo-observations."""
    pri = getattr(model, "prior_observations", None)
    if pri is not None and len(pri()):
        obs = pd.concat([obs, pri()], ignore_index=True)
    if not model.flight_conditions:
        return obs
    return with_run_sd(obs, model.flight_run_sd())


class WithAdded:
    """The model with the effects already added as fitted parameters (forward selection):
    ``predict(theta, eff)`` reads the added strengths from ``theta``."""

    def __init__(self, model, added, theta=None):
        self.model = model
        self.added = dict(added)
        self.theta = None if theta is None else dict(theta)

    def predict(self, theta, effects=None):
        th = {k: v for k, v in theta.items() if k not in self.added}
        eff = dict(effects or {})
        eff.update({k: theta.get(k, s) for k, s in self.added.items()})
        return self.model.predict(th, eff)

    def model_se(self):
        if getattr(self.model, "state_dependent_se", False):
            # the model's own uncertainty where each fit asks (an emulator's): a callable
            def se_at(theta, effects=None):
                th = {k: v for k, v in theta.items() if k not in self.added}
                eff = dict(effects or {})
                eff.update({k: theta.get(k, s) for k, s in self.added.items()})
                return self.model.model_se(th, eff)
            return se_at
        se = self.model.model_se(self.theta)
        if not self.added:
            return se
        ex = self.model.resolution_se(self.added).reindex(se.index).fillna(0.0)
        return np.sqrt(se ** 2 + ex ** 2)

    def effect_se(self, effects):
        on = dict(self.added)
        on.update(effects or {})
        full = self.model.resolution_se(on)
        if not self.added:
            return full
        have = self.model.resolution_se(self.added)
        return np.sqrt(np.maximum(full ** 2 - have ** 2, 0.0))


def fitted_parameters(model, theta, added):
    """BaseParameters at the current values: the model's, then the added effects' strengths."""
    out = []
    for p in model.base_params():
        out.append(BaseParameter(p.name, float(np.clip(theta.get(p.name, p.value), p.lower,
                                                        p.upper)), p.lower, p.upper))
    effs = {e.name: e for e in model.effects()}
    for name, s in added.items():
        e = effs[name]
        out.append(BaseParameter(name, float(np.clip(s, e.lower, e.upper)), e.lower, e.upper))
    return out


class _Corrected:
    """The model shifted onto the twin's own means at the points it was rerun at:
    predict(p) = model(p) + delta(p), delta_k = rerun(P_k) - model(P_k) at the last point,
    and along the last move (P_k-1 -> P_k, in units of the fit's standard errors ``scale``)
    the secant of the two deltas (a rank-one Broyden correction of the model's slope along
    the direction it was wrong in). The model's error at P_k - the effects' responses were
    measured at the anchor, not at the fitted base parameters, and are interpolated between
    levels - is gone there. Keys the rerun does not predict (the priors) keep the model's."""

    def __init__(self, model, points, scale, added):
        self.w = WithAdded(model, added)               # the strengths read from theta
        self.scale = dict(scale)
        self.names = list(self.scale)
        self.pts, self.deltas = [], []
        for p, pred in points:
            at = self.w.predict(dict(p))
            self.pts.append(np.array([p[k] for k in self.names], float))
            self.deltas.append((pred.reindex(at.index) - at).fillna(0.0))
        self.p = dict(points[-1][0])
        self.step = None
        if len(self.pts) >= 2:
            d = (self.pts[-1] - self.pts[-2]) / np.array([self.scale[k] for k in self.names])
            if float(d @ d) > SECANT_MIN_MOVE_SE ** 2:   # a shorter secant is the reruns' noise
                self.step = d / float(d @ d)

    def predict(self, theta, effects=None):
        p = dict(theta, **(effects or {}))
        y = self.w.predict(theta, effects) + self.deltas[-1]
        if self.step is not None:
            x = np.array([p.get(k, v) for k, v in zip(self.names, self.pts[-1])], float)
            t = float(((x - self.pts[-1]) / np.array([self.scale[k] for k in self.names]))
                      @ self.step)
            y = y + t * (self.deltas[-1] - self.deltas[-2])
        return y

    def fit(self, obs, rerun_se, start):
        """Base parameters and added strengths refitted on the shifted model, its noise the
        rerun mean's standard error (0 for the priors)."""
        se = rerun_se.reindex(self.deltas[-1].index).fillna(0.0)
        _, fit = calibrate_base(self.predict, obs, start, model_se=se)
        return fit

    def moved(self, fit) -> float:
        """Largest move of a parameter from the last point, in its standard errors."""
        out = 0.0
        for k, v in self.p.items():
            se = float(fit.stderr.get(k, np.nan))
            if np.isfinite(se) and se > 0:
                out = max(out, abs(float(fit.params[k]) - v) / se)
        return out


class _ShiftedModel:
    """A model whose predict is a :class:`_Corrected` one (shifted onto twin reruns at the
    calibrated point); effect resolution, parameters and effects are the model's. Diagnosis on
    it asks which effect is missing from the twin itself, not from the model's approximation
    of it.

    Its noise is the rerun mean's: near the rerun point the prediction IS the mean of
    ``rerun_replicates`` twin runs there, not the model's extrapolation from its anchor, whose
    base responses carry their own noise away from it (1.6 restitution steps off the anchor
    that noise made the sigmas 1.7 times too large and every chi2 gain 0.4 times as large).
    It is the anchor mean's standard error (the replicate sd pooled over all the model's
    groups of seeds, a steadier estimate than one rerun's three seeds) for ``rerun_replicates``
    seeds."""

    def __init__(self, model, corrected, rerun_replicates=None):
        self._model = model
        self._corr = corrected
        self._se_scale = (1.0 if rerun_replicates is None else
                          math.sqrt(float(model.replicates) / float(rerun_replicates)))

    def predict(self, theta, effects=None):
        return self._corr.predict(theta, effects)

    def model_se(self, theta=None):
        return self._model.model_se() * self._se_scale

    def __getattr__(self, name):
        return getattr(self._model, name)


def rerun_score(obs, pred, se, final, n_params) -> dict:
    """chi2 of the data against a twin rerun's means (the priors' pseudo-observations at the
    fit's values), sigma = hypot(measured sd, the rerun mean's se)."""
    key = pd.MultiIndex.from_frame(obs[["condition_id", "observable"]])
    p = pred.reindex(key).to_numpy(float)
    p = np.where(np.isfinite(p), p, final.prediction.reindex(key).to_numpy(float))
    s = np.hypot(obs["sd"].to_numpy(float), se.reindex(key).fillna(0.0).to_numpy(float))
    z = (p - obs["value"].to_numpy(float)) / s
    return {"prediction": pd.Series(p, index=key), "z": pd.Series(z, index=key),
            "chi2": float(np.nansum(z ** 2)), "dof": int(np.isfinite(z).sum()) - n_params}


def joint_fit(model, obs, theta, added):
    """The base parameters and the added effects' strengths fitted together on ``model``
    (the strengths read from the parameters; the model's noise plus the effects' resolution
    error): a FitResult."""
    w = WithAdded(model, added, theta)
    _, fit = calibrate_base(w.predict, obs, fitted_parameters(model, theta, added),
                            model_se=w.model_se())
    return fit


def refit_start(model, diag_model, obs, theta_model, added):
    """Where the final twin-corrected refits start when the diagnosis ran on a corrected model
    (``diag_model`` is not ``model``) and added effects: the base parameters and the added
    strengths fitted jointly on ``model`` itself from its own calibrated point ``theta_model``
    (a FitResult). None otherwise (the refits start from the diagnosis's own fit)."""
    if not added or diag_model is model:
        return None
    return joint_fit(model, obs, theta_model, added)


def _stage_row(stage, fit, n_params):
    return {"stage": stage, "chi2": fit.chi2, "dof": fit.dof, "chi2_dof": fit.chi2_dof,
            "p_value": fit.p_value, "n_params": n_params}


def twin_confirmation(without, with_effects, diags, added, nulls=()) -> dict | None:
    """Does the twin confirm the effects the model added?

    ``without`` and ``with_effects`` are fits of the model shifted onto the twin's reruns (the
    twin-corrected fits at the calibrated point, and at the final point with ``added`` on).
    The effects' chi2 gain there (the objective, -2 log likelihood) is set against what the
    diagnosis asked of them at their steps (the Bonferroni threshold times the bootstrap's
    scale, summed over the added effects; ``nulls`` are :func:`forward_select`'s 'null' rows,
    one per bootstrapped step). None when either fit is missing or nothing was added.

    Returns dict: gain_chi2, needed_chi2, confirmed (gain >= needed)."""
    if without is None or with_effects is None or not added:
        return None
    scales = {int(n["step"]): float(n["scale"]) for n in nulls}
    need = 0.0
    for step, d in enumerate(diags, start=1):
        if d.best in added:
            scale = scales.get(step, 1.0)
            need += float(d.threshold_delta_chi2) * (scale if np.isfinite(scale) else 1.0)
    gain = float(without.objective - with_effects.objective)
    return {"gain_chi2": gain, "needed_chi2": need, "confirmed": bool(gain >= need)}


def rerun_table(dataset, theta, added, *, replicates, seed0, sweep_kw, base_config,
                flight_ids, budget_runs=None):
    """The twin itself at the final parameters with the added DEM effects on (fresh seeds):
    its prediction per observable and its standard error, as a model with no responses."""
    cands = candidates()
    dem = {}
    for name, s in added.items():
        if cands[name].kind == "dem" and s > 0:
            dem.update(cands[name].spec(s))
    kin = {k: s for k, s in added.items() if cands[k].kind == "kinetics"}
    cfg = dict(base_config or {})
    if dem:
        cfg["effects"] = dem
    ref = {k: float("%.4g" % theta[k]) for k in ("restitution", "static_friction",
                                                 "rolling_friction", "amplitude_m")}
    m = OpenTwinModel(dataset.conditions, yield_times_of(dataset), theta_ref=ref, base=(),
                      velocity_frame=dataset.velocity_frame, flight_conditions=flight_ids,
                      replicates=replicates, diff_replicates=1, effect_names=(),
                      base_config=cfg, seed0=seed0, budget_runs=budget_runs, **sweep_kw)
    m.fit(stage="base")
    th = dict(theta)
    pred = m.predict(th, kin)
    se = m.model_se(th)
    return pred, se, m


# --------------------------------------------------------------------------- the loop

def null_scale(diag, w, obs, base_params, effs, *, n_draws, alpha, noise_observables,
               conditions, seed=0):
    """Parametric bootstrap of one diagnosis step: ``n_draws`` datasets drawn from the step's
    calibrated fit (no further effect; Gaussian noise with the stated sigma) are diagnosed like
    the real one. Returns (c, null_max, n_false): c >= 1 scales the nominal chi2-gain threshold
    so that the draws' median largest gain sits where the nominal law puts it - what the scan
    over each strength's range and the bounds add to chance (look-elsewhere); n_false counts
    the draws in which an effect was significant at the nominal level."""
    rng = np.random.default_rng(seed)
    cal = diag.calibrated
    key = pd.MultiIndex.from_frame(obs[["condition_id", "observable"]])
    mu = cal.prediction.reindex(key).to_numpy(float)
    sig = np.asarray(cal.sigma, float)
    null_max, n_false = [], 0
    for _ in range(int(n_draws)):
        o = obs.copy()
        o["value"] = mu + sig * rng.standard_normal(len(mu))
        d = diagnose(w.predict, o, base_params, effs, model_se=w.model_se(),
                     crn_correlation=getattr(w.model, "crn_correlation", 0.0),
                     conditions=conditions, alpha=alpha, noise_observables=noise_observables,
                     effect_se=w.effect_se, structure=False)
        t = d.table[d.table["identifiable"]]
        null_max.append(float(t["delta_chi2"].max()) if len(t) else 0.0)
        n_false += int(d.best is not None)
    k = max(int(diag.table["identifiable"].sum()), 1)
    sim = np.max(stats.chi2.rvs(1, size=(4000, k), random_state=1), axis=1)
    ratio = np.median(null_max) / max(float(np.median(sim)), 1e-12) if null_max else 1.0
    return max(1.0, float(ratio)), null_max, n_false


def forward_select(model, obs, theta, *, conditions=None, alpha=0.01, max_effects=MAX_EFFECTS,
                   noise_observables=None, log=print, null_draws=0):
    """Forward selection of effects on a model with ``predict``, ``model_se``,
    ``resolution_se``, ``base_params`` and ``effects`` (an :class:`OpenTwinModel` or any model
    of that shape): diagnose, add the best significant effect (its strength joins the fitted
    parameters), diagnose the rest again, until nothing more is significant or ``max_effects``
    are in.

    Returns
    -------
    dict with 'added' (name -> strength, in order), 'diagnoses' (one Diagnosis per step),
    'steps' (their tables with a ``step`` column), 'stairs' (staircase rows '+ <effect>'),
    'last_fit' (the fit of the last addition, or None), 'theta' (base parameters there),
    'null' (per step: the bootstrap's threshold scale, its draws' largest gains, false alarms)

    With ``null_draws`` > 0 an effect must also beat the nominal threshold scaled by
    :func:`null_scale` (the significance calibrated on data drawn from the fitted model).
    """
    theta = dict(theta)
    added, diags, step_rows, stairs, last_fit = {}, [], [], [], None
    nulls = []
    nb = len(model.base_params())
    for step in range(1, max_effects + 2):
        w = WithAdded(model, added, theta)
        kinds = {e.name: e.kind for e in model.effects()}
        kin_in = any(kinds.get(k) == "kinetics" for k in added)
        # kinetics effects replace the yield law: one at a time (they do not compose)
        effs = [e for e in model.effects() if e.name not in added
                and not (kin_in and e.kind == "kinetics")]
        if not effs:
            break
        diag = diagnose(w.predict, obs, fitted_parameters(model, theta, added), effs,
                        model_se=w.model_se(),
                        crn_correlation=getattr(model, "crn_correlation", 0.0),
                        conditions=conditions,
                        alpha=alpha, noise_observables=noise_observables,
                        effect_se=w.effect_se)
        t = diag.table.copy()
        t.insert(0, "step", step)
        t["threshold_scale"] = 1.0
        if diag.best is not None and null_draws:
            c, nm, nf = null_scale(diag, w, obs, fitted_parameters(model, theta, added), effs,
                                   n_draws=null_draws, alpha=alpha, conditions=conditions,
                                   noise_observables=noise_observables, seed=step)
            nulls.append({"step": step, "scale": c, "null_max_delta_chi2": nm,
                          "n_false": nf, "n_draws": null_draws})
            t["threshold_scale"] = c
            need = c * diag.threshold_delta_chi2
            keep = t["significant"] & (t["delta_chi2"] > need)
            if not keep.any():
                log("step %d: %s does not beat the bootstrap-calibrated threshold (chi2 gain "
                    "%.1f, needed %.1f = %.2f x nominal; %d of %d null draws named an effect)"
                    % (step, diag.best, float(t.loc[t["effect"] == diag.best, "delta_chi2"]
                                              .iloc[0]), need, c, nf, null_draws))
                t["significant"] = False
                diag.verdict = ("nothing beyond the bootstrap-calibrated threshold: %s gains "
                                "chi2 %.1f, %.1f needed (%d of %d datasets drawn from the fit "
                                "without it named an effect at the nominal level)"
                                % (diag.best, float(t.loc[t["effect"] == diag.best,
                                                          "delta_chi2"].iloc[0]), need, nf,
                                   null_draws))
                diag.best = None
                diag.status = "nothing_beyond_bootstrap"
            else:
                t["significant"] = keep
                diag.best = str(t.loc[keep, "effect"].iloc[0])
            diag.table["significant"] = t["significant"].to_numpy()
        diags.append(diag)
        step_rows.append(t)
        log("step %d: %s" % (step, diag.verdict))
        if diag.best is None or step > max_effects:
            break
        fit = diag.fits[diag.best]
        added[diag.best] = float(fit.params[diag.best])
        theta = {k: float(fit.params[k]) for k in theta}
        for k in list(added):
            if k in fit.params:
                added[k] = float(fit.params[k])
        last_fit = fit
        stairs.append(_stage_row("+ " + diag.best, fit, nb + len(added)))
    return {"added": added, "diagnoses": diags, "steps": step_rows, "stairs": stairs,
            "last_fit": last_fit, "theta": theta, "null": nulls}


def twin_corrected_refits(model, obs, theta, added, final, rerun_fn, *,
                          max_refits=MAX_POLISH, tol_se=POLISH_TOL_SE, log=print) -> dict:
    """Twin reruns at the fitted point and refits of the model shifted onto them.

    ``rerun_fn(theta, added) -> (prediction, se, runs)`` runs the twin at base parameters
    ``theta`` with the effects ``added`` on (its means and their standard errors per key).
    The model's strengths come from responses measured at its anchor; at a fitted point away
    from it the effects interact with the base parameters (a visco-elastic contact slows the
    ball less at a higher restitution) and the levels are interpolated, so the fitted strength
    is biased by the model's error there. Each refit shifts the model onto the rerun's means at
    the current point (:class:`_Corrected`) and fits again; a point that moved by more than
    ``tol_se`` standard errors is rerun and refitted, at most ``max_refits`` times. A slope
    error of the model by a factor r leaves (1 - r) of the strength's error per refit. The
    standard errors of the last refit are scaled by sqrt(chi2/dof) where that exceeds 1 and
    combined in quadrature with the last refit's step of each parameter (an unconverged
    iteration is as uncertain as it still moves).

    Returns dict: 'final' (FitResult), 'theta', 'added', 'rerun' (the last rerun's score:
    prediction, z, chi2, dof, runs of every rerun), 'refits' (one row per refit), 'stairs'
    (staircase rows: 'twin-corrected [n]', 'twin rerun')."""
    nb = len(theta)
    theta, added = dict(theta), dict(added)
    refits, stairs, runs, points = [], [], [], []
    corr = None
    scale = {k: float(final.stderr.get(k, np.nan)) for k in list(theta) + list(added)}
    scale = {k: v if np.isfinite(v) and v > 0 else 1.0 for k, v in scale.items()}
    for it in range(max_refits + 1):
        pred, se, r = rerun_fn(dict(theta), dict(added))
        rr = rerun_score(obs, pred, se, final, nb + len(added))
        runs.append(pd.DataFrame(r).assign(rerun=it + 1))
        rr["runs"] = pd.concat(runs, ignore_index=True)
        if it == max_refits:
            break
        points.append((dict(theta, **added), pred))
        corr = _Corrected(model, points, scale, added)
        fit = corr.fit(obs, se, fitted_parameters(model, theta, added))
        moved = corr.moved(fit)
        refits.append({"refit": it + 1, "moved_se": moved, "chi2_dof": fit.chi2_dof,
                       **{k: float(fit.params[k]) for k in added}})
        log("twin-corrected refit %d: %s (moved %.2f se), chi2/dof %.2f"
            % (it + 1, _fmt_theta({k: fit.params[k] for k in list(theta) + list(added)}),
               moved, fit.chi2_dof))
        prev = dict(theta, **added)
        theta = {k: float(fit.params[k]) for k in theta}
        added = {k: float(fit.params[k]) for k in added}
        # the se reported: the fit's, scaled up where the shifted model fits worse than its
        # noise says, and combined with this refit's own step (the iteration's error is of
        # the order of its last step; a converged refit barely adds to it)
        birge = math.sqrt(max(1.0, float(fit.chi2_dof)))
        se_eff = {k: float(np.hypot(birge * float(fit.stderr.get(k, np.nan)),
                                    float(fit.params[k]) - prev[k]))
                  for k in prev}
        final = dataclasses.replace(fit, stderr=dict(fit.stderr, **se_eff))
        refits[-1]["birge"] = birge
        stairs.append(_stage_row("twin-corrected" if it == 0 else "twin-corrected %d"
                                 % (it + 1), fit, nb + len(added)))
        if moved < tol_se:
            break
    stairs.append({"stage": "twin rerun", "chi2": rr["chi2"], "dof": rr["dof"],
                   "chi2_dof": rr["chi2"] / max(rr["dof"], 1),
                   "p_value": float(stats.chi2.sf(rr["chi2"], max(rr["dof"], 1))),
                   "n_params": nb + len(added)})
    return {"final": final, "theta": theta, "added": added, "rerun": rr, "refits": refits,
            "stairs": stairs, "corrected": corr if refits else None}


def run_loop(dataset, *, theta_ref=None, base=None, replicates=3, diff_replicates=2,
             rerun=True, rerun_replicates=3, alpha=0.01, max_effects=MAX_EFFECTS,
             max_reanchor=MAX_REANCHOR, max_polish=MAX_POLISH, budget_runs=None, base_config=None, runner=None,
             workers=2, backend="local", runs_dir=None, progress=True, scheduler=None,
             slurm=None, log=print, flights=True, track_cache=None,
             null_draws=20, extra_effects=()) -> LoopResult:
    """Run the loop on a loaded :class:`analysis.measurements.Dataset` (see the module doc).

    Parameters
    ----------
    dataset : Dataset
    theta_ref : dict or None - first anchor (default: the calibration's posterior mean)
    base : tuple of base-parameter names (default all four)
    replicates, diff_replicates : anchor seeds, seeds per response level
    rerun, rerun_replicates : the final twin rerun and its seeds per condition
    alpha : family-wise level of each diagnosis step (Bonferroni over the candidates)
    max_effects, max_reanchor : limits of the forward selection and of re-anchoring
    max_polish : twin-corrected refits after the rerun (0: the rerun only scores the fit).
        The model, shifted onto the rerun's means at the fitted point, is refitted; a point
        that moves by more than ``POLISH_TOL_SE`` standard errors gets its own rerun
    budget_runs : most new twin runs the loop may start (None: no limit); checked before each
        build, nothing runs beyond it
    base_config : dict - run-config keys of every twin run (e.g. record_s, dt_s, a jar STL)
    runner, workers, backend, runs_dir, progress, scheduler, slurm : the sweep's
    log : callable(str) for progress lines
    track_cache : folder where the tracks of the dataset's films are cached (default
        results/track_cache)
    null_draws : datasets drawn from the fitted model per step whose diagnosis calibrates the
        significance threshold (:func:`null_scale`; 0: the nominal Bonferroni level only)
    extra_effects : optional catalog entries diagnosed beside the default catalog
        (twin_model.OPTIONAL_CANDIDATES, e.g. 'end_fillet'; :func:`optional_effects`)
    """
    from analysis.open_model import DEFAULT_BASE
    t_start = time.time()
    phys = physics_table(dataset.conditions)
    sweep_kw = dict(runner=runner, workers=workers, backend=backend, runs_dir=runs_dir,
                    progress=progress, scheduler=scheduler, slurm=slurm)
    tracking = None
    if dataset.video_files and any(c not in dataset.tracks for c in dataset.video_files):
        import dataclasses
        from analysis.config import TRACK_CACHE_DIR
        from analysis.videos import track_dataset_videos
        tracks, tracking = track_dataset_videos(dataset, track_cache or TRACK_CACHE_DIR,
                                                progress=progress)
        log("tracked %d film(s): %s" % (len(tracking), "; ".join(
            "%s %d frames, %d lost, %d re-acquired, %.4f mm/px (%s)%s"
            % (q.condition_id, q.n_frames, q.n_lost, q.n_reacquired, q.m_per_px * 1e3,
               q.scale_source, " [cached]" if q.cached else "") for q in tracking.itertuples())))
        dataset = dataclasses.replace(dataset, tracks=dict(dataset.tracks, **tracks))
    obs0, fl_ids, _ = dataset_observations(dataset, flights)
    theta_ref = dict(theta_ref or reference_parameters())
    effect_names = None
    if extra_effects:
        effect_names = ([c.name for c in CANDIDATES if c.kind == "dem"]
                        + optional_effects(extra_effects, base_config))
    used = {"new": 0}

    def budget_left():
        return None if budget_runs is None else budget_runs - used["new"]

    def build(ref, stage, scout=False):
        reps = dict(replicates=replicates, diff_replicates=diff_replicates)
        if scout:
            reps = dict(replicates=min(SCOUT_REPLICATES, replicates),
                        diff_replicates=min(SCOUT_DIFF_REPLICATES, diff_replicates),
                        noisy_replicates=min(SCOUT_DIFF_REPLICATES, diff_replicates))
        m = OpenTwinModel(dataset.conditions, yield_times_of(dataset), theta_ref=ref,
                          base=tuple(base or DEFAULT_BASE),
                          velocity_frame=dataset.velocity_frame, flight_conditions=fl_ids,
                          base_config=base_config, budget_runs=budget_left(),
                          effect_names=effect_names, **reps, **sweep_kw)
        ps = m.plan_summary(stage)
        log("model at %s (%s): %d runs, %d cached, %d new, about %.0f min on %d worker(s)"
            % (_fmt_theta(ref), "scout: anchor + base responses, fewer seeds" if scout else
               "anchor + base responses" if stage == "base" else
               "+ effect responses", ps["runs"], ps["cached"], ps["new"], ps["est_wall_s"] / 60,
               workers))
        m.fit(stage)
        used["new"] += ps["new"]
        return m

    noise = {"v_mean_m_s", "f_col_hz"}
    if fl_ids:
        from analysis.flights import FLIGHT_OBSERVABLES
        noise |= set(FLIGHT_OBSERVABLES)

    def make_rerun_fn(model):
        """rerun_fn(theta, added) of :func:`twin_corrected_refits`: the twin at the model's
        other parameters with ``theta`` and the DEM effects of ``added`` on (fresh seeds)."""
        def rerun_fn(th, eff):
            pred, se, rmodel = rerun_table(dataset, dict(model.theta_ref, **th), eff,
                                           replicates=rerun_replicates, seed0=100,
                                           sweep_kw=sweep_kw, base_config=base_config,
                                           flight_ids=fl_ids, budget_runs=budget_left())
            used["new"] += rmodel.n_new_
            return pred, se, rmodel.runs_
        return rerun_fn

    def calibrated(model):
        """(obs, baseline fit, calibrated fit, theta) of the base parameters on ``model``."""
        obs = fit_observations(obs0, model)
        baseline, cal = calibrate_base(model.predict, obs, model.base_params(),
                                       model_se=model.model_se())
        theta = {p.name: cal.params[p.name] for p in model.base_params()}
        # once more with the model's noise where the calibration landed (its base responses
        # are measured, so away from the anchor they carry their own noise)
        start = [BaseParameter(p.name, float(np.clip(theta[p.name], p.lower, p.upper)),
                               p.lower, p.upper) for p in model.base_params()]
        _, cal = calibrate_base(model.predict, obs, start, model_se=model.model_se(theta))
        theta = {p.name: cal.params[p.name] for p in model.base_params()}
        return obs, baseline, cal, theta

    def analyse(model):
        """calibrate (and, with reruns, refit on the twin-corrected model), forward
        selection, final joint fit on one model."""
        obs, baseline, cal, theta = calibrated(model)
        theta_model = dict(theta)
        nb = len(model.base_params())
        stair = [_stage_row("baseline", baseline, 0), _stage_row("calibrated", cal, nb)]
        diag_model, pre = model, []
        if rerun and max_polish > 0:
            # the twin itself at the calibrated point: the model shifted onto it (and the base
            # parameters refitted there) is what diagnosis asks which effect is missing from -
            # not the model's own error at an off-anchor point
            log("twin rerun at the calibrated point (%d seeds per condition): diagnosis on the "
                "twin-corrected model" % rerun_replicates)
            tc0 = twin_corrected_refits(model, obs, theta, {}, cal, make_rerun_fn(model),
                                        max_refits=max_polish, log=log)
            if tc0["corrected"] is not None:
                cal = tc0["final"]
                theta = {k: float(cal.params[k]) for k in theta}
                diag_model = _ShiftedModel(model, tc0["corrected"], rerun_replicates)
            for row in tc0["stairs"]:
                st = row["stage"]
                row = dict(row, stage="twin rerun (calibrated)" if st == "twin rerun"
                           else st.replace("twin-corrected", "calibrated, twin-corrected"))
                stair.append(row)
            pre = tc0["refits"]
        fs = forward_select(diag_model, obs, theta, conditions=dataset.conditions, alpha=alpha,
                            max_effects=max_effects, noise_observables=noise, log=log,
                            null_draws=null_draws)
        added, last_fit, theta = fs["added"], fs["last_fit"], fs["theta"]
        stair += fs["stairs"]
        # final joint fit (all added strengths with the base): strengths and their se
        final = last_fit if last_fit is not None else cal
        if added:
            f2 = joint_fit(diag_model, obs, theta, added)
            if f2.objective <= last_fit.objective:
                final = f2
            for k in added:
                added[k] = float(final.params[k])
            theta = {k: float(final.params[k]) for k in theta}
        # where the final twin-corrected refits start: the strengths fitted jointly with the
        # base parameters on the model itself, from its own calibrated point. The corrected
        # model's base point was refitted WITHOUT the effects (a strong one drags it far: the
        # arc of eff_p05 took static and rolling friction to their bounds, 13.8 se) and its
        # shift was measured there, so strengths fitted on it started from a biased point
        # (arc 5.00 +- 0.16 for 6.04, 9.9 for 12.8); the diagnosis - which effects - stays
        # on the corrected model
        start = refit_start(model, diag_model, obs, theta_model, added)
        return dict(obs=obs, cal=cal, nb=nb, stair=stair, fs=fs, added=added, final=final,
                    theta=theta, pre=pre, refit_start=start)

    def reanchored(model, params, out, stage):
        new_ref = dict(model.theta_ref)
        for p in model.base_names:
            new_ref[p] = float("%.4g" % params[p])
        log("%s beyond the model's measured responses (%s): re-anchoring there"
            % ("calibrated point" if stage == "base" else "final point",
               ", ".join("%s %+.1f steps" % kv for kv in out.items())))
        reanchors.append({"from": model.theta_ref, "to": new_ref, "beyond": out,
                          "stage": stage})
        return new_ref

    reanchors = []
    ref = dict(theta_ref)
    # --- settle the anchor on a scout build (anchor and base responses with fewer seeds, the
    # first seeds of the whole build's): the effect responses (about half of the model's runs)
    # and the rest of the seeds are built once, where the calibration lands
    while len(reanchors) < max_reanchor:
        mb = build(ref, "base", scout=True)
        cal_params = calibrated(mb)[2].params
        out = mb.outside(cal_params)
        if not out:
            break
        ref = reanchored(mb, cal_params, out, "base")
    # --- build, analyse; re-anchor where the final point (with its effects) leaves the
    # measured responses
    while True:
        model = build(ref, "all")
        an = analyse(model)
        out = model.outside(an["final"].params)
        if not out or len(reanchors) >= max_reanchor:
            break
        ref = reanchored(model, an["final"].params, out, "all")
    obs, cal, stair, fs = an["obs"], an["cal"], an["stair"], an["fs"]
    added, final, theta = an["added"], an["final"], an["theta"]
    diags, step_rows = fs["diagnoses"], fs["steps"]
    eff_se = {k: float(final.stderr.get(k, np.nan)) for k in added}

    # --- twin rerun at the final parameters, and the twin-corrected refits
    rr, polish = None, []
    if rerun:
        log("twin rerun at the final parameters (%d seeds per condition)" % rerun_replicates)
        st = an.get("refit_start")
        if st is not None:
            theta = {k: float(st.params[k]) for k in theta}
            added = {k: float(st.params[k]) for k in added}
            final = st
            log("refits start from the joint fit on the model: %s"
                % _fmt_theta(dict(theta, **added)))
        tc = twin_corrected_refits(model, obs, theta, added, final, make_rerun_fn(model),
                                   max_refits=max_polish, log=log)
        final, theta, added, rr, polish = (tc["final"], tc["theta"], tc["added"], tc["rerun"],
                                           tc["refits"])
        stair += tc["stairs"]
        eff_se = {k: float(final.stderr.get(k, np.nan)) for k in added}
    staircase = pd.DataFrame(stair)
    confirm = None
    if rerun and polish and an["pre"]:
        confirm = twin_confirmation(cal, final, diags, added, fs["null"])
        if confirm is not None:
            log("twin confirmation: chi2 gain %.1f on the twin-corrected fits, %.1f needed: %s"
                % (confirm["gain_chi2"], confirm["needed_chi2"],
                   "confirmed" if confirm["confirmed"] else "NOT confirmed"))

    # --- tables
    steps = pd.concat(step_rows, ignore_index=True) if step_rows else pd.DataFrame()
    diagnosis = _diagnosis_table(steps, added, eff_se)
    params = []
    for p in model.base_params():
        params.append({"name": p.name, "role": "base", "value": final.params.get(p.name),
                       "se": final.stderr.get(p.name)})
    for k, reason in model.held.items():
        params.append({"name": k, "role": "held", "value": model.theta_ref[k], "se": np.nan,
                       "note": reason})
    for k, s in added.items():
        params.append({"name": k, "role": "effect", "value": s, "se": eff_se[k],
                       "note": candidates()[k].strength_label})
    parameters = pd.DataFrame(params)
    comp = obs.copy()
    key = pd.MultiIndex.from_frame(obs[["condition_id", "observable"]])
    comp["calibrated"] = cal.prediction.reindex(key).to_numpy(float)
    comp["z_calibrated"] = cal.residuals.reindex(key).to_numpy(float)
    comp["final"] = final.prediction.reindex(key).to_numpy(float)
    comp["z_final"] = final.residuals.reindex(key).to_numpy(float)
    if rr is not None:
        comp["twin_rerun"] = rr["prediction"].to_numpy(float)
        comp["z_twin_rerun"] = rr["z"].to_numpy(float)
    status, verdict = _verdict_words(diags, added, eff_se, cal, final, rr, dataset, model,
                                     alpha, confirm)
    info = {"dataset": dataset.name, "velocity_frame": dataset.velocity_frame,
            "conditions": [dict(r, label=label(r["frequency_hz"], r["ball_diameter_mm"],
                                              r["amplitude_mm"]))
                           for r in phys.drop(columns=["physics_key"]).to_dict("records")],
            "anchor": model.theta_ref, "reanchors": reanchors, "held": model.held,
            "base_response_z": {k: round(float(v), 2) for k, v in
                                getattr(model, "response_z_", {}).items()},
            "new_runs": used["new"], "wall_s": time.time() - t_start,
            "flight_conditions": fl_ids, "alpha": alpha,
            "tracking": None if tracking is None else tracking.to_dict("records"),
            "bootstrap": fs["null"], "twin_corrected": polish,
            "twin_corrected_calibration": an["pre"], "twin_confirmation": confirm,
            "beyond_model": out}
    return LoopResult(status=status, verdict=verdict,
                      effects={k: (added[k], eff_se[k]) for k in added}, staircase=staircase,
                      diagnosis=diagnosis, steps=steps, parameters=parameters,
                      comparison=comp, model_runs=model.runs_, info=info, diagnoses=diags,
                      tracks={c: dataset.tracks[c] for c in (tracking["condition_id"]
                                                            if tracking is not None else [])},
                      rerun_runs=None if rr is None else rr["runs"])


#: run-config keys the loop sets itself, never through ``--set``: the conditions, the seeds, the
#: effects, and the base parameters it calibrates (open_model.DEFAULT_BASE); --frame and
#: --record-s have their own options
LOOP_OWNED_KEYS = frozenset({"frequency_hz", "ball_diameter_m", "seed", "effects", "frame",
                             "record_s"})


def run_settings(pairs, *, frame="lab", record_s=None):
    """The run-config keys fixed in every twin run of the loop (``--set KEY=VALUE``, ``--frame``,
    ``--record-s``), validated; None when there are none.

    ``pairs`` are (key, value) tuples, e.g. the apparatus of the user's rig
    (``jar_inner_diameter_m``, ``jar_fillet_radius_m``, ``stl_path``; docs/apparatus.md), the
    contact law (``rolling_model``) or numerics (``dt_s``).

    Raises
    ------
    ValueError - an unknown key, a key the loop sets or calibrates itself, a key given twice,
        or a value the run config refuses
    """
    from analysis.config import twin_config
    from analysis.open_model import DEFAULT_BASE
    out = {}
    for k, v in pairs:
        if k not in twin_config.PARAMETERS:
            raise ValueError("--set %s: not a run-config key (yade_scripts/twin_config.py)" % k)
        if k in LOOP_OWNED_KEYS or k in DEFAULT_BASE:
            raise ValueError("--set %s: the loop sets this itself (conditions, seeds, effects "
                             "and the calibrated base parameters %s; --frame, --record-s)"
                             % (k, ", ".join(DEFAULT_BASE)))
        if k in out:
            raise ValueError("--set %s given twice" % k)
        out[k] = v
    if record_s:
        out["record_s"] = record_s
    if frame != "lab":
        out["frame"] = frame
    try:
        twin_config.complete_config(dict(out))
    except twin_config.ConfigError as exc:
        raise ValueError("--set: %s" % exc)
    return out or None


def optional_effects(names, base_config=None):
    """The optional catalog entries ``names`` (twin_model.OPTIONAL_CANDIDATES), checked against
    the runs' jar: each must be able to act on it at its largest strength.

    Raises
    ------
    ValueError - an unknown name, or an effect that cannot act on this jar (e.g. end_fillet on
        an STL whose fillet is unknown)
    """
    from analysis.config import twin_config
    from analysis.twin_model import OPTIONAL_CANDIDATES
    from effects import jar_config
    opt = {c.name: c for c in OPTIONAL_CANDIDATES}
    out = []
    for n in names:
        if n not in opt:
            raise ValueError("--with-effect %s: not an optional catalog entry (optional: %s; "
                             "the others are always diagnosed)" % (n, ", ".join(opt)))
        cfg = dict(base_config or {}, effects=opt[n].spec(opt[n].s_max))
        try:
            jar_config(twin_config.complete_config(cfg))
        except twin_config.ConfigError as exc:
            raise ValueError("--with-effect %s: %s" % (n, exc))
        if n not in out:
            out.append(n)
    return out


def with_assumed_v_sd(dataset, v_rel_sd):
    """``dataset`` whose empty ``v_mean_sd_m_s`` cells hold ``v_rel_sd`` x v_mean_m_s (the
    measurement sd the loop assumes where the data state none; stated sds are kept).

    Raises
    ------
    ValueError - v_rel_sd not a finite number in (0, 0.5)
    """
    if not (isinstance(v_rel_sd, (int, float)) and math.isfinite(v_rel_sd)
            and 0.0 < v_rel_sd < 0.5):
        raise ValueError("--v-rel-sd must lie in (0, 0.5) (a fraction of v_mean), got %r"
                         % (v_rel_sd,))
    summ = dataset.summary.copy()
    sd = pd.to_numeric(summ["v_mean_sd_m_s"], errors="coerce")
    fill = sd.isna()
    summ["v_mean_sd_m_s"] = sd.where(~fill, v_rel_sd * summ["v_mean_m_s"].astype(float))
    return dataclasses.replace(dataset, summary=summ)


def _fmt_theta(t):
    return ", ".join("%s %.4g" % (k, v) for k, v in t.items())


def _diagnosis_table(steps, added, eff_se):
    """One row per candidate: added effects first (in the order added, with the final joint
    strength), then the rest as ranked in the last step (identifiable first, then by chi2
    gain, largest first: both columns are in the table)."""
    if not len(steps):
        return pd.DataFrame(columns=["effect", "kind", "rank", "significant", "strength",
                                     "strength_se", "delta_chi2", "p_bonferroni",
                                     "identifiable", "step"])
    rows = []
    for i, name in enumerate(added):
        r = steps[(steps["effect"] == name) & steps["significant"]].iloc[-1]
        rows.append({"effect": name, "kind": r["kind"], "significant": True,
                     "strength": added[name], "strength_se": eff_se[name],
                     "delta_chi2": r["delta_chi2"], "p_bonferroni": r["p_bonferroni"],
                     "identifiable": bool(r["identifiable"]), "step": int(r["step"])})
    last = steps[steps["step"] == steps["step"].max()]
    # the rest in the order the page states and shows: identifiable ones first, each group by
    # its chi2 gain, largest first (the diagnosis' own ranking)
    last = last.assign(_id=last["identifiable"].astype(bool),
                       _g=pd.to_numeric(last["delta_chi2"], errors="coerce").fillna(-np.inf))
    last = last.sort_values(["_id", "_g"], ascending=[False, False], kind="stable")
    for _, r in last.iterrows():
        if r["effect"] in added:
            continue
        rows.append({"effect": r["effect"], "kind": r["kind"], "significant": False,
                     "strength": r["strength"], "strength_se": r["strength_se"],
                     "delta_chi2": r["delta_chi2"], "p_bonferroni": r["p_bonferroni"],
                     "identifiable": bool(r["identifiable"]), "step": int(r["step"])})
    t = pd.DataFrame(rows)
    t.insert(2, "rank", np.arange(1, len(t) + 1))
    return t


def _verdict_words(diags, added, eff_se, cal, final, rr, dataset, model, alpha,
                   confirm=None):
    from analysis.report.loop_words import prior_sd, stated_stroke_words, \
        UNCONSTRAINED_SE_RATIO
    head = ("calibrated chi2/dof %.2f (dof %d)" % (cal.chi2_dof, cal.dof) if cal.dof > 0 else
            "calibrated chi2/dof untestable (dof %d: no more observations than fitted "
            "parameters)" % cal.dof)
    parts = []
    if added:
        found = []
        for k, s in added.items():
            c = candidates()[k]
            found.append("%s (%s = %.3g +- %.2g)" % (k, c.strength_label, s, eff_se[k]))
        status = "effects"
        parts.append("missing effect%s: %s; chi2/dof %.2f -> %.2f"
                     % ("s" if len(added) > 1 else "", "; ".join(found), cal.chi2_dof,
                        final.chi2_dof))
        # ties: a candidate as good as the one added at its step
        for d in diags:
            if d.best is None:
                continue
            t = d.table
            b = t[t["effect"] == d.best].iloc[0]
            ties = t[t["significant"] & (t["effect"] != d.best)
                     & (b["delta_chi2"] - t["delta_chi2"] < TIE_DELTA_CHI2)]
            for _, o in ties.iterrows():
                parts.append("%s explains the data about as well as %s (chi2 gain %.1f "
                             "against %.1f): the data cannot tell them apart"
                             % (o["effect"], d.best, o["delta_chi2"], b["delta_chi2"]))
    else:
        status = "nothing_missing" if cal.p_value >= alpha else "unexplained"
        parts.append("nothing missing: no candidate effect is significant; %s" % head
                     if status == "nothing_missing" else
                     "no candidate effect explains the misfit (%s, p = %.2g)"
                     % (head, cal.p_value))
    if added and final.p_value < alpha:
        status = "effects_partial"
        parts.append("what stays unexplained: chi2/dof %.2f (p = %.2g) after the effects found"
                     % (final.chi2_dof, final.p_value))
    if diags and diags[-1].structure is not None and len(diags[-1].structure):
        st = diags[-1].structure
        w = list(st.loc[st["significant"], "words"])
        if w and (status != "nothing_missing"):
            parts.append("residual structure: " + "; ".join(w))
    demoted = [d for d in diags if d.status == "nothing_beyond_bootstrap"]
    if demoted:
        parts.append(demoted[-1].verdict)
    if model.held:
        held = []
        stroke = stated_stroke_words(getattr(dataset, "conditions", None))
        for k, reason in model.held.items():
            if k == "amplitude_m" and stroke:
                held.append("the stroke as the dataset states it (amplitude_mm %s), not "
                            "fitted" % stroke)
            else:
                held.append("%s held at the anchor %.4g (%s)"
                            % (k, float(model.theta_ref.get(k, np.nan)), reason))
        parts.append("; ".join(held))
    # parameters the data leave about as uncertain as the prior (the report's rule)
    loose = []
    try:
        bounds = {p.name: (p.lower, p.upper) for p in model.base_params()}
    except (AttributeError, TypeError):
        bounds = {}
    cands = candidates()
    bounds.update({k: (0.0, float(cands[k].s_max)) for k in added if k in cands})
    priors = getattr(model, "priors", None) or {}
    for k in bounds:
        se = float(final.stderr.get(k, np.nan)) if k not in added else float(
            eff_se.get(k, np.nan))
        sd = prior_sd(k, bounds, priors)
        if np.isfinite(sd) and sd > 0 and not (np.isfinite(se)
                                               and se < UNCONSTRAINED_SE_RATIO * sd):
            loose.append("%s (se %.2g for a prior sd %.2g)" % (k, se, sd))
    if loose:
        parts.append("not constrained by the data: " + ", ".join(loose))
    beyond = model.outside(final.params)
    if beyond:
        parts.append("the final point lies beyond the model's measured responses (%s; no "
                     "re-anchoring left): its figures there are extrapolated"
                     % ", ".join("%s %+.1f steps" % kv for kv in beyond.items()))
    if confirm is not None:
        parts.append("%s: with %s, the model shifted onto the twin's reruns gains chi2 %.1f "
                     "(%.1f needed)"
                     % ("the twin confirms it" if confirm["confirmed"] else
                        "the twin does NOT confirm it (treat it as a suggestion)",
                        "these effects" if len(added) > 1 else "the effect",
                        confirm["gain_chi2"], confirm["needed_chi2"]))
    if rr is not None:
        parts.append("the real twin rerun at the final parameters: chi2/dof %.2f"
                     % (rr["chi2"] / max(rr["dof"], 1)))
    return status, ". ".join(parts) + "."


# --------------------------------------------------------------------------- output

def write_loop(res: LoopResult, out_dir, dataset, protected=()) -> Path:
    """Write the loop's folder atomically (see the module docstring for the files).

    What the files state beyond the result itself (:mod:`analysis.report.loop_words`): a run
    made by the FAKE twin says so on its page, in both figures (titles, watermark, PNG text)
    and in loop.json (``twin``, ``fake_twin``); parameters.csv gives a stroke the dataset
    states as stated and a column ``constrained``; diagnosis.csv the chi2 gain each candidate
    needed (``delta_chi2_needed``, the test as applied: Bonferroni x the bootstrap's scale, the
    F-test, BIC); loop.json is strict JSON (NaN and infinities as null)."""
    from analysis.plotting.diagnose_plots import write_loop_figures
    from analysis.report import loop_page
    from analysis.report.loop_words import (FAKE_WORDS, UNCONSTRAINED_RULE,
                                            annotate_parameters, is_fake_run, json_clean,
                                            needed_gains, quoted_stages, step_scale)

    out_dir = Path(out_dir)
    fake = is_fake_run(res)
    bounds, priors = {}, {}
    try:
        from analysis.open_model import calibration_prior
        from analysis.parameter_space import CALIBRATED, effect_strengths
        bounds = dict(CALIBRATED, **{k: v[:2] for k, v in effect_strengths().items()})
        priors = calibration_prior()
    except (OSError, KeyError, ValueError, ImportError):
        pass                          # no prior known: the flat prior over the bounds
    params = annotate_parameters(res.parameters, getattr(dataset, "conditions", None),
                                 bounds=bounds, priors=priors)
    diagnosis = res.diagnosis.copy()
    significance = []
    for k, d in enumerate(res.diagnoses, start=1):
        c = step_scale(res.steps, k)
        significance.append({"step": k, "nominal_delta_chi2": float(d.threshold_delta_chi2),
                             "bootstrap_scale": c,
                             "applied_delta_chi2": float(d.threshold_delta_chi2) * c,
                             "n_candidates": int(len(d.table)), "alpha": float(d.alpha)})
    if len(diagnosis):
        need = []
        for _, r in diagnosis.iterrows():
            st = int(r["step"])
            if 1 <= st <= len(res.diagnoses):
                ng = needed_gains(res.diagnoses[st - 1], step_scale(res.steps, st))
                need.append(float(ng.get(r["effect"], np.nan)))
            else:
                need.append(np.nan)
        diagnosis["delta_chi2_needed"] = need
    steps = res.steps.copy()
    if len(steps) and "step" in steps.columns:
        need = []
        for _, r in steps.iterrows():
            st = int(r["step"])
            ng = (needed_gains(res.diagnoses[st - 1], step_scale(res.steps, st))
                  if 1 <= st <= len(res.diagnoses) else {})
            need.append(float(ng.get(r["effect"], np.nan)) if len(ng) else np.nan)
        steps["delta_chi2_needed"] = need
    quoted = quoted_stages(res.staircase) if len(res.staircase) else {}
    with output_dir(out_dir, protected) as tmp:
        diagnosis.to_csv(tmp / "diagnosis.csv", index=False)
        res.staircase.to_csv(tmp / "staircase.csv", index=False)
        steps.to_csv(tmp / "steps.csv", index=False)
        params.to_csv(tmp / "parameters.csv", index=False)
        res.comparison.to_csv(tmp / "comparison.csv", index=False)
        res.model_runs.to_csv(tmp / "model_runs.csv", index=False)
        if res.rerun_runs is not None:
            res.rerun_runs.to_csv(tmp / "rerun_runs.csv", index=False)
        if res.tracks:
            (tmp / "tracks").mkdir()
            for cid, tr in res.tracks.items():
                tr.to_csv(tmp / "tracks" / ("%s.csv" % cid), index=False)
            pd.DataFrame(res.info["tracking"]).to_csv(tmp / "tracking.csv", index=False)
        info = dict(res.info, status=res.status, verdict=res.verdict,
                    effects={k: {"strength": s, "se": se} for k, (s, se) in res.effects.items()},
                    twin=FAKE_WORDS if fake else "the DEM twin (YADE)", fake_twin=fake,
                    quoted_stages={role: str(res.staircase["stage"].iloc[i])
                                   for role, i in quoted.items()},
                    significance=significance,
                    unconstrained=[str(n) for n, c in zip(params["name"], params["constrained"])
                                   if not pd.isna(c) and not bool(c)],
                    unconstrained_rule=UNCONSTRAINED_RULE)
        (tmp / "loop.json").write_text(json.dumps(json_clean(info), indent=1, allow_nan=False,
                                                  default=_json))
        write_loop_figures(res.staircase, res.diagnoses[0] if res.diagnoses else None, tmp,
                           dataset, fake=fake, quoted=quoted,
                           threshold_scale=step_scale(res.steps, 1))
        (tmp / "report.md").write_text(loop_page(res, dataset, fake=fake, parameters=params,
                                                 diagnosis=diagnosis, quoted=quoted,
                                                 significance=significance))
    return out_dir


def _json(o):
    """JSON form of what :func:`analysis.report.loop_words.json_clean` left (numpy scalars;
    NaN and infinities as null, never the invalid tokens NaN / Infinity)."""
    if isinstance(o, (np.floating, float)):
        v = float(o)
        return v if math.isfinite(v) else None
    if isinstance(o, np.integer):
        return o.item()
    if isinstance(o, np.bool_):
        return bool(o)
    return str(o)


# --------------------------------------------------------------------------- CLI

def rerun_runs(n_conditions, *, rerun=True, replicates=3, max_refits=MAX_POLISH):
    """(runs, most runs) of the loop's twin reruns, fresh seeds each: ``replicates`` per
    condition at the calibrated point (with refits) and at the final point; each
    twin-corrected refit that moves the point adds one more rerun there (at most
    ``max_refits`` per point)."""
    if not rerun:
        return 0, 0
    per = int(n_conditions) * int(replicates)
    points = 2 if max_refits > 0 else 1
    return per * points, per * points * (1 + int(max_refits))


class _Parser(argparse.ArgumentParser):
    """argparse with one error line (``analysis.loop: error: ...``) and exit code 2."""

    def error(self, message):
        print("analysis.loop: error: %s" % message, file=sys.stderr)
        sys.exit(2)


def check_options(a):
    """Refuse (ValueError, one line) every option value the loop cannot run with, before the
    dataset is read or anything planned - the dry run included."""
    def at_least(flag, value, lo):
        if value is not None and value < lo:
            raise ValueError("%s must be >= %d, got %d" % (flag, lo, value))
    for flag, value in (("--replicates", a.replicates), ("--diff-replicates", a.diff_replicates),
                        ("--rerun-replicates", a.rerun_replicates), ("--workers", a.workers)):
        at_least(flag, value, 1)
    for flag, value in (("--budget-runs", a.budget_runs), ("--max-refits", a.max_refits),
                        ("--null-draws", a.null_draws), ("--max-reanchor", a.max_reanchor),
                        ("--max-effects", a.max_effects)):
        at_least(flag, value, 0)
    if not (math.isfinite(a.alpha) and 0.0 < a.alpha < 1.0):
        raise ValueError("--alpha must lie in (0, 1), got %g" % a.alpha)
    if a.record_s is not None and not (a.record_s > 0 and math.isfinite(a.record_s)):
        raise ValueError("--record-s must be > 0 s, got %g" % a.record_s)
    if a.v_rel_sd is not None and not (math.isfinite(a.v_rel_sd) and 0.0 < a.v_rel_sd < 0.5):
        raise ValueError("--v-rel-sd must lie in (0, 0.5) (a fraction of v_mean), got %g"
                         % a.v_rel_sd)
    if a.scheduler is not None and a.backend != "dask":
        raise ValueError("--scheduler %s needs --backend dask (got --backend %s)"
                         % (a.scheduler, a.backend))
    if a.fake and a.backend == "dask":
        raise ValueError("--fake runs the analytic stand-in in this process: use --backend "
                         "local or serial")


def dof_limits(ds, max_effects, base=None):
    """(calibration dof, max effects) of a loop on ``ds``, before anything is planned.

    The calibration fits every base parameter the dataset does not state (and, with yields,
    the powder line's slope and intercept) to the dataset's observations and the frictions'
    prior pseudo-observations; each added effect costs one more degree of freedom. Raises
    ValueError when the calibration would keep no degree of freedom (one condition with
    v_mean and f_col only: chi2/dof undefined, nothing can be tested); otherwise the number
    of effects is capped so that one degree of freedom stays. A dataset whose films are not
    yet tracked may gain impact observables: then nothing is refused or capped here.
    """
    from analysis.open_model import DEFAULT_BASE, calibration_prior
    from analysis.run_configs import stated_amplitude_m
    if ds.video_files and any(c not in ds.tracks for c in ds.video_files):
        return None, max_effects
    obs, _, _ = dataset_observations(ds, True)
    n_obs = int(np.isfinite(pd.to_numeric(obs["value"], errors="coerce")).sum())
    phys = physics_table(ds.conditions)
    names = list(base or DEFAULT_BASE)
    if all(stated_amplitude_m(r) is not None for r in phys.to_dict("records")):
        names = [n for n in names if n != "amplitude_m"]
    try:
        n_prior = len(set(calibration_prior()) & set(names))
    except (OSError, ValueError, KeyError):
        n_prior = 0
    n_par = len(names) + (2 if yield_times_of(ds) else 0)
    dof = n_obs + n_prior - n_par
    if dof < 1:
        raise ValueError(
            "%s: %d observation(s) at %d condition(s) (+ %d prior pseudo-observation(s)) for "
            "%d calibrated parameter(s) (%s) leave %d degrees of freedom: chi2/dof is "
            "undefined and no effect can be tested; measure at more conditions (each adds "
            "v_mean and f_col), add jar tracks, or state the stroke (amplitude_mm)"
            % (ds.name, n_obs, len(phys), n_prior,
               n_par, ", ".join(names + (["slope_pct_per_kj", "intercept_pct"]
                                        if yield_times_of(ds) else [])), dof))
    return dof, min(max_effects, dof - 1)


def main(argv=None):
    """The command (see the module doc); Ctrl-C at any moment: one line, exit 130."""
    if signal.getsignal(signal.SIGINT) is globals().get("_interrupted_early"):
        signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        return _main(argv)
    except KeyboardInterrupt as exc:                # SIGINT / SIGTERM: one line, 130 / 143
        from analysis.sweep import interrupted_exit
        return interrupted_exit("analysis.loop", exc)


def _main(argv=None):
    ap = _Parser(
        prog="python -m analysis.loop",
        description="The loop on a measurement dataset: build the twin model at its "
        "conditions, calibrate, diagnose which effect is missing, add it (repeatedly), rerun "
        "the twin, write one report folder.",
        epilog="example: python -m analysis.loop --dataset data/measurements/paper_table3 "
        "--out results/loop/paper_table3",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dataset", required=True, help="dataset folder (docs/dataset_format.md)")
    ap.add_argument("--out", required=True,
                    help="output folder; replaced only when an earlier loop wrote it")
    ap.add_argument("--budget-runs", type=int, default=None,
                    help="most new twin runs to start [runs] (default: no limit); the loop stops "
                    "with exit 3 before a build that needs more")
    ap.add_argument("--dry-run", action="store_true",
                    help="print the first build's plan (runs, cached, estimated wall time) "
                    "and exit; nothing is run or written")
    ap.add_argument("--replicates", type=int, default=3, help="anchor seeds per condition [seeds]")
    ap.add_argument("--diff-replicates", type=int, default=2,
                    help="seeds per base-parameter / effect level [seeds]")
    ap.add_argument("--no-rerun", action="store_true", help="skip the final twin rerun")
    ap.add_argument("--rerun-replicates", type=int, default=3,
                    help="seeds per condition of the final twin rerun [seeds]")
    ap.add_argument("--max-refits", type=int, default=MAX_POLISH,
                    help="[refits] twin-corrected refits after the rerun: the model shifted onto the "
                    "rerun's means at the fitted point and refitted; a point that moves gets "
                    "its own rerun (0: the rerun only scores the fit)")
    ap.add_argument("--alpha", type=float, default=0.01,
                    help="family-wise significance level of each diagnosis step [-]")
    ap.add_argument("--null-draws", type=int, default=20,
                    help="[datasets] datasets drawn from the fitted model per step to calibrate the "
                    "significance threshold (0: nominal level only)")
    ap.add_argument("--max-reanchor", type=int, default=MAX_REANCHOR,
                    help="[re-anchorings] most re-anchorings of the model where the answer lies beyond its "
                    "measured responses (each costs a new model build)")
    ap.add_argument("--max-effects", type=int, default=MAX_EFFECTS,
                    help="most effects added (forward selection) [effects]")
    ap.add_argument("--frame", choices=("lab", "jar", "auto"), default="lab",
                    help="frame the twin runs are integrated in (run config 'frame'): 'auto' "
                    "runs the jar frame where the effects allow it, 1.7x faster per run; the "
                    "default 'lab' keeps the runs committed in results/ usable (they are lab "
                    "runs: another frame is another run id)")
    ap.add_argument("--record-s", type=float, default=None,
                    help="recorded time per twin run [s] (default the run config's 0.5 s)")
    ap.add_argument("--with-effect", action="append", default=[], metavar="NAME",
                    help="an optional catalog entry diagnosed beside the default ones "
                    "(repeatable): end_fillet (the jar's end edges rounded more; needs the "
                    "default or a parametric jar)")
    ap.add_argument("--v-rel-sd", type=float, default=None, metavar="F",
                    help="[-] measurement sd of v_mean assumed where the dataset states none, as a "
                    "fraction of v_mean (default 0.015; e.g. 0.01 for 1 %%)")
    ap.add_argument("--set", action="append", default=[], dest="settings", metavar="KEY=VALUE",
                    type=parse_key_value,
                    help="run-config key fixed in every twin run (repeatable): your rig's "
                    "apparatus, e.g. jar_inner_diameter_m=0.028 jar_fillet_radius_m=0.01 or "
                    "stl_path=my_jar.stl (docs/apparatus.md), rolling_model, dt_s; not the "
                    "conditions, seeds, effects or the calibrated base parameters")
    ap.add_argument("--workers", type=int, default=2, help="parallel twin runs [processes]")
    ap.add_argument("--backend", choices=("local", "serial", "dask"), default="local",
                    help="sweep backend (dask: --scheduler ADDRESS or a local cluster)")
    ap.add_argument("--scheduler", default=None, help="address of a running Dask scheduler")
    ap.add_argument("--fake", action="store_true",
                    help="use the FAKE analytic twin (tests and demonstrations only)")
    a = ap.parse_args(argv)
    try:
        # every option and the output (its parent included) before the dataset is read or
        # anything planned: a bad value never costs a build
        check_options(a)
        check_out_dir(a.out, [a.dataset])
        base_config = run_settings(a.settings, frame=a.frame, record_s=a.record_s)
        extra = optional_effects(a.with_effect, base_config)
        ds = load_dataset(a.dataset)
        for line in ds.warnings:            # accepted, but outside what the twin is tested on
            print("analysis.loop: warning: %s" % line, file=sys.stderr)
        physics_table(ds.conditions)
        if a.v_rel_sd is not None:
            ds = with_assumed_v_sd(ds, a.v_rel_sd)
        _, max_effects = dof_limits(ds, a.max_effects)
        if max_effects < a.max_effects:
            print("analysis.loop: note: at most %d effect(s) added (--max-effects %d): each "
                  "costs a degree of freedom and the dataset leaves %d beyond the calibration"
                  % (max_effects, a.max_effects, max_effects + 1), file=sys.stderr)
        runner = None
        runs_dir = None
        if a.fake:
            from analysis.config import FAKE_RUNS_DIR
            from analysis.fake_twin import run_fake_twin
            runner, runs_dir = run_fake_twin, FAKE_RUNS_DIR
        if a.dry_run:
            m = OpenTwinModel(ds.conditions, yield_times_of(ds),
                              velocity_frame=ds.velocity_frame, replicates=a.replicates,
                              diff_replicates=a.diff_replicates, base_config=base_config,
                              runner=runner, workers=a.workers, runs_dir=runs_dir,
                              effect_names=([c.name for c in CANDIDATES if c.kind == "dem"]
                                            + extra) if extra else None)
            for stage in ("base", "all"):
                ps = m.plan_summary(stage)
                print("%s: %d runs, %d cached, %d new, about %.0f min on %d worker(s) "
                      "(%.0f s per run)" % ("anchor + base responses" if stage == "base"
                                            else "with the effect responses", ps["runs"],
                                            ps["cached"], ps["new"], ps["est_wall_s"] / 60,
                                            a.workers, run_wall_s(base_config, runs_dir)))
            lo, hi = rerun_runs(len(ds.conditions), rerun=not a.no_rerun,
                                replicates=a.rerun_replicates, max_refits=a.max_refits)
            if lo:
                print("twin reruns: %d runs (%d seed(s) at %d condition(s), at %s), up to %d "
                      "when the twin-corrected refits move the point"
                      % (lo, a.rerun_replicates, len(ds.conditions),
                         "the calibrated and the final point" if a.max_refits > 0
                         else "the final point", hi))
            w = max(a.workers, 1)
            print("total: %d runs, %d new (up to %d), about %.0f min on %d worker(s); each "
                  "re-anchoring (at most %d) adds a build" % (
                      ps["runs"] + lo, ps["new"] + lo, ps["new"] + hi,
                      math.ceil((ps["new"] + lo) / w) * run_wall_s(base_config, runs_dir) / 60,
                      a.workers, a.max_reanchor))
            return 0
        res = run_loop(ds, replicates=a.replicates, diff_replicates=a.diff_replicates,
                       null_draws=a.null_draws, max_reanchor=a.max_reanchor,
                       max_polish=a.max_refits,
                       rerun=not a.no_rerun, rerun_replicates=a.rerun_replicates,
                       alpha=a.alpha, max_effects=max_effects, budget_runs=a.budget_runs,
                       base_config=base_config, runner=runner, workers=a.workers,
                       backend=a.backend, scheduler=a.scheduler, runs_dir=runs_dir,
                       log=lambda s: print(s, file=sys.stderr), extra_effects=extra)
        write_loop(res, a.out, ds, protected=[a.dataset])
    except BudgetError as exc:
        print("analysis.loop: %s" % exc, file=sys.stderr)
        return 3
    except (DatasetError, ConditionError, OutputError, ValueError) as exc:
        print("analysis.loop: error: %s" % exc, file=sys.stderr)
        return 2
    except RuntimeError as exc:                     # a twin run failed: not the input's fault
        print("analysis.loop: error: %s" % str(exc).replace("\n", " "), file=sys.stderr)
        return 1
    print(res.verdict)
    print("staircase: " + ", ".join("%s %.2f" % (r.stage, r.chi2_dof)
                                    for r in res.staircase.itertuples()))
    print("wrote %s" % a.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
