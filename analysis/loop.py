"""The whole loop on a researcher's own dataset: compare, diagnose, add (iterated), twin rerun.

    python -m analysis.loop --dataset DIR --out DIR [--budget-runs N] [--dry-run]

The loop runs as stages over one typed state (:class:`LoopState`; its choices in
:class:`LoopSettings`), on ONE model of the twin: :class:`analysis.emulated_twin.EmulatedTwin`,
Gaussian-process emulators of every observable over the base parameters, every candidate
effect's strength jointly and the conditions, fitted to every twin run made for the dataset.

1. **read** the dataset (``docs/dataset_format.md``; a bad file is one error naming file, row and
   column). Conditions are matched by physics (frequency, ball, stroke where stated), never by
   their ids; the velocity frame is honoured; tracks that carry the jar (``jar_x_m``) add the
   impact observables; films are tracked first.
2. **build** the model in waves (:func:`analysis.emulated_twin.build_in_waves`): wave 0 a
   Latin hypercube over the base parameters' priors with one candidate effect on in half its
   points, and the reference point with ``--replicates`` seeds (the twin's chaos per
   condition); then ``--waves`` waves of ``--per-wave`` points where the data are plausible
   (history matching), with no effect and each effect free in turn. The plan (runs, cached,
   from the committed run table, new, wall time) is printed first and checked against
   ``--budget-runs``; twin runs are cached by run id, so a killed loop resumes.
3. **calibrate** the base parameters (restitution, stroke, the frictions) on the emulator,
   its own uncertainty in the likelihood where each fit asks.
4. **diagnose and add**, forward selection: rank every candidate effect; add the best one
   that beats the bootstrap-calibrated threshold; diagnose the rest again (``--max-effects``).
5. **focus**: a wave of ``--focus-points`` design points where the selected fit's posterior
   lies, with the effects found on (:func:`analysis.history_matching.posterior_cloud`); the
   emulator refitted with them, the calibration and the selection redone on it.
6. **confirm**: the twin itself at the final point with the effects found (fresh seeds,
   ``--rerun-replicates`` per condition); these runs join the training runs (they are design
   points too), the emulator is refitted and the final fit redone on it; a final point that
   moves by more than :data:`CONFIRM_TOL_SE` standard errors gets its own rerun
   (``--confirm-rounds``), after a focus wave when the emulator missed the rerun or the
   refitted point leans on its uncertainty (:func:`lean_of`, :attr:`Lean.sure`).
7. **intervals**: every fitted parameter's 95 % profile-likelihood interval on the emulator,
   bounded by the misfit's rise (:func:`analysis.diagnose.profile_interval`: the emulator's
   own log-determinant left out, so no value is ruled out for the runs not made near it);
   before the confirmation (step 6), the twin at each closed end's profiled point
   (``--interval-rounds``; the emulator refitted, the fit and the intervals redone; a round
   only for the ends that moved), and after it the intervals again on the final model.
8. **write** one folder (atomically; only a folder this project wrote is ever replaced):

   ========================  ==================================================================
   ``report.md``             the verdict in words, the staircase, the parameters, figures
   ``diagnosis.csv``         one row per candidate: effect, kind, rank, significant, strength,
                             strength_se, delta_chi2, p_bonferroni, identifiable, step
   ``staircase.csv``         stage, chi2, dof, chi2_dof (baseline, calibrated, + each effect,
                             refitted with the interval ends' runs, twin rerun,
                             refitted on the twin reruns)
   ``steps.csv``             every diagnosis step's full ranking (column ``step``)
   ``parameters.csv``        name, role (base / effect), value, se, profile_lo, profile_hi
   ``comparison.csv``        per observable: measured, sd, calibrated, final, twin rerun, z;
                             motion_mode_final: the twin's motion mode the final fit scores
                             it in (a model with two modes or more)
   ``model_runs.csv``        every twin run the model was fitted to (wave, point, condition_id,
                             seed, run_id, the design inputs, the observables)
   ``rerun_runs.csv``        the confirmation runs at the final point (also in model_runs.csv)
   ``loop.json``             verdict, status, effects found, run counts, wall times
   ``tracking.csv``,         (a dataset with films) each film's tracking quality: frames,
   ``tracks/<id>.csv``       lost frames, re-acquisitions, scale; the tracks made from them
   ``staircase.png``, ``ranking.png``
   ========================  ==================================================================

Example::

    python -m analysis.loop --dataset data/measurements/paper_table3 \\
        --out results/loop/paper_table3
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
import functools
import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
from scipy import linalg, stats

from analysis.atomic_dir import OutputError, check_out_dir, output_dir
from analysis.conditions import ConditionError, label, physics_table
from analysis.catalog import CANDIDATES, candidates
from analysis.diagnose import (BaseParameter, calibrate_base, dataset_observations, diagnose,
                               profile_interval, shared_covariance, with_run_sd)
from analysis.measurements import DatasetError, conditions_file, load_dataset, yield_times_of
from analysis.parameter_space import (ParameterVector, coordinates_of,
                                     reference_parameters)
from analysis.processes import in_processes
from analysis.sweep import parse_key_value
from analysis.twin_runs import BudgetError, TwinRuns

#: candidate effects beyond this many are not added (a guard against chasing noise)
MAX_EFFECTS = 3
#: two candidates whose -2 log L gains differ by less than this are "about as good"
TIE_DELTA_CHI2 = 2.0
#: the base parameters the loop calibrates (declared in analysis.parameter_space)
DEFAULT_BASE = ("restitution", "amplitude_m", "static_friction", "rolling_friction")
#: a refit on the emulator with the confirmation runs that moves no parameter by more than
#: this many of its standard errors ends the confirmation rounds
CONFIRM_TOL_SE = 0.5
#: seeds of the confirmation runs: round r uses CONFIRM_SEED0 + r * replicates onwards (fresh
#: seeds, never the design's)
CONFIRM_SEED0 = 100
#: seed of the focus wave's runs (the design's seed added)
FOCUS_SEED0 = 50
#: seeds of the runs at the intervals' ends: round r uses INTERVAL_SEED0 + r
INTERVAL_SEED0 = 300
#: an interval end within this fraction of its interval's width of one already run is not
#: run again (the rounds stop when no end moves by more)
END_TOL_WIDTH = 0.1
#: an observation is undecided (history matching) where the emulator's sd is above this share of
#: the data's and the data are more than CUTOFF of their sds off its mean, but not of the
#: combined sd: plausible only because the emulator does not know the twin there
SURE_SHARE = 0.5


@dataclass
class LoopSettings:
    """The loop's choices (the command's options; see ``python -m analysis.loop --help``)."""

    alpha: float = 0.01              # family-wise level of each diagnosis step [-]
    max_effects: int = MAX_EFFECTS   # most effects added [-]
    null_draws: int = 20             # bootstrap datasets per step [-]
    points: int = 24                 # wave-0 design points [-]
    replicates: int = 3              # seeds of the reference point (the chaos) [-]
    waves: int = 2                   # refinement waves [-]
    per_wave: int = 8                # design points per refinement wave [-]
    focus_points: int = 6            # design points of the focus wave about the fit [-]
    rerun: bool = True               # the twin at the final point
    rerun_replicates: int = 3        # its seeds per condition [-]
    confirm_rounds: int = 2          # most reruns at moved final points [-]
    interval_rounds: int = 3         # most rounds of runs at the intervals' ends [-]
    intervals: bool = True           # profile-likelihood intervals
    seed: int = 0                    # design seed [-]
    flights: bool = True             # impact observables from jar tracks
    extra_effects: tuple = ()        # optional catalog entries diagnosed too
    base: tuple = DEFAULT_BASE       # the base parameters calibrated (over their priors)
    free: tuple = ()                 # (name, lo, hi): parameters calibrated too (--free)
    n_jobs: int = 1                  # processes for the analysis' fits (--workers) [-]

    def check(self):
        """ValueError naming the first setting the loop cannot run with."""
        for name in ("points", "replicates"):
            if getattr(self, name) < 2:
                raise ValueError("--%s must be >= 2, got %d" % (name, getattr(self, name)))
        for name in ("per_wave", "rerun_replicates", "confirm_rounds", "n_jobs"):
            if getattr(self, name) < 1:
                raise ValueError("--%s must be >= 1, got %d"
                                 % (name.replace("_", "-"), getattr(self, name)))
        for name in ("waves", "null_draws", "max_effects", "focus_points",
                     "interval_rounds"):
            if getattr(self, name) < 0:
                raise ValueError("--%s must be >= 0, got %d"
                                 % (name.replace("_", "-"), getattr(self, name)))
        if not (math.isfinite(self.alpha) and 0.0 < self.alpha < 1.0):
            raise ValueError("--alpha must lie in (0, 1), got %g" % self.alpha)
        return self


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
    (:func:`analysis.diagnose.with_run_sd`); and the priors of the model's base parameters
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

    def _split(self, theta, effects):
        """(base parameters, effects) of the model: the added strengths read from ``theta``."""
        th = {k: v for k, v in theta.items() if k not in self.added}
        eff = dict(effects or {})
        eff.update({k: theta.get(k, s) for k, s in self.added.items()})
        return th, eff

    def predict(self, theta, effects=None):
        return self.model.predict(*self._split(theta, effects))

    def prefetch(self, pairs):
        """The model's batch evaluation of the points a fit asks for next, where it has one."""
        f = getattr(self.model, "prefetch", None)
        if f is not None:
            f([self._split(t, e) for t, e in pairs])

    def model_se(self):
        if getattr(self.model, "state_dependent_se", False):
            # the model's own uncertainty where each fit asks (an emulator's): a callable
            def se_at(theta, effects=None):
                return self.model.model_se(*self._split(theta, effects))
            if hasattr(self.model, "model_cov"):
                # ... and how its errors at one point correlate between the observations
                def cov_at(theta, effects=None):
                    return self.model.model_cov(*self._split(theta, effects)), self.model.keys
                se_at.cov = cov_at
            if hasattr(self.model, "mode_components"):
                # ... and its response per motion mode: the likelihood is their mixture
                def modes_at(theta, effects=None):
                    return self.model.mode_components(*self._split(theta, effects))
                se_at.modes = modes_at
            return se_at
        return self.model.model_se(self.theta)


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


@dataclass
class RerunScore:
    """The data against a twin rerun's means (:func:`rerun_score`) and the emulator's check
    there (:func:`emulator_vs_twin`, set by the confirmation)."""

    prediction: pd.Series            # the rerun's mean per (condition_id, observable)
    z: pd.Series                     # (prediction - data) / sigma
    chi2: float
    dof: int
    emulator_vs_twin: dict | None = None

    @property
    def chi2_dof(self) -> float:
        return self.chi2 / max(self.dof, 1)

    @property
    def p_value(self) -> float:
        """The data against the rerun's means: chi2 with ``dof`` (at least 1)."""
        return float(stats.chi2.sf(self.chi2, max(self.dof, 1)))


@dataclass
class Rerun:
    """One confirmation round: the twin at the fitted point."""

    round: int
    point: dict                      # the fitted point it ran at (base parameters, strengths)
    runs: pd.DataFrame
    score: RerunScore
    moved_se: float                  # how far the refit with its runs moved the point [se]
    focus: dict | None = None        # the focus wave it triggered (missed or not sure)
    lean: Lean | None = None         # the refit's lean on the emulator (:func:`lean_of`)

    def record(self) -> dict:
        """What loop.json's ``reruns`` holds of it (no runs: model_runs.csv has them)."""
        out = {"round": self.round, "point": self.point, "moved_se": self.moved_se}
        if self.focus is not None:
            out["focus"] = self.focus
        if self.lean is not None:
            out["lean"] = self.lean.record()
        return out | {"chi2": self.score.chi2, "dof": self.score.dof,
                      "emulator_vs_twin": self.score.emulator_vs_twin}


@dataclass
class Lean:
    """How much a fit leans on the emulator's uncertainty (:func:`lean_of`)."""

    share: float                     # largest emulator sd / data sd over the observations
    worst: str                       # the observation of that share
    chi2_data: float                 # chi2 at the fit's means with the data's sd alone
    dof: int
    p_data: float                    # its p-value (chi2 with dof)
    p_fit: float                     # the fit's own p-value (the emulator's sd in sigma)
    alpha: float                     # the level it is judged at
    undecided: tuple = ()            # (observation, its z with the data's sd alone, its
    #                                  share): history matching's undecided observations
    #                                  (SURE_SHARE), largest |z| first

    @property
    def sure(self) -> bool:
        """The point may be final: the emulator's uncertainty does not decide whether the data
        fit there - they fit its means with their own sd alone, or they misfit even with it
        (history matching's undecided point: plausible only with the emulator's variance)."""
        return self.p_data >= self.alpha or self.p_fit < self.alpha

    def record(self) -> dict:
        return {"share": self.share, "worst": self.worst, "chi2_data": self.chi2_data,
                "dof": self.dof, "p_data": self.p_data, "p_fit": self.p_fit,
                "sure": self.sure,
                "undecided": [{"observation": o, "z_data": z, "share": q}
                              for o, z, q in self.undecided]}

    def words(self) -> str:
        out = ("the emulator's sd there is %.2f of the data's (at %s); at its means with the "
               "data's sd alone chi2/dof %.2f (p = %.2g)"
               % (self.share, self.worst, self.chi2_data / max(self.dof, 1), self.p_data))
        if self.undecided:
            out += "; undecided: %s%s" % (", ".join(
                "%s (its mean %.1f data sds off, the emulator's sd %.1f of the data's)"
                % u for u in self.undecided[:3]),
                " and %d more" % (len(self.undecided) - 3) if len(self.undecided) > 3 else "")
        return out


def lean_of(fit, obs, alpha) -> Lean:
    """How far ``fit`` (a FitResult scored with the emulator's sd in sigma) rests on the
    emulator's uncertainty at its point: per observation of ``obs`` the emulator's sd
    sqrt(sigma^2 - sd^2) against the data's sd, and the chi2 of the fit's means (each condition
    in the motion mode it was scored in) with the data's sd alone beside the fit's own. A point
    where the data are plausible only because the emulator does not know the twin there (the
    fit passes at ``alpha``, the data's sd alone does not) is not yet a result."""
    key = pd.MultiIndex.from_frame(obs[["condition_id", "observable"]])
    sd = pd.Series(obs["sd"].to_numpy(float), index=key).reindex(fit.prediction.index)
    sigma = (pd.Series(fit.sigma, index=fit.prediction.index) if fit.sigma is not None
             else sd)
    measured = fit.prediction - fit.residuals * sigma
    em = np.sqrt(np.maximum(sigma ** 2 - sd ** 2, 0.0))
    share = (em / sd).fillna(0.0)
    z = (fit.prediction - measured) / sd
    chi2 = float(np.nansum(z ** 2))
    dof = max(int(np.isfinite(z).sum()) - len(fit.params), 1)
    i = share.idxmax() if len(share) else ("", "")
    from analysis.history_matching import CUTOFF
    off = (share > SURE_SHARE) & (z.abs() > CUTOFF) & ((z * sd / sigma).abs() <= CUTOFF)
    undecided = tuple(("%s %s" % k, float(z[k]), float(share[k]))
                      for k in z[off].abs().sort_values(ascending=False).index)
    return Lean(share=float(share.max()) if len(share) else 0.0, worst="%s %s" % i,
                chi2_data=chi2, dof=dof, p_data=float(stats.chi2.sf(chi2, dof)),
                p_fit=float(fit.p_value), alpha=float(alpha), undecided=undecided)


def rerun_score(obs, pred, se, final, n_params) -> RerunScore:
    """chi2 of the data against a twin rerun's means (the priors' pseudo-observations at the
    fit's values), sigma = hypot(measured sd, the rerun mean's se) per key (z), and the data's
    shared errors (a film's scale: ``shared_sd``) correlating the keys they share in chi2."""
    key = pd.MultiIndex.from_frame(obs[["condition_id", "observable"]])
    p = pred.reindex(key).to_numpy(float)
    p = np.where(np.isfinite(p), p, final.prediction.reindex(key).to_numpy(float))
    s = np.hypot(obs["sd"].to_numpy(float), se.reindex(key).fillna(0.0).to_numpy(float))
    r = p - obs["value"].to_numpy(float)
    z = r / s
    ok = np.isfinite(z)
    shared = shared_covariance(obs.reset_index(drop=True))
    if shared is None:
        chi2 = float(np.sum(z[ok] ** 2))
    else:
        S = (np.diag(s ** 2) + shared)[np.ix_(ok, ok)]
        chi2 = float(r[ok] @ linalg.cho_solve(linalg.cho_factor(S, lower=True), r[ok]))
    return RerunScore(prediction=pd.Series(p, index=key), z=pd.Series(z, index=key),
                      chi2=chi2, dof=int(ok.sum()) - n_params)


def joint_fit(model, obs, theta, added):
    """The base parameters and the added effects' strengths fitted together on ``model``
    (the strengths read from the parameters; the model's noise plus the effects' resolution
    error): a FitResult."""
    w = WithAdded(model, added, theta)
    _, fit = calibrate_base(w.predict, obs, fitted_parameters(model, theta, added),
                            model_se=w.model_se())
    return fit


def _stage_row(stage, fit, n_params):
    return {"stage": stage, "chi2": fit.chi2, "dof": fit.dof, "chi2_dof": fit.chi2_dof,
            "p_value": fit.p_value, "n_params": n_params}


# --------------------------------------------------------------------------- selection

def _null_draw(w, args, o):
    """One bootstrap draw's diagnosis: (its largest identifiable chi2 gain, an effect named)."""
    base_params, effs, alpha, noise_observables, conditions = args
    d = diagnose(w.predict, o, base_params, effs, model_se=w.model_se(),
                 crn_correlation=getattr(w.model, "crn_correlation", 0.0),
                 conditions=conditions, alpha=alpha, noise_observables=noise_observables,
                 structure=False)
    t = d.table[d.table["identifiable"]]
    return (float(t["delta_chi2"].max()) if len(t) else 0.0), d.best is not None


def _null_draws(w, obs, mu, sig, chol, args, seed, n_draws, n_jobs, progress) -> list:
    """The bootstrap's draws about ``mu`` (noise ``sig``, or ``chol`` @ z where the emulator's
    errors correlate), each diagnosed: [(largest gain, an effect named)]."""
    rng = np.random.default_rng(seed)
    noise = (lambda z: sig * z) if chol is None else (lambda z: chol @ z)
    draws = [obs.assign(value=mu + noise(rng.standard_normal(len(mu))))
             for _ in range(int(n_draws))]
    return in_processes(functools.partial(_null_draw, w, args), draws, n_jobs,
                        "bootstrap draws", "draw", progress)


@dataclass(frozen=True)
class DrawsCache:
    """Where a loop keeps its diagnosis steps' bootstrap outcomes (:func:`null_scale`):
    ``store``, a :class:`analysis.fit_cache.FitCache` in ``<runs dir>/bootstrap_draws``, and
    ``context``, the hash of what made the model (the loop's settings, the conditions, the
    runs the emulator was fitted to: :func:`draws_cache`)."""

    store: object
    context: str


def draws_cache(state) -> DrawsCache | None:
    """The :class:`DrawsCache` of a loop whose emulator fits are cached (None otherwise)."""
    from analysis.fit_cache import DRAWS_FOLDER, FitCache, digest
    fits = getattr(state.model, "fit_cache", None)
    if fits is None:
        return None
    return DrawsCache(FitCache(fits.folder.parent / DRAWS_FOLDER),
                      digest(dataclasses.replace(state.settings, n_jobs=1),
                             state.dataset.conditions, state.model.runs_))


def _draws_key(context, obs, w, args, seed, n_draws, mu, sig, chol) -> str:
    """The hash a step's bootstrap outcomes are kept under: the code, what made the model
    (``context``), the observations, the point and the added effects, the candidates, the
    test's settings, the seed and number of draws, and the calibrated fit's mean and noise."""
    from analysis.fit_cache import code_fingerprint, digest
    base_params, effs, alpha, noise_obs, conditions = args
    return digest("bootstrap draws", code_fingerprint(), context, obs,
                  sorted(w.added.items()), sorted((w.theta or {}).items()),
                  list(base_params), list(effs), alpha, sorted(noise_obs or ()), conditions,
                  int(seed), int(n_draws), mu, sig, chol)


def null_scale(diag, w, obs, base_params, effs, *, n_draws, alpha, noise_observables,
               conditions, seed=0, n_jobs=1, progress=False, cache=None):
    """Parametric bootstrap of one diagnosis step: ``n_draws`` datasets drawn from the step's
    calibrated fit (no further effect; Gaussian noise with the stated sigma) are diagnosed like
    the real one. Returns (c, null_max, n_false): c >= 1 scales the nominal chi2-gain threshold
    so that the draws' median largest gain sits where the nominal law puts it - what the scan
    over each strength's range and the bounds add to chance (look-elsewhere); n_false counts
    the draws in which an effect was significant at the nominal level. ``n_jobs`` > 1
    diagnoses the draws in that many processes (the same draws, the same answer);
    ``progress``: a bar over the draws on stderr. ``cache`` (a :class:`DrawsCache`): the
    draws' outcomes are kept under a hash of everything they depend on and read back when
    the same step comes again (a resumed loop)."""
    cal = diag.calibrated
    key = pd.MultiIndex.from_frame(obs[["condition_id", "observable"]])
    mu = cal.prediction.reindex(key).to_numpy(float)
    sig = np.asarray(cal.sigma, float)
    args = (base_params, effs, alpha, noise_observables, conditions)
    ck = None if cache is None else _draws_key(cache.context, obs, w, args, seed, n_draws,
                                                mu, sig, cal.chol)
    hit = None if ck is None else cache.store.get(ck)
    if hit is not None and len(hit.get("outcomes") or ()) == int(n_draws):
        out = [(float(g), bool(b)) for g, b in hit["outcomes"]]
    else:
        out = _null_draws(w, obs, mu, sig, cal.chol, args, seed, n_draws, n_jobs, progress)
        if ck is not None:
            cache.store.put(ck, {"outcomes": [[g, bool(b)] for g, b in out]})
    null_max = [g for g, _ in out]
    n_false = sum(int(b) for _, b in out)
    k = max(int(diag.table["identifiable"].sum()), 1)
    sim = np.max(stats.chi2.rvs(1, size=(4000, k), random_state=1), axis=1)
    ratio = np.median(null_max) / max(float(np.median(sim)), 1e-12) if null_max else 1.0
    return max(1.0, float(ratio)), null_max, n_false


@dataclass
class Selection:
    """What forward selection found (:func:`forward_select`)."""

    added: dict                      # effect -> strength, in the order added
    theta: dict                      # the base parameters at the last addition's fit
    diagnoses: list                  # one Diagnosis per step
    steps: list                      # their tables, with a ``step`` column
    stairs: list                     # staircase rows '+ <effect>'
    last_fit: object = None          # the fit of the last addition (None: nothing added)
    null: list = field(default_factory=list)   # per step: the bootstrap's threshold scale,
    #                                   its draws' largest gains, false alarms
    need: dict = field(default_factory=dict)   # effect -> the chi2 gain it needed when added


def forward_select(model, obs, theta, *, conditions=None, alpha=0.01, max_effects=MAX_EFFECTS,
                   noise_observables=None, log=print, null_draws=0, n_jobs=1, progress=False,
                   draws=None):
    """Forward selection of effects on a model with ``predict``, ``model_se``, ``base_params``
    and ``effects`` (:class:`analysis.emulated_twin.TwinModelContract`): diagnose, add the
    best significant effect (its strength joins the fitted
    parameters), diagnose the rest again, until nothing more is significant or ``max_effects``
    are in.

    Returns a :class:`Selection`.

    With ``null_draws`` > 0 an effect must also beat the nominal threshold scaled by
    :func:`null_scale` (the significance calibrated on data drawn from the fitted model).
    ``progress``: a bar per step over the candidates' fits and one over the bootstrap draws;
    ``draws``: a :class:`DrawsCache` of the bootstrap's outcomes.
    """
    theta = dict(theta)
    added, diags, step_rows, stairs, last_fit = {}, [], [], [], None
    nulls, need = [], {}
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
                        alpha=alpha, noise_observables=noise_observables, n_jobs=n_jobs,
                        progress="step %d: candidates" % step if progress else None)
        t = diag.table.copy()
        t.insert(0, "step", step)
        t["threshold_scale"] = 1.0
        scale = 1.0
        if diag.best is not None and null_draws:
            c, nm, nf = null_scale(diag, w, obs, fitted_parameters(model, theta, added), effs,
                                   n_draws=null_draws, alpha=alpha, conditions=conditions,
                                   noise_observables=noise_observables, seed=step,
                                   n_jobs=n_jobs, progress=progress, cache=draws)
            nulls.append({"step": step, "scale": c, "null_max_delta_chi2": nm,
                          "n_false": nf, "n_draws": null_draws})
            t["threshold_scale"] = scale = c
            needed = c * diag.threshold_delta_chi2
            keep = t["significant"] & (t["delta_chi2"] > needed)
            if not keep.any():
                log("step %d: %s does not beat the bootstrap-calibrated threshold (chi2 gain "
                    "%.1f, needed %.1f = %.2f x nominal; %d of %d null draws named an effect)"
                    % (step, diag.best, float(t.loc[t["effect"] == diag.best, "delta_chi2"]
                                              .iloc[0]), needed, c, nf, null_draws))
                t["significant"] = False
                diag.verdict = ("nothing beyond the bootstrap-calibrated threshold: %s gains "
                                "chi2 %.1f, %.1f needed (%d of %d datasets drawn from the fit "
                                "without it named an effect at the nominal level)"
                                % (diag.best, float(t.loc[t["effect"] == diag.best,
                                                          "delta_chi2"].iloc[0]), needed, nf,
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
        need[diag.best] = scale * diag.threshold_delta_chi2
        added[diag.best] = float(fit.params[diag.best])
        theta = {k: float(fit.params[k]) for k in theta}
        for k in list(added):
            if k in fit.params:
                added[k] = float(fit.params[k])
        last_fit = fit
        stairs.append(_stage_row("+ " + diag.best, fit, nb + len(added)))
    return Selection(added=added, theta=theta, diagnoses=diags, steps=step_rows,
                     stairs=stairs, last_fit=last_fit, null=nulls, need=need)


def prune_effects(model, obs, theta, added, need, log=print):
    """Backward elimination on a refitted model: each effect in ``added`` must still gain
    what it needed when it was added (``need``: its step's chi2-gain threshold, the bootstrap's
    scale included) against the fit without it; the weakest that does not is dropped and the
    rest checked again. An effect that compensated another's wrong strength on an emulator
    that has since learned from twin runs there (a decoy) goes; the strength of one that
    stays is refitted. Returns (theta, added, fit, dropped) with ``dropped`` a list of
    {"effect", "delta_chi2", "needed"} and ``fit`` the joint fit at the end."""
    theta, added = dict(theta), dict(added)
    fit = joint_fit(model, obs, theta, added)
    dropped = []
    while added:
        base = {k: float(fit.params[k]) for k in theta}
        trial = {}
        for k in added:
            rest = {j: float(fit.params[j]) for j in added if j != k}
            f = joint_fit(model, obs, base, rest)
            trial[k] = (max(f.objective - fit.objective, 0.0), f)
        k = min(trial, key=lambda j: trial[j][0] - need.get(j, 0.0))
        gain, f = trial[k]
        if gain >= need.get(k, 0.0):
            break
        log("%s dropped: on the refitted emulator it gains chi2 %.1f, %.1f needed"
            % (k, gain, need.get(k, 0.0)))
        dropped.append({"effect": k, "delta_chi2": gain, "needed": float(need.get(k, 0.0))})
        added = {j: float(f.params[j]) for j in added if j != k}
        theta = {j: float(f.params[j]) for j in theta}
        fit = f
    return ({k: float(fit.params[k]) for k in theta},
            {k: float(fit.params[k]) for k in added}, fit, dropped)


# --------------------------------------------------------------------------- the state

@dataclass
class LoopState:
    """Everything the stages hand on: the dataset and its observations, the one model, the
    fits of each stage and the twin's reruns."""

    dataset: object
    settings: LoopSettings
    base_config: dict | None
    obs0: pd.DataFrame               # the dataset's observations
    flight_ids: list
    model: object                    # EmulatedTwin
    obs: pd.DataFrame | None = None  # what the fits see (impact sds floored at one run's)
    waves: dict = field(default_factory=dict)
    stair: list = field(default_factory=list)
    baseline: object = None          # FitResult at the reference point
    calibrated: object = None        # FitResult, base parameters fitted
    selection: Selection | None = None  # forward_select's answer
    theta: ParameterVector | None = None  # base parameters at the current point
    added: ParameterVector | None = None  # effect -> strength, in the order added
    final: object = None             # the last fit
    reruns: list = field(default_factory=list)      # a Rerun per confirmation round
    dropped: list = field(default_factory=list)     # effects dropped after a rerun (prune)
    focus: dict = field(default_factory=dict)       # the focus wave: its centre, runs, before
    intervals: dict = field(default_factory=dict)   # name -> ProfileInterval
    interval_rounds: list = field(default_factory=list)  # runs at the intervals' ends
    tracking: pd.DataFrame | None = None
    tracks: dict = field(default_factory=dict)
    progress: bool = True            # progress bars on stderr for the long analysis steps

    @property
    def n_base(self):
        return len(self.model.base_params())

    @property
    def coordinates(self) -> dict:
        """{name: Coordinate} of the model's base parameters and candidates' strengths (its
        bounds, the units :mod:`analysis.parameter_space` declares)."""
        return coordinates_of(self.model.base_params(), self.model.effects())

    def vector(self, values, names=None) -> ParameterVector:
        """A ParameterVector of ``names`` (default: all of ``values``) read from ``values``."""
        names = list(values.keys() if names is None else names)
        return ParameterVector.of(values, names, self.coordinates)

    def set_point(self, theta, added):
        """The current point: base parameters ``theta`` and the added strengths ``added``."""
        self.theta, self.added = self.vector(theta), self.vector(added)

    @property
    def point(self) -> ParameterVector:
        """The current point: the base parameters, then the added effects' strengths."""
        return self.theta | self.added


def loop_space(dataset, extra_effects=(), free=(), base=DEFAULT_BASE):
    """The design space of a loop on ``dataset``: the base parameters ``base`` (default
    :data:`DEFAULT_BASE`; the stroke left out when every condition states it) over their
    priors, then the
    parameters ``free`` names ((name, lo, hi): ``--free``, an apparatus parameter or a
    narrower prior of a base one), the default DEM catalog and the optional DEM entries asked
    for (an observation entry is no design input: :class:`analysis.emulated_twin.EmulatedTwin`
    applies it to its predictions)."""
    from analysis.history_matching import DesignSpace
    from analysis.run_configs import stated_amplitude_m
    from analysis.catalog import OPTIONAL_CANDIDATES
    phys = physics_table(dataset.conditions)
    stated = all(stated_amplitude_m(r) is not None for r in phys.to_dict("records"))
    names = [n for n in dict.fromkeys(list(base) + [f[0] for f in free])
             if not (stated and n == "amplitude_m")]
    opt = {c.name: c for c in OPTIONAL_CANDIDATES}
    effs = [c for c in CANDIDATES if c.kind == "dem"] + [opt[n] for n in extra_effects
                                                         if opt[n].kind == "dem"]
    return DesignSpace.of(names, tuple(effs), priors={n: (lo, hi) for n, lo, hi in free})


def read_stage(dataset, settings, *, base_config=None, track_cache=None, progress=True,
               log=print, track=True, fit_cache=None) -> LoopState:
    """Track the dataset's films (cached; not with ``track=False``), read its observations,
    set up the model (its emulators' fits remembered in ``fit_cache``, an
    :class:`analysis.fit_cache.FitCache`, when given)."""
    from analysis.emulated_twin import EmulatedTwin
    tracking, tracks = None, {}
    if track and dataset.video_files and any(c not in dataset.tracks
                                             for c in dataset.video_files):
        from analysis.config import TRACK_CACHE_DIR
        from analysis.videos import track_dataset_videos
        tracks, tracking = track_dataset_videos(dataset, track_cache or TRACK_CACHE_DIR,
                                                progress=progress)
        log("tracked %d film(s): %s" % (len(tracking), "; ".join(
            "%s %d frames, %d lost, %d re-acquired, %.4f mm/px (%s)%s"
            % (q.condition_id, q.n_frames, q.n_lost, q.n_reacquired, q.m_per_px * 1e3,
               q.scale_source, " [cached]" if q.cached else "") for q in tracking.itertuples())))
        dataset = dataclasses.replace(dataset, tracks=dict(dataset.tracks, **tracks))
    obs0, fl_ids, _ = dataset_observations(dataset, settings.flights)
    pins = pinned_observation(dataset)
    for n in settings.extra_effects:
        if n in pins:
            log("%s: pinned by videos/video.json (%s), applied to every prediction, not "
                "diagnosed" % (n, ", ".join("%s %g" % kv for kv in pins[n].items())))
    space = loop_space(dataset, settings.extra_effects, settings.free, settings.base)
    ref = dict(apparatus_reference(base_config), **reference_parameters())
    ref = {p.name: float(np.clip(ref.get(p.name, np.mean(p.prior)), *p.prior))
           for p in space.base}
    model = EmulatedTwin(dataset.conditions, space, velocity_frame=dataset.velocity_frame,
                         flight_conditions=fl_ids, yield_times_min=yield_times_of(dataset),
                         theta_ref=ref, seed=settings.seed,
                         observation=[n for n in settings.extra_effects
                                      if candidates()[n].kind == "observation"
                                      and n not in pins],
                         pinned=pins, fit_cache=fit_cache)
    asked = set(settings.base) | {n for n, _, _ in settings.free}
    if "amplitude_m" in asked and "amplitude_m" not in space.base_names:
        model.held["amplitude_m"] = "stated by the dataset"
    return LoopState(dataset=dataset, settings=settings, base_config=base_config, obs0=obs0,
                     flight_ids=fl_ids, model=model, tracking=tracking, tracks=tracks,
                     progress=progress)


def apparatus_reference(base_config=None) -> dict:
    """The reference value of each apparatus parameter: the runs' own (``--set``, the base
    config) where given, else the run config's default (the 25 mL jar's); a parameter derived
    from others (the jar's diameter and length from its volume) has none here and starts at
    its prior's middle."""
    from analysis.config import twin_config
    from analysis.parameter_space import APPARATUS
    cfg = twin_config.complete_config(dict(base_config or {}))
    return {k: float(cfg[k]) for k in APPARATUS if cfg.get(k) is not None}


def wave0_runs(state: LoopState) -> pd.DataFrame:
    """The runs of wave 0 (what :func:`analysis.emulated_twin.build_in_waves` runs first)."""
    from analysis.emulated_twin import wave0_runs as design
    s = state.settings
    return design(state.model, s.points, s.replicates, s.seed, state.base_config)[1]


def build_stage(state: LoopState, twin, log=print):
    """Wave 0 and the refinement waves; the model fitted to all their runs."""
    from analysis.emulated_twin import build_in_waves
    s = state.settings
    model, _, hist = build_in_waves(state.model, state.obs0, twin, n_initial=s.points,
                                    n_waves=s.waves, per_wave=s.per_wave,
                                    replicates=s.replicates, seed=s.seed,
                                    base_config=state.base_config, log=log,
                                    obs_chaos_runs=1.0)
    state.model, state.waves = model, hist
    state.obs = fit_observations(state.obs0, model)


def calibrate_stage(state: LoopState):
    """The base parameters fitted on the emulator (its sd in the likelihood)."""
    m = state.model
    w = WithAdded(m, {})
    state.baseline, state.calibrated = calibrate_base(m.predict, state.obs, m.base_params(),
                                                      model_se=w.model_se())
    state.set_point({p.name: state.calibrated.params[p.name] for p in m.base_params()}, {})
    state.final = state.calibrated
    state.stair = [_stage_row("baseline", state.baseline, 0),
                   _stage_row("calibrated", state.calibrated, state.n_base)]


def noise_observables(state: LoopState) -> set:
    out = {"v_mean_m_s", "f_col_hz"}
    if state.flight_ids:
        from analysis.flights import FLIGHT_OBSERVABLES
        out |= set(FLIGHT_OBSERVABLES)
    return out


def select_stage(state: LoopState, log=print):
    """Forward selection of the missing effects from the calibrated point."""
    s = state.settings
    fs = forward_select(state.model, state.obs, state.theta,
                        conditions=state.dataset.conditions, alpha=s.alpha,
                        max_effects=s.max_effects, noise_observables=noise_observables(state),
                        log=log, null_draws=s.null_draws, n_jobs=s.n_jobs,
                        progress=state.progress, draws=draws_cache(state))
    state.selection = fs
    state.set_point(fs.theta, fs.added)
    if fs.last_fit is not None:
        state.final = fs.last_fit
    state.stair += fs.stairs


def focus_stage(state: LoopState, twin, log=print):
    """The focus wave: ``focus_points`` design points where the selected fit's posterior lies
    (:func:`analysis.history_matching.posterior_cloud`: the base parameters from its Gaussian
    approximation widened, the strengths of the effects found stratified over their whole
    range - the twin's response to them measured at the fitted base point, not only where the
    emulator believes the strength is), run at every condition; the emulator refitted with
    them, then the calibration and the forward selection redone on it - the emulator is
    refined where the verdict is made before the verdict is taken."""
    state.focus = focus_wave(state, twin, log)


def focus_wave(state: LoopState, twin, log=print, *, wave="focus", seed_add=0) -> dict | None:
    """One focus wave (see :func:`focus_stage`) about the current fit; its record {n_points,
    n_runs, before, after} (None with ``focus_points`` 0). ``seed_add`` draws another cloud."""
    from analysis.history_matching import design_runs, effect_input, posterior_cloud
    s, m = state.settings, state.model
    if s.focus_points < 1:
        return None
    cands = candidates()
    dem = {k: v for k, v in state.added.items() if cands[k].kind == "dem"}
    centre = dict(state.theta, **{effect_input(k): v for k, v in dem.items()})
    centre = {k: v for k, v in centre.items() if k in m.space.bounds()}
    cov = state.final.cov.rename(index=lambda k: effect_input(k) if k in dem else k,
                                 columns=lambda k: effect_input(k) if k in dem else k)
    pts = posterior_cloud(m.space, centre, cov, s.focus_points,
                          seed=s.seed + FOCUS_SEED0 + seed_add,
                          spread=[effect_input(k) for k in dem],
                          ridge=ridge_of(state, {effect_input(k): k for k in dem}))
    pts.insert(0, "point", np.arange(len(pts)) + int(m.runs_["point"].max()) + 1)
    runs = design_runs(m.space, pts, m.conditions, seeds=(s.seed + FOCUS_SEED0,),
                       base_config=state.base_config)
    runs["wave"] = wave
    log("%s wave: %d points about the fit (%s), %d runs"
        % (wave, len(pts), state.point.describe(), len(runs)))
    runs = twin(runs)
    m.fit(pd.concat([m.runs_, runs], ignore_index=True))
    before = {"point": state.point.to_dict(), "effects": state.added.to_dict(),
              "chi2_dof": state.final.chi2_dof}
    calibrate_stage(state)
    select_stage(state, log)
    if set(before["effects"]) != set(state.added):
        log("after the %s wave the selection changed: %s -> %s"
            % (wave, ", ".join(before["effects"]) or "nothing",
               ", ".join(state.added) or "nothing"))
    return {"n_points": int(len(pts)), "n_runs": int(len(runs)), "before": before,
            "after": {"point": state.point.to_dict(),
                      "effects": state.added.to_dict(), "chi2_dof": state.final.chi2_dof}}


def ridge_of(state: LoopState, names: dict):
    """The ridge a focus wave follows: a callable from held strengths (a DataFrame whose
    columns are the design inputs ``names`` maps to effect names) to the base parameters
    fitted at them on the emulator's mean (chi2 with the data's sd only: where the data are
    plausible, not where the emulator is sure), each fit started from the nearest one already
    made towards the current fit (a continuation along one strength)."""
    m, obs = state.model, state.obs
    bp = m.base_params()

    def at(held: dict, start: dict) -> dict:
        eff = dict(state.added, **held)

        def pred(theta, effects=None):
            return m.predict(theta, dict(effects or {}, **eff))
        if hasattr(m, "prefetch"):         # the emulator's batch of a Jacobian's points
            pred.prefetch = lambda pairs: m.prefetch([(t, dict(e or {}, **eff))
                                                      for t, e in pairs])
        starts = [BaseParameter(p.name, float(np.clip(start.get(p.name, p.value), p.lower,
                                                      p.upper)), p.lower, p.upper) for p in bp]
        _, fit = calibrate_base(pred, obs, starts)
        return {p.name: float(fit.params[p.name]) for p in bp}

    def ridge(values: pd.DataFrame) -> pd.DataFrame:
        held = values.rename(columns=names)
        first = held.columns[0]
        s0 = float(state.added.get(first, 0.0))
        out = [None] * len(held)
        for side in (held[first] >= s0, held[first] < s0):
            start = dict(state.theta)
            order = held[side][first].sub(s0).abs().sort_values().index
            for i in order:
                start = at({k: float(held.at[i, k]) for k in held.columns}, start)
                out[i] = start
        return pd.DataFrame(out, index=values.index)
    return ridge


def twin_means(model, runs, theta, effects):
    """(mean, se) Series by the model's keys of the twin's own runs at one point: the run means
    of speed, f_col and the impact observables, the yields through the fitted powder line (or
    kinetics effect) - the emulator's :meth:`_assemble` on the runs instead of its emulators."""
    from analysis.emulated_twin import SPEED_COLUMN
    from analysis.emulator import Prediction
    cids = list(model.conditions["condition_id"])
    parts = {}
    for o in (SPEED_COLUMN[model.velocity_frame], "f_col_hz") + model.flight_obs:
        g = runs.groupby("condition_id")[o]
        mean = g.mean().reindex(cids).to_numpy(float)
        n = g.count().reindex(cids).to_numpy(float)
        se = (g.std(ddof=1).reindex(cids).to_numpy(float) / np.sqrt(np.maximum(n, 1)))
        parts[o] = Prediction(mean[None], np.nan_to_num(se, nan=0.0)[None],
                              np.zeros((1, len(cids))))
    return tuple(pd.Series(model._assemble(parts, theta, effects, which), index=model.keys,
                           dtype=float) for which in ("mean", "latent_sd"))


def fitted_moves(a, b) -> float:
    """Largest move between two fits in units of the later fit's standard errors."""
    out = 0.0
    for k, v in b.params.items():
        se = float(b.stderr.get(k, np.nan))
        if k in a.params and np.isfinite(se) and se > 0:
            out = max(out, abs(float(v) - float(a.params[k])) / se)
    return out


#: the emulator's stated uncertainty covers a twin rerun when the chi2 of their difference has
#: a p-value of at least this (chi2 with one dof per observation)
COVER_P = 0.01


def emulator_vs_twin(model, obs, theta, added, twin_mean, n_seeds) -> dict:
    """The emulator against a twin rerun at one point, before the rerun's runs join it (an
    out-of-sample test of its stated uncertainty): per observation of ``obs``
    z = (emulator mean - rerun mean) / sqrt(emulator sd^2 + chaos sd^2 / n_seeds), the chaos sd
    the emulator's own (pooled over every run, steadier than the sd of ``n_seeds`` runs).
    Returns {"chi2", "n", "p", "max_abs_z", "worst"} (p: chi2 with n dof)."""
    cands = candidates()
    w = WithAdded(model, added, theta)
    th = dict(theta, **added)
    mu = w.predict(th)
    se = w.model_se()
    se = se(th) if callable(se) else se
    dem = {k: v for k, v in added.items() if cands[k].kind == "dem"}
    chaos = model.chaos_sd(theta, dem)
    key = pd.MultiIndex.from_frame(obs[["condition_id", "observable"]])
    d = mu.reindex(key).to_numpy(float) - twin_mean.reindex(key).to_numpy(float)
    var = (se.reindex(key).fillna(0.0).to_numpy(float) ** 2
           + chaos.reindex(key).fillna(0.0).to_numpy(float) ** 2 / max(int(n_seeds), 1))
    with np.errstate(invalid="ignore", divide="ignore"):
        z = d / np.sqrt(var)
    ok = np.isfinite(z)
    n = int(ok.sum())
    chi2 = float(np.sum(z[ok] ** 2))
    if n and hasattr(model, "model_cov"):
        # the emulator's errors at one point move together across conditions: chi2 in the
        # metric of its covariance plus the rerun's chaos
        idx = model.keys.get_indexer(key[ok])
        S = model.model_cov(theta, dict(added))[np.ix_(idx, idx)]
        S[np.diag_indices_from(S)] = var[ok]
        chi2 = float(d[ok] @ np.linalg.solve(S, d[ok]))
    i = int(np.nanargmax(np.where(ok, np.abs(z), -np.inf))) if n else 0
    return {"chi2": chi2, "n": n, "p": float(stats.chi2.sf(chi2, n)) if n else float("nan"),
            "max_abs_z": float(abs(z[i])) if n else float("nan"),
            "worst": "%s %s" % key[i] if n else ""}


def confirm_stage(state: LoopState, twin, log=print):
    """The twin at the final point (a design point), the emulator refitted with its runs, the
    final fit redone; the next round (``confirm_rounds`` at most) when the point moved by
    :data:`CONFIRM_TOL_SE` or more, or when the rerun fell beyond the emulator's stated
    uncertainty (:func:`emulator_vs_twin` p < :data:`COVER_P`), or when the refitted point
    leans on the emulator's uncertainty (:func:`lean_of`: the data plausible there only
    because the emulator does not know the twin) - then a focus wave about the refitted point
    first (:func:`focus_wave`: one point's runs do not teach the emulator the neighbourhood),
    the calibration and the selection redone on it."""
    from analysis.history_matching import design_runs
    s, m = state.settings, state.model
    cands = candidates()
    for r in range(s.confirm_rounds):
        dem = {k: v for k, v in state.added.items() if cands[k].kind == "dem"}
        pt = m.point(state.theta, dem)
        pt.insert(0, "point", int(m.runs_["point"].max()) + 1)
        seed0 = CONFIRM_SEED0 + r * s.rerun_replicates
        runs = design_runs(m.space, pt, m.conditions,
                           seeds=range(seed0, seed0 + s.rerun_replicates),
                           base_config=state.base_config)
        runs["wave"] = "confirm %d" % (r + 1)
        log("twin rerun at the final point (%d seeds per condition): %s"
            % (s.rerun_replicates, state.point.describe()))
        runs = twin(runs)
        pred, se = twin_means(m, runs, state.theta, state.added)
        n_par = state.n_base + len(state.added)
        score = rerun_score(state.obs, pred, se, state.final, n_par)
        score.emulator_vs_twin = emulator_vs_twin(m, state.obs, state.theta, state.added,
                                                  pred, s.rerun_replicates)
        state.stair.append({"stage": "twin rerun", "chi2": score.chi2, "dof": score.dof,
                            "chi2_dof": score.chi2_dof,
                            "p_value": score.p_value,
                            "n_params": n_par})
        m.fit(pd.concat([m.runs_, runs], ignore_index=True))
        theta, added, refit, dropped = prune_effects(m, state.obs, state.theta, state.added,
                                                     state.selection.need, log)
        moved = fitted_moves(state.final, refit) if not dropped else math.inf
        state.dropped += [dict(d, round=r + 1, wave=runs["wave"].iloc[0]) for d in dropped]
        state.reruns.append(Rerun(round=r + 1, point=state.point.to_dict(), runs=runs,
                                  score=score, moved_se=moved))
        state.stair.append(_stage_row("refitted on the twin reruns", refit,
                                      state.n_base + len(added)))
        log("refitted with the rerun's runs: chi2/dof %.2f, %s"
            % (refit.chi2_dof, "the point moved %.2f se" % moved if not dropped else
               "without %s" % ", ".join(d["effect"] for d in dropped)))
        state.final = refit
        state.set_point(theta, added)
        lean = state.reruns[-1].lean = lean_of(refit, state.obs, s.alpha)
        ev = score.emulator_vs_twin
        missed = ev["p"] < COVER_P
        if ((moved < CONFIRM_TOL_SE and not missed and lean.sure)
                or r + 1 == s.confirm_rounds):
            break
        if missed or not lean.sure:
            log(("the emulator missed the twin rerun (chi2 %.1f for %d observations, p = %.2g)"
                 % (ev["chi2"], ev["n"], ev["p"]) if missed else
                 "the refitted point leans on the emulator's uncertainty: " + lean.words())
                + ": a focus wave about the refitted point before the next rerun")
            before = list(state.stair)
            state.reruns[-1].focus = focus_wave(state, twin, log,
                                                   wave="focus after rerun %d" % (r + 1),
                                                   seed_add=r + 1)
            # the second pass's calibration and additions follow the rows so far (its
            # baseline is the first one's)
            state.stair = before + state.stair[1:]


def profile_all(state: LoopState):
    """95 % profile-likelihood intervals of every fitted parameter on the current model and
    final fit, into ``state.intervals`` - in ``n_jobs`` processes (one parameter each)."""
    w = WithAdded(state.model, state.added, state.theta)
    bp = fitted_parameters(state.model, state.theta, state.added)
    names = [q.name for q in bp]
    one = functools.partial(_profile_one, w, state.obs, bp, state.final)
    state.intervals.update(zip(names, in_processes(one, names, state.settings.n_jobs,
                                                   "profile intervals", "parameter",
                                                   state.progress)))


def _profile_one(w, obs, bp, fit, name):
    """One parameter's profile interval on ``w`` (:func:`profile_all`)."""
    return profile_interval(w.predict, obs, bp, name, fit, model_se=w.model_se())


def _fit_held(w, obs, held) -> dict:
    """The fit of ``held`` (one parameter pinned) on ``w``: its parameters."""
    _, fit = calibrate_base(w.predict, obs, held, model_se=w.model_se())
    return {k: float(v) for k, v in fit.params.items()}


def end_points(state: LoopState, done: dict) -> list:
    """The profiled point at each closed interval end not yet run: (name, side, end value,
    the base parameters there, the strengths there), the other parameters refitted on the
    emulator with ``name`` held at the end - for the parameters that are the twin's inputs (the
    design's base parameters and the DEM effects added; the powder line's and the measurement
    chain's act after the twin). ``done`` maps (name, side) to the end value already run; an
    end within :data:`END_TOL_WIDTH` of its interval's width of it is not run again."""
    w = WithAdded(state.model, state.added, state.theta)
    bp = fitted_parameters(state.model, state.theta, state.added)
    cands = candidates()
    inputs = set(state.model.space.base_names) | {k for k in state.added
                                                   if cands[k].kind == "dem"}
    ends, helds = [], []
    for q in bp:
        iv = state.intervals.get(q.name)
        if iv is None or q.name not in inputs:
            continue
        width = iv.upper - iv.lower
        for side, v, is_open in (("lower", iv.lower, iv.open_lower),
                                 ("upper", iv.upper, iv.open_upper)):
            prev = done.get((q.name, side))
            if is_open or (prev is not None and abs(v - prev) <= END_TOL_WIDTH * width):
                continue
            ends.append((q.name, side, float(v)))
            helds.append([BaseParameter(p.name, float(v), float(v), float(v) + 1e-12
                                        * (p.upper - p.lower)) if p.name == q.name else p
                          for p in bp])
    fits = in_processes(functools.partial(_fit_held, w, state.obs), helds,
                        state.settings.n_jobs, "interval ends", "end", state.progress)
    base = [p.name for p in state.model.base_params()]
    return [(name, side, v, {k: at[k] for k in base}, {k: at[k] for k in state.added})
            for (name, side, v), at in zip(ends, fits)]


def interval_stage(state: LoopState, twin, log=print):
    """95 % profile-likelihood intervals of every fitted parameter on the final model; then,
    ``interval_rounds`` times at most, the ``twin`` at each closed end's profiled point
    (:func:`end_points`, one seed per condition: design points where the posterior's edge
    lies - the emulator is refined at the fitted point, and an end it never saw runs at can
    be its error rather than the data's), the emulator refitted with their runs, the final
    fit and the intervals redone - an effect that no longer gains what it needed when it was
    added dropped first (:func:`prune_effects`); rounds until no end moves
    (``interval_rounds`` at most)."""
    from analysis.history_matching import design_runs
    profile_all(state)
    s, m = state.settings, state.model
    cands = candidates()
    done = {}
    for r in range(s.interval_rounds):
        ends = end_points(state, done)
        if not ends:
            break
        pts = []
        for i, (name, side, v, theta, strengths) in enumerate(ends):
            dem = {k: x for k, x in strengths.items() if cands[k].kind == "dem"}
            pt = m.point(theta, dem)
            pt.insert(0, "point", int(m.runs_["point"].max()) + 1 + i)
            pts.append(pt)
            done[(name, side)] = v
        runs = design_runs(m.space, pd.concat(pts, ignore_index=True), m.conditions,
                           seeds=(INTERVAL_SEED0 + r,), base_config=state.base_config)
        runs["wave"] = "interval ends %d" % (r + 1)
        before = {k: [iv.lower, iv.upper] for k, iv in state.intervals.items()}
        log("twin runs at %d interval end(s) (round %d): %s" % (len(ends), r + 1, ", ".join(
            "%s %s %.4g" % e[:3] for e in ends)))
        runs = twin(runs)
        m.fit(pd.concat([m.runs_, runs], ignore_index=True))
        # every effect must still earn its place on the emulator the ends' runs refined (as
        # after a rerun: backward elimination), then the joint fit
        need = state.selection.need if state.selection is not None else {}
        theta, added, refit, dropped = prune_effects(m, state.obs, state.theta, state.added,
                                                     need, log)
        state.dropped += [dict(d, round=r + 1, wave=runs["wave"].iloc[0]) for d in dropped]
        state.final = refit
        state.set_point(theta, added)
        state.stair.append(_stage_row("refitted with the interval ends' runs", refit,
                                      state.n_base + len(state.added)))
        profile_all(state)
        state.interval_rounds.append({
            "round": r + 1, "n_points": len(ends), "n_runs": int(len(runs)),
            "ends": [{"parameter": e[0], "side": e[1], "value": e[2]} for e in ends],
            "before": before,
            "after": {k: [iv.lower, iv.upper] for k, iv in state.intervals.items()}})


def run_loop(dataset, settings: LoopSettings | None = None, *, twin: TwinRuns | None = None,
             base_config=None, track_cache=None, progress=True, log=print,
             committed_fits=True) -> LoopResult:
    """Run the loop's stages on a loaded :class:`analysis.measurements.Dataset` (see the module
    doc). ``twin`` runs the design's runs (default: the YADE twin through the sweep, cached in
    results/runs, with the committed run table); ``base_config`` holds the run-config keys of
    every twin run (the frame, the rig's apparatus, ``record_s``); ``committed_fits``: the
    emulator also replays the committed fits (:data:`analysis.fit_cache.COMMITTED_FITS`)."""
    t0 = time.time()
    twin = twin if twin is not None else TwinRuns(base_config=base_config, progress=progress)
    state = run_stages(dataset, settings, twin=twin, base_config=base_config,
                       track_cache=track_cache, progress=progress, log=log,
                       committed_fits=committed_fits)
    return result_of(state, new_runs=twin.new_runs, wall_s=time.time() - t0,
                     failed=getattr(twin, "failed", None))


def run_committed(argv, runs_dir, log=print, committed_fits=True):
    """The loop of ``python -m analysis.loop`` options ``argv`` on the committed and cached runs
    only, with ``runs_dir`` as its run cache (no new twin run: a missing one raises
    :class:`analysis.twin_runs.BudgetError`); ``committed_fits`` as :func:`run_loop`'s.
    Returns (LoopResult, the dataset)."""
    args = build_parser().parse_args(argv)
    ds, settings, base_config, _ = prepare(args)
    twin = TwinRuns(runs_dir=runs_dir, budget_runs=0, workers=args.workers,
                    base_config=base_config)
    return run_loop(ds, settings, twin=twin, base_config=base_config, log=log,
                    committed_fits=committed_fits), ds


def run_stages(dataset, settings: LoopSettings | None, *, twin, base_config=None,
               track_cache=None, progress=True, log=print, committed_fits=True) -> LoopState:
    """The stages in order (read, build, calibrate, select, focus, the intervals' ends,
    confirm, intervals) on one state, returned: what :func:`run_loop` reports, and what a
    calibration (:mod:`analysis.calibrate`, ``max_effects`` 0) samples its posterior on."""
    from analysis.fit_cache import COMMITTED_FITS, FitCache
    s = (settings or LoopSettings()).check()
    runs_dir = getattr(twin, "runs_dir", None)
    also = [COMMITTED_FITS] if committed_fits else []
    fits = None if runs_dir is None else FitCache.beside(runs_dir, also=also)
    state = read_stage(dataset, s, base_config=base_config, track_cache=track_cache,
                       progress=progress, log=log, fit_cache=fits)
    build_stage(state, twin, log)
    calibrate_stage(state)
    select_stage(state, log)
    focus_stage(state, twin, log)
    if s.intervals and s.rerun and s.interval_rounds:
        interval_stage(state, twin, log)    # the intervals' ends run before the reruns
    if s.rerun:
        confirm_stage(state, twin, log)
    if s.intervals:
        profile_all(state)
    return state


def result_of(state: LoopState, *, new_runs, wall_s, failed=None) -> LoopResult:
    """The loop's tables and words from its final state."""
    fs, final, cal = state.selection, state.final, state.calibrated
    model, dataset = state.model, state.dataset
    eff_se = {k: float(final.stderr.get(k, np.nan)) for k in state.added}
    steps = pd.concat(fs.steps, ignore_index=True) if fs.steps else pd.DataFrame()
    diagnosis = _diagnosis_table(steps, state.added, eff_se)
    parameters = parameter_table(state, eff_se)
    comp = state.obs[["condition_id", "observable", "value", "sd"]].copy()
    key = pd.MultiIndex.from_frame(comp[["condition_id", "observable"]])
    comp["calibrated"] = cal.prediction.reindex(key).to_numpy(float)
    comp["z_calibrated"] = cal.residuals.reindex(key).to_numpy(float)
    comp["final"] = final.prediction.reindex(key).to_numpy(float)
    comp["z_final"] = final.residuals.reindex(key).to_numpy(float)
    if final.mode is not None:
        comp["motion_mode_final"] = pd.Series(final.mode, index=final.prediction.index
                                              ).reindex(key).to_numpy(object)
    rr = state.reruns[-1].score if state.reruns else None
    if rr is not None:
        comp["twin_rerun"] = rr.prediction.to_numpy(float)
        comp["z_twin_rerun"] = rr.z.to_numpy(float)
    # the last round's refit is the final fit: its lean is already measured
    lean = (state.reruns[-1].lean if state.reruns and state.reruns[-1].lean is not None
            else lean_of(final, state.obs, state.settings.alpha))
    from analysis.report.loop_words import fake_runs
    fake = fake_runs(*(r.runs for r in state.reruns))
    status, verdict = _verdict_words(fs.diagnoses, state.added, eff_se, cal, final, rr,
                                     dataset, model, state.settings.alpha, parameters,
                                     state.dropped, lean, fake)
    phys = physics_table(dataset.conditions)
    reruns = (pd.concat([r.runs for r in state.reruns], ignore_index=True)
              if state.reruns else None)
    info = {"dataset": dataset.name, "velocity_frame": dataset.velocity_frame,
            "conditions": [dict(r, label=label(r["frequency_hz"], r["ball_diameter_mm"],
                                              r["amplitude_mm"]))
                           for r in phys.drop(columns=["physics_key"]).to_dict("records")],
            "reference_point": model.theta_ref, "model": "emulator",
            "pinned_observation": model.pinned,
            "settings": dataclasses.asdict(state.settings),
            "waves": {str(k): v for k, v in state.waves.items()},
            "n_model_runs": int(len(model.runs_)), "motion_modes": model.mode_counts(),
            "stated_motion_modes": model.stated_modes(),
            "new_runs": int(new_runs),
            "wall_s": wall_s, "flight_conditions": state.flight_ids,
            "alpha": state.settings.alpha,
            "tracking": None if state.tracking is None else state.tracking.to_dict("records"),
            "bootstrap": fs.null, "focus": state.focus, "dropped": state.dropped,
            "failed_runs": ([] if failed is None or not len(failed) else
                            failed[[c for c in ("run_id", "error", "wave", "point",
                                                "condition_id", "seed") if c in failed]]
                            .to_dict("records")),
            "reruns": [r.record() for r in state.reruns], "final_lean": lean.record(),
            "interval_rounds": state.interval_rounds}
    return LoopResult(status=status, verdict=verdict,
                      effects={k: (state.added[k], eff_se[k]) for k in state.added},
                      staircase=pd.DataFrame(state.stair), diagnosis=diagnosis, steps=steps,
                      parameters=parameters, comparison=comp,
                      model_runs=run_table_of(model.runs_), info=info,
                      diagnoses=fs.diagnoses, tracks=state.tracks,
                      rerun_runs=None if reruns is None else run_table_of(reruns))


def run_table_of(runs: pd.DataFrame) -> pd.DataFrame:
    """A table of twin runs as the loop writes it (the config left out: the run id names it)."""
    return runs.drop(columns=[c for c in ("config",) if c in runs.columns])


def parameter_table(state: LoopState, eff_se) -> pd.DataFrame:
    """name, role, value, se, unit, profile interval (and whether it is open at a bound)."""
    from analysis.parameter_space import SPACE
    final = state.final
    rows = []
    names = [p.name for p in state.model.base_params()] + list(state.added)
    for k in names:
        iv = state.intervals.get(k)
        is_eff = k in state.added
        rows.append({"name": k, "role": "effect" if is_eff else "base",
                     "value": float(final.params.get(k, np.nan)),
                     "se": eff_se[k] if is_eff else float(final.stderr.get(k, np.nan)),
                     "unit": (candidates()[k].strength_label if is_eff else
                              SPACE[k].unit if k in SPACE else ""),
                     "profile_lo": iv.lower if iv else np.nan,
                     "profile_hi": iv.upper if iv else np.nan,
                     "profile_open": ((" ".join(w for w, o in (("lower", iv.open_lower),
                                                             ("upper", iv.open_upper)) if o))
                                      if iv else ""),
                     "note": candidates()[k].strength_label if is_eff else ""})
    for k, reason in state.model.held.items():
        rows.append({"name": k, "role": "held", "value": state.model.theta_ref.get(k, np.nan),
                     "se": np.nan, "note": reason})
    return pd.DataFrame(rows)


#: run-config keys the loop sets itself, never through ``--set``: the conditions, the seeds, the
#: effects, and the base parameters it calibrates (DEFAULT_BASE); --frame and
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
        full = twin_config.complete_config(dict(out))
    except twin_config.ConfigError as exc:
        raise ValueError("--set: %s" % exc)
    if ({"stl_path", "stl_units"} & set(out)) and twin_config.parametric_jar(full) is None:
        # the user's jar mesh read and checked now, not by every twin run that would fail on it
        from geometry.stl_io import MeshError, measure_jar
        try:
            measure_jar(twin_config.resolve_stl(full), full["stl_units"])
        except MeshError as exc:
            raise ValueError("--set stl_path=%s: %s" % (full["stl_path"], exc))
    return out or None


#: the optional effects that move an apparatus parameter (it cannot be freed beside them)
EFFECT_MOVES = {"end_fillet": "jar_fillet_radius_m", "stroke_drift": "amplitude_m"}


def free_parameters(specs, base_config=None, extra=()) -> tuple:
    """(name, lo, hi) of each ``--free NAME[=LO:HI]`` (:func:`analysis.parameter_space.
    parse_free`: a declared parameter, a range inside its prior); none without ``specs``.

    Raises
    ------
    ValueError - an unknown name or bad range, a parameter also fixed by ``--set``, or one an
        optional effect asked for moves too
    """
    from analysis.parameter_space import parse_free
    if not specs:
        return ()
    out = parse_free(specs)
    for name in out:
        if name in (base_config or {}):
            raise ValueError("--free %s and --set %s: a parameter is either calibrated or "
                             "fixed" % (name, name))
        for eff in extra:
            if EFFECT_MOVES.get(eff) == name and name not in DEFAULT_BASE:
                raise ValueError("--free %s and --with-effect %s both move %s: choose one"
                                 % (name, eff, name))
    return tuple((n, float(lo), float(hi)) for n, (lo, hi) in out.items())


def optional_effects(names, base_config=None):
    """The optional catalog entries ``names`` (catalog.OPTIONAL_CANDIDATES), checked against
    the runs' jar: each must be able to act on it at its largest strength.

    Raises
    ------
    ValueError - an unknown name, or an effect that cannot act on this jar (e.g. end_fillet on
        an STL whose fillet is unknown)
    """
    from analysis.config import twin_config
    from analysis.catalog import OPTIONAL_CANDIDATES
    from effects import jar_config
    opt = {c.name: c for c in OPTIONAL_CANDIDATES}
    out = []
    for n in names:
        if n not in opt:
            raise ValueError("--with-effect %s: not an optional catalog entry (optional: %s; "
                             "the others are always diagnosed)" % (n, ", ".join(opt)))
        if opt[n].kind == "dem":       # the measurement chain has no run, no jar to act on
            cfg = dict(base_config or {}, effects=opt[n].spec(opt[n].s_max))
            try:
                jar_config(twin_config.complete_config(cfg))
            except twin_config.ConfigError as exc:
                raise ValueError("--with-effect %s: %s" % (n, exc))
        if n not in out:
            out.append(n)
    return out


def pinned_observation(dataset) -> dict:
    """The observation effects ``dataset``'s videos/video.json pins
    (:func:`analysis.measurements.observation_pins`: {effect: {parameter: value}}), each
    checked against its declared bounds. The loop applies them to every prediction and does
    not diagnose them.

    Raises
    ------
    ValueError - a pinned value outside the effect's declared bounds (named)
    """
    from analysis.measurements import observation_pins
    from effects import load_effects
    pins = observation_pins(dataset.observation_chain)
    for name, params in pins.items():
        try:
            load_effects({name: params}, side="observation")
        except ValueError as exc:
            raise ValueError("videos/video.json pins %s %s: %s" % (name, params, exc))
    return pins


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


#: a profile interval this many times wider than +- 1.96 se: the likelihood is not quadratic
#: there and the verdict says the se understates the uncertainty
SE_UNDERSTATES_RATIO = 3.0


def _interval_words(parameters, name, se=np.nan):
    """', 95 % interval lo-hi' from the parameters table's profile interval ('' without); when
    the interval is :data:`SE_UNDERSTATES_RATIO` or more times wider than +- 1.96 ``se`` (the
    curvature's at the optimum: a likelihood far from quadratic, e.g. where the twin's motion
    mode flips), the words say so and that the interval is the one to quote."""
    if parameters is None or "profile_lo" not in parameters:
        return ""
    r = parameters[parameters["name"] == name]
    if not len(r) or not np.isfinite(float(r["profile_lo"].iloc[0])):
        return ""
    lo, hi = float(r["profile_lo"].iloc[0]), float(r["profile_hi"].iloc[0])
    words = ", 95 %% interval %.3g-%.3g" % (lo, hi)
    ratio = (hi - lo) / (2 * 1.96 * se) if se > 0 else np.nan
    if ratio >= SE_UNDERSTATES_RATIO:
        words += (" - %.0f times wider than +- 1.96 se: the likelihood is not quadratic there "
                  "and the se understates the uncertainty; quote the interval" % ratio)
    return words


def rerun_words(rr, final, alpha=None, added=(), fake=False):
    """The twin rerun's chi2/dof beside the model's, and whether the emulator's stated
    uncertainty covered the rerun (:func:`emulator_vs_twin`, before the rerun's runs joined
    it). With ``alpha``: when the rerun misfits the data (p < alpha) where the model's fit
    does not, the words say the twin does not confirm the fit - and the effects ``added``
    are then the emulator's answer, not the twin's. ``fake``: the rerun's runs are the FAKE
    twin's (the words say so instead of 'real')."""
    out = ("the %s twin rerun at the final parameters: chi2/dof %.2f, the emulator's there "
           "%.2f" % ("FAKE" if fake else "real", rr.chi2_dof, final.chi2_dof))
    p_rr = rr.p_value
    if alpha is not None and p_rr < alpha <= final.p_value:
        out += (" - the twin does NOT confirm the fit (its rerun's p = %.2g)%s; more runs "
                "where the fit lands decide it" % (
                    p_rr, "" if not added else ": %s %s named on the emulator only"
                    % (", ".join(added), "is" if len(added) == 1 else "are")))
    ev = rr.emulator_vs_twin
    if ev and ev["n"]:
        cover = ev["p"] >= COVER_P
        out += ("; the emulator's prediction there against the rerun's means, before they "
                "joined it: chi2 %.1f for %d observations (p = %.2g, largest |z| %.1f at %s): "
                "%s" % (ev["chi2"], ev["n"], ev["p"], ev["max_abs_z"], ev["worst"],
                        "within its stated uncertainty" if cover else
                        "BEYOND its stated uncertainty - the emulator is not accurate there yet"))
    return out


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
                   parameters=None, dropped=(), lean=None, fake=False):
    """(status, the verdict's sentences): what was found or not, what was dropped, what stays
    unexplained, the residual structure, what was held, what the data leave loose, the rerun
    and whether the final point leans on the emulator's uncertainty."""
    if added:
        status = "effects"
        parts = [_found_words(added, eff_se, parameters, cal, final)] + _tie_words(diags)
    else:
        status = "nothing_missing" if cal.p_value >= alpha else "unexplained"
        parts = [_nothing_words(cal, status)]
    parts += [_dropped_words(d) for d in dropped]
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
        parts.append(_held_words(model, dataset))
    loose = _loose_words(model, added, final, eff_se, parameters)
    if loose:
        parts.append("not constrained by the data: " + ", ".join(loose))
    if rr is not None:
        parts.append(rerun_words(rr, final, alpha, list(added), fake))
    # a final point that leans on the emulator's uncertainty, where no twin rerun confirms
    # the fit (none made, or one that misfits): the verdict rests on the emulator's ignorance
    confirmed = rr is not None and rr.p_value >= alpha
    if lean is not None and not lean.sure and not confirmed:
        parts.append("the final point leans on the emulator's uncertainty: %s - the data are "
                     "plausible there because the emulator does not know the twin yet, not "
                     "because the twin fits them; more runs there (--confirm-rounds) decide it"
                     % lean.words())
    return status, ". ".join(parts) + "."


def _found_words(added, eff_se, parameters, cal, final) -> str:
    """The effects added, each with its strength, se and interval, and the chi2/dof they
    bring."""
    found = []
    for k, s in added.items():
        c = candidates()[k]
        found.append("%s (%s = %.3g +- %.2g%s)" % (k, c.strength_label, s, eff_se[k],
                                                  _interval_words(parameters, k, eff_se[k])))
    return ("missing effect%s: %s; chi2/dof %.2f -> %.2f"
            % ("s" if len(added) > 1 else "", "; ".join(found), cal.chi2_dof, final.chi2_dof))


def _tie_words(diags) -> list:
    """A sentence per candidate as good as the one added at its step."""
    out = []
    for d in diags:
        if d.best is None:
            continue
        t = d.table
        b = t[t["effect"] == d.best].iloc[0]
        ties = t[t["significant"] & (t["effect"] != d.best)
                 & (b["delta_chi2"] - t["delta_chi2"] < TIE_DELTA_CHI2)]
        for _, o in ties.iterrows():
            out.append("%s explains the data about as well as %s (chi2 gain %.1f "
                       "against %.1f): the data cannot tell them apart"
                       % (o["effect"], d.best, o["delta_chi2"], b["delta_chi2"]))
    return out


def _nothing_words(cal, status) -> str:
    """No effect added: nothing missing, or a misfit no candidate explains."""
    head = ("calibrated chi2/dof %.2f (dof %d)" % (cal.chi2_dof, cal.dof) if cal.dof > 0 else
            "calibrated chi2/dof untestable (dof %d: no more observations than fitted "
            "parameters)" % cal.dof)
    if status == "nothing_missing":
        return "nothing missing: no candidate effect is significant; %s" % head
    return "no candidate effect explains the misfit (%s, p = %.2g)" % (head, cal.p_value)


def _dropped_words(d) -> str:
    """An effect backward elimination dropped, and after which runs."""
    what = ("the runs at the intervals' ends" if str(d.get("wave", "")).startswith(
        "interval") else "the twin reruns")
    return ("%s, named before %s, dropped after them: on the emulator refitted with their "
            "runs it gains chi2 %.1f, %.1f needed"
            % (d["effect"], what, d["delta_chi2"], d["needed"]))


def _held_words(model, dataset) -> str:
    """The base parameters the model holds, and why (a stroke the dataset states)."""
    from analysis.report.loop_words import stated_stroke_words
    held = []
    stroke = stated_stroke_words(getattr(dataset, "conditions", None))
    for k, reason in model.held.items():
        if k == "amplitude_m" and stroke:
            held.append("the stroke as the dataset states it (amplitude_mm %s), not "
                        "fitted" % stroke)
        else:
            held.append("%s held at %.4g (%s)"
                        % (k, float(model.theta_ref.get(k, np.nan)), reason))
    return "; ".join(held)


def _loose_words(model, added, final, eff_se, parameters) -> list:
    """The parameters the data leave about as uncertain as the prior (the report's rule),
    each with its spread and the prior's sd."""
    from analysis.report.loop_words import is_constrained, prior_sd, spread_of
    try:
        bounds = {p.name: (p.lower, p.upper) for p in model.base_params()}
    except (AttributeError, TypeError):
        bounds = {}
    cands = candidates()
    bounds.update({k: (0.0, float(cands[k].s_max)) for k in added if k in cands})
    priors = getattr(model, "priors", None) or {}
    ivs = ({} if parameters is None or "profile_lo" not in parameters else
           {r["name"]: (r["profile_lo"], r["profile_hi"]) for r in parameters.to_dict("records")})
    loose = []
    for k in bounds:
        se = float(final.stderr.get(k, np.nan)) if k not in added else float(
            eff_se.get(k, np.nan))
        lo, hi = (float(v) for v in ivs.get(k, (np.nan, np.nan)))
        sd = prior_sd(k, bounds, priors)
        if np.isfinite(sd) and sd > 0 and not is_constrained(se, sd, lo, hi):
            loose.append("%s (spread %.2g for a prior sd %.2g)" % (k, spread_of(se, lo, hi),
                                                                   sd))
    return loose


# --------------------------------------------------------------------------- output

def write_loop(res: LoopResult, out_dir, dataset, protected=()) -> Path:
    """Write the loop's folder atomically (see the module docstring for the files).

    What the files state beyond the result itself (:mod:`analysis.report.loop_words`): a run
    made by the FAKE twin says so on its page, in both figures (titles, watermark, PNG text)
    and in loop.json (``twin``, ``fake_twin``); parameters.csv gives a stroke the dataset
    states as stated and a column ``constrained``; diagnosis.csv the chi2 gain each candidate
    needed (``delta_chi2_needed``, the test as applied: Bonferroni x the bootstrap's scale, the
    F-test, BIC); loop.json is strict JSON (NaN and infinities as null)."""
    from analysis.plotting.loop_plots import write_loop_figures
    from analysis.report import loop_page
    from analysis.report.loop_words import (FAKE_WORDS, UNCONSTRAINED_RULE,
                                            annotate_parameters, is_fake_run, json_clean,
                                            needed_gains, quoted_stages, step_scale)

    out_dir = Path(out_dir)
    fake = is_fake_run(res)
    bounds, priors = {}, {}
    from analysis.parameter_space import CALIBRATED, effect_strengths
    # the model's priors are flat over the design's bounds
    bounds = dict(CALIBRATED, **{k: v[:2] for k, v in effect_strengths().items()})
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

class _Parser(argparse.ArgumentParser):
    """argparse with one error line (``analysis.loop: error: ...``) and exit code 2."""

    def error(self, message):
        print("analysis.loop: error: %s" % message, file=sys.stderr)
        sys.exit(2)


def check_options(a):
    """Refuse (ValueError, one line) every option value the loop cannot run with, before the
    dataset is read or anything planned - the dry run included."""
    if not str(a.dataset).strip():
        raise ValueError("--dataset is empty; give the dataset's folder")
    if a.workers < 1:
        raise ValueError("--workers must be >= 1, got %d" % a.workers)
    if a.seed < 0:
        raise ValueError("--seed must be >= 0, got %d" % a.seed)
    if a.budget_runs is not None and a.budget_runs < 0:
        raise ValueError("--budget-runs must be >= 0, got %d" % a.budget_runs)
    for flag in ("diff_replicates", "max_reanchor", "max_refits"):
        v = getattr(a, flag)
        if v is not None and v < 0:
            raise ValueError("--%s must be >= 0, got %d" % (flag.replace("_", "-"), v))
    settings_of(a).check()
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


def settings_of(a, max_effects=None, extra=(), free=()) -> LoopSettings:
    """The LoopSettings of the command's options (``--max-refits N``, the earlier form, asks
    for up to N reruns after the first: ``--confirm-rounds N + 1``)."""
    rounds = a.confirm_rounds if a.max_refits is None else a.max_refits + 1
    return LoopSettings(alpha=a.alpha, max_effects=a.max_effects if max_effects is None
                        else max_effects, null_draws=a.null_draws, points=a.points,
                        replicates=a.replicates, waves=a.waves, per_wave=a.per_wave,
                        focus_points=a.focus_points,
                        rerun=not a.no_rerun, rerun_replicates=a.rerun_replicates,
                        confirm_rounds=rounds, intervals=not a.no_intervals,
                        interval_rounds=a.interval_rounds, seed=a.seed,
                        extra_effects=tuple(extra), free=tuple(free),
                        n_jobs=max(int(getattr(a, "workers", 1) or 1), 1))


def dof_limits(ds, max_effects, extra=(), free=(), base=DEFAULT_BASE):
    """(calibration dof, max effects) of a loop on ``ds``, before anything is planned.

    The calibration fits every base parameter of the design space (the stroke not when every
    condition states it) and, with yields, the powder line's slope and intercept, to the
    dataset's observations; each added effect costs one more degree of freedom. Raises
    ValueError when the calibration would keep no degree of freedom (one condition with
    v_mean and f_col only: chi2/dof undefined, nothing can be tested); otherwise the number
    of effects is capped so that one degree of freedom stays. A dataset whose films are not
    yet tracked may gain impact observables: then nothing is refused or capped here.
    """
    if ds.video_files and any(c not in ds.tracks for c in ds.video_files):
        return None, max_effects
    obs, _, _ = dataset_observations(ds, True)
    n_obs = int(np.isfinite(pd.to_numeric(obs["value"], errors="coerce")).sum())
    names = loop_space(ds, extra, free, base).base_names
    yields = ["slope_pct_per_kj", "intercept_pct"] if yield_times_of(ds) else []
    dof = n_obs - len(names) - len(yields)
    if dof < 1:
        raise ValueError(
            "%s: %d observation(s) at %d condition(s) for %d calibrated parameter(s) (%s) "
            "leave %d degrees of freedom: chi2/dof is undefined and no effect can be tested; "
            "measure at more conditions (each adds v_mean and f_col), add jar tracks, or "
            "state the stroke (amplitude_mm)"
            % (ds.name, n_obs, len(ds.conditions), len(names) + len(yields),
               ", ".join(names + yields), dof))
    return dof, min(max_effects, dof - 1)


#: the FAKE analytic twin's wall time per run in the dry run's plan [s]
FAKE_RUN_WALL_S = 0.05


def plan_lines(ds, settings, base_config, twin) -> list:
    """The dry run's lines: wave 0 exactly (cached, committed, new), the refinement waves and
    the reruns at most, the total and its wall time."""
    from analysis.emulated_twin import wave_runs
    from analysis.twin_runs import run_wall_s
    state = read_stage(ds, settings, base_config=base_config, track=False, log=lambda _: None)
    p0 = twin.plan(wave0_runs(state))
    n_c = len(ds.conditions)
    most = wave_runs(n_c, n_initial=settings.points, n_waves=settings.waves,
                     per_wave=settings.per_wave, replicates=settings.replicates)
    rerun = (settings.confirm_rounds * settings.rerun_replicates * n_c) if settings.rerun else 0
    focus = settings.focus_points * n_c
    n_par = len(state.model.space.base_names) + settings.max_effects
    ends = (settings.interval_rounds * 2 * n_par * n_c
            if settings.intervals and settings.rerun else 0)
    from analysis import config
    fake = Path(twin.runs_dir) == Path(config.FAKE_RUNS_DIR)
    per = FAKE_RUN_WALL_S if fake else run_wall_s(base_config, twin.runs_dir)
    new_most = p0.new + most["refinement"] + focus + rerun + ends
    return [
        "wave 0 (%d points + the reference point x %d seeds, %d conditions): %s"
        % (settings.points, settings.replicates, n_c, p0.words(twin.workers)),
        "refinement waves: up to %d runs (%d waves x %d points x %d conditions, where the data "
        "are plausible)" % (most["refinement"], settings.waves, settings.per_wave, n_c),
        "focus wave: %d runs (%d points about the selected fit x %d conditions)"
        % (focus, settings.focus_points, n_c),
        "twin reruns at the final point: up to %d runs (%d round(s) x %d seeds x %d conditions)"
        % (rerun, settings.confirm_rounds if settings.rerun else 0, settings.rerun_replicates,
           n_c),
        "runs at the intervals' ends: up to %d (%d round(s) x 2 ends x %d parameters x %d "
        "conditions; a round only for the ends that moved)"
        % (ends, settings.interval_rounds if ends else 0, n_par, n_c),
        "total: up to %d runs, up to %d new, about %.0f min of twin runs on %d worker(s) "
        "(%.2g s per run%s), plus the analysis (the fits and the bootstrap draws: minutes to "
        "half an hour a loop on one core)"
        % (p0.runs + most["refinement"] + focus + rerun + ends, new_most,
           math.ceil(new_most / max(twin.workers, 1)) * per / 60, twin.workers, per,
           ", the FAKE analytic twin" if fake else "")]


def main(argv=None):
    """The command (see the module doc); Ctrl-C at any moment: one line, exit 130."""
    if signal.getsignal(signal.SIGINT) is globals().get("_interrupted_early"):
        signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        return _main(argv)
    except KeyboardInterrupt as exc:                # SIGINT / SIGTERM: one line, 130 / 143
        from analysis.sweep import interrupted_exit
        return interrupted_exit("analysis.loop", exc)


def build_parser() -> argparse.ArgumentParser:
    """The command's options (``python -m analysis.loop --help``)."""
    ap = _Parser(
        prog="python -m analysis.loop",
        description="The loop on a measurement dataset: build the emulator of the twin at its "
        "conditions in waves of twin runs, calibrate, diagnose which effect is missing, add it "
        "(repeatedly), rerun the twin at the final point, write one report folder.",
        epilog="example: python -m analysis.loop --dataset data/measurements/paper_table3 "
        "--out results/loop/paper_table3",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    d = LoopSettings()
    ap.add_argument("--dataset", required=True, help="dataset folder (docs/dataset_format.md)")
    ap.add_argument("--out", required=True,
                    help="output folder; replaced only when an earlier loop wrote it")
    ap.add_argument("--budget-runs", type=int, default=None,
                    help="most new twin runs to start [runs] (default: no limit); the loop stops "
                    "with exit 3 before a wave that needs more")
    ap.add_argument("--dry-run", action="store_true",
                    help="print the plan (wave 0's runs, cached and new; the waves and reruns at "
                    "most; the estimated wall time) and exit; nothing is run or written")
    ap.add_argument("--points", type=int, default=d.points,
                    help="wave-0 design points [points] (default %(default)s)")
    ap.add_argument("--replicates", type=int, default=d.replicates,
                    help="seeds of the reference point, the twin's chaos per condition [seeds] "
                    "(default %(default)s)")
    ap.add_argument("--waves", type=int, default=d.waves,
                    help="refinement waves where the data are plausible [waves] (default "
                    "%(default)s)")
    ap.add_argument("--per-wave", type=int, default=d.per_wave,
                    help="design points per refinement wave [points] (default %(default)s)")
    ap.add_argument("--focus-points", type=int, default=d.focus_points,
                    help="design points of the focus wave about the selected fit, after "
                    "which the calibration and the selection are redone (0: none) [points] "
                    "(default %(default)s)")
    ap.add_argument("--seed", type=int, default=d.seed, help="design seed [-] (default "
                    "%(default)s)")
    ap.add_argument("--no-rerun", action="store_true",
                    help="skip the twin reruns at the final point")
    ap.add_argument("--rerun-replicates", type=int, default=d.rerun_replicates,
                    help="seeds per condition of each twin rerun [seeds] (default %(default)s)")
    ap.add_argument("--confirm-rounds", type=int, default=d.confirm_rounds,
                    help="most twin reruns: after each the emulator is refitted with the "
                    "rerun's runs and the fit redone; a point that moves by more than %.1f se "
                    "gets the next, a rerun beyond the emulator's stated uncertainty or a point "
                    "that leans on it (the fit passes with the emulator's sd, its means with the "
                    "data's sd alone do not) a focus wave first [rounds] (default %%(default)s)"
                    % CONFIRM_TOL_SE)
    ap.add_argument("--no-intervals", action="store_true",
                    help="skip the profile-likelihood intervals (the se only)")
    ap.add_argument("--interval-rounds", type=int, default=d.interval_rounds,
                    help="most rounds of twin runs at the intervals' ends (one seed per "
                    "condition at each closed end's profiled point; the emulator refitted, the "
                    "final fit and the intervals redone; a round only for the ends that moved) "
                    "[rounds] (default %(default)s; 0: none)")
    ap.add_argument("--alpha", type=float, default=d.alpha,
                    help="family-wise significance level of each diagnosis step [-] (default "
                    "%(default)s)")
    ap.add_argument("--null-draws", type=int, default=d.null_draws,
                    help="[datasets] datasets drawn from the fitted model per step to calibrate the "
                    "significance threshold (0: nominal level only; default %(default)s)")
    ap.add_argument("--max-effects", type=int, default=MAX_EFFECTS,
                    help="most effects added (forward selection) [effects] (default "
                    "%(default)s)")
    ap.add_argument("--frame", choices=("lab", "jar", "auto"), default="auto",
                    help="frame the twin runs are integrated in (run config 'frame'; default "
                    "%(default)s: the jar frame, 1.7-1.9x faster, where the effects allow it)")
    ap.add_argument("--record-s", type=float, default=None,
                    help="recorded time per twin run [s] (default the run config's 0.5 s)")
    ap.add_argument("--with-effect", action="append", default=[], metavar="NAME",
                    help="an optional catalog entry diagnosed beside the default ones "
                    "(repeatable): end_fillet (the jar's end edges rounded more; needs the "
                    "default or a parametric jar), stroke_drift (the stroke falls with the set "
                    "frequency); the measurement chain, at no twin run: apparent_scale, "
                    "smoothing_window, frame_rate, camera_plane, collision_count (docs/loop.md)")
    ap.add_argument("--v-rel-sd", type=float, default=None, metavar="F",
                    help="[-] measurement sd of v_mean assumed where the dataset states none, as a "
                    "fraction of v_mean (default 0.015; e.g. 0.01 for 1 %%)")
    ap.add_argument("--free", action="append", default=[], metavar="NAME[=LO:HI]",
                    help="an apparatus parameter calibrated beside the contact parameters and "
                    "the stroke, over its declared prior or LO:HI inside it (repeatable): "
                    "jar_inner_diameter_m, jar_inner_length_m, jar_volume_m3, "
                    "jar_fillet_radius_m (analysis/parameter_space.py); a base parameter with "
                    "LO:HI narrows its prior")
    ap.add_argument("--set", action="append", default=[], dest="settings", metavar="KEY=VALUE",
                    type=parse_key_value,
                    help="run-config key fixed in every twin run (repeatable): your rig's "
                    "apparatus, e.g. jar_inner_diameter_m=0.028 jar_fillet_radius_m=0.01 or "
                    "stl_path=my_jar.stl (docs/apparatus.md), rolling_model, dt_s; not the "
                    "conditions, seeds, effects or the calibrated base parameters")
    ap.add_argument("--workers", type=int, default=2,
                    help="parallel processes: twin runs and the analysis' independent fits "
                    "(bootstrap draws, candidates, profile intervals) [processes] "
                    "(default %(default)s)")
    ap.add_argument("--backend", choices=("local", "serial", "dask"), default="local",
                    help="sweep backend (dask: --scheduler ADDRESS or a local cluster)")
    ap.add_argument("--scheduler", default=None, help="address of a running Dask scheduler")
    ap.add_argument("--fake", action="store_true",
                    help="use the FAKE analytic twin (tests and demonstrations only)")
    # the anchored model's options (before the emulator): accepted, see CHANGELOG.md
    ap.add_argument("--max-refits", type=int, default=None,
                    help="[rounds] the earlier form of --confirm-rounds: N asks for N + 1")
    ap.add_argument("--diff-replicates", type=int, default=None,
                    help="[seeds] accepted for earlier command lines; no effect")
    ap.add_argument("--max-reanchor", type=int, default=None,
                    help="[re-anchorings] accepted for earlier command lines; no effect")
    return ap


def _main(argv=None):
    a = build_parser().parse_args(argv)
    try:
        ds, settings, base_config, twin = prepare(a)
        if a.dry_run:
            print("\n".join(plan_lines(ds, settings, base_config, twin)))
            return 0
        res = run_loop(ds, settings, twin=twin, base_config=base_config,
                       log=lambda s: print(s, file=sys.stderr))
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
    print(("FAKE twin (the analytic stand-in, not the DEM): " if a.fake else "") + res.verdict)
    print("staircase: " + ", ".join("%s %.2f" % (r.stage, r.chi2_dof)
                                    for r in res.staircase.itertuples()))
    print("wrote %s" % a.out)
    return 0


def prepare(a):
    """Every check of the parsed command ``a`` before anything runs - the options and the
    output folder (its parent included) before the dataset is read, then the dataset, its
    physics and its degrees of freedom: a bad value never costs a run. Returns (dataset,
    settings, base_config, twin)."""
    check_options(a)
    for flag in ("diff_replicates", "max_reanchor"):
        if getattr(a, flag) is not None:
            print("analysis.loop: note: --%s has no effect since the loop's model is the "
                  "emulator (no anchor; see CHANGELOG.md)" % flag.replace("_", "-"),
                  file=sys.stderr)
    check_out_dir(a.out, [a.dataset])
    base_config = run_settings(a.settings, frame=a.frame, record_s=a.record_s)
    extra = optional_effects(a.with_effect, base_config)
    free = free_parameters(a.free, base_config, extra)
    ds = load_dataset(a.dataset)
    for line in ds.warnings:            # accepted, but outside what the twin is tested on
        print("analysis.loop: warning: %s" % line, file=sys.stderr)
    physics_table(ds.conditions, conditions_file(ds))
    check_balls_fit(ds, base_config)
    pinned_observation(ds)              # a stated chain outside its bounds: before any run
    from analysis.videos import check_films
    check_films(ds)                     # every film opens and decodes: before any tracking
    if a.v_rel_sd is not None:
        ds = with_assumed_v_sd(ds, a.v_rel_sd)
    _, max_effects = dof_limits(ds, a.max_effects, extra, free)
    if max_effects < a.max_effects:
        print("analysis.loop: note: at most %d effect(s) added (--max-effects %d): each "
              "costs a degree of freedom and the dataset leaves %d beyond the calibration"
              % (max_effects, a.max_effects, max_effects + 1), file=sys.stderr)
    settings = settings_of(a, max_effects, extra, free).check()
    return ds, settings, base_config, twin_of(a, base_config)


def check_balls_fit(ds, base_config):
    """Each condition's ball fits the jar its runs name (the scene's rule,
    :func:`analysis.twin.check_ball_fits_jar`), before any run: a ConditionError naming the
    row, not a wave of failed runs."""
    from analysis.config import twin_config
    from analysis.run_configs import condition_runs
    from analysis.twin import check_ball_fits_jar
    for i, r in enumerate(condition_runs(ds.conditions, base_config=base_config)):
        try:
            check_ball_fits_jar(twin_config.complete_config(dict(r.config)))
        except twin_config.ConfigError as exc:
            raise ConditionError("%s, row %d (line %d), column 'ball_diameter_mm': condition "
                                 "%r: %s" % (conditions_file(ds), i + 1, i + 2,
                                             r.condition_id, exc))


def twin_of(a, base_config) -> TwinRuns:
    """The twin the command's runs go to: YADE through the sweep (cache results/runs and the
    committed run table), or with ``--fake`` the analytic stand-in (cache results/runs_fake)."""
    kw = dict(workers=a.workers, backend=a.backend, scheduler=a.scheduler,
              budget_runs=a.budget_runs, base_config=base_config)
    if a.fake:
        from analysis import config
        from analysis.fake_twin import run_fake_twin
        return TwinRuns(runner=run_fake_twin, runs_dir=config.FAKE_RUNS_DIR, **kw)
    return TwinRuns(**kw)


if __name__ == "__main__":
    sys.exit(main())
