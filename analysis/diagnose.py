"""Which physical effect is missing? Generic effect diagnosis against a measurement dataset.

The model
---------
A model is any callable ::

    predict(theta_base: dict[str, float], effects: dict[str, float]) -> pandas.Series

returning the model's MEAN prediction indexed by ``(condition_id, observable)`` (a 2-level
MultiIndex; extra keys are ignored). ``theta_base`` holds the base (calibratable) parameters, e.g.
restitution and friction; ``effects`` holds the strength of every candidate effect (the null
strength switches an effect off). The model's own replicate noise - the DEM twin is chaotic - is
given separately as ``model_se`` (standard error of the mean prediction per key), see
:func:`diagnose`. A stochastic ``predict`` should use common random numbers (the same seeds for
every call), so that differences between calls carry little noise; set ``crn_correlation``
accordingly (0 = independent seeds per call, 1 = deterministic / perfectly common noise).

The observations
----------------
Either a :class:`analysis.measurements.Dataset` (its summary observables, plus yields as
observables ``'yield_pct@<t>min'``), or a DataFrame with columns condition_id, observable, value,
sd (e.g. :func:`analysis.measurements.measurement_table`). Each residual's uncertainty is
``sigma = sqrt(sd**2 + model_se**2)`` and residuals are whitened by it (the "whitened metric").
A model whose ``model_se`` callable carries ``.cov`` (an emulator's: its errors at one point
move together across conditions) is scored with the full covariance ``diag(sd**2) + K``:
residuals whitened by its Cholesky factor, -2 log L = chi2 + log det (Kennedy & O'Hagan 2001).
:func:`dataset_observations` builds that table from a dataset, with the impact observables of
its jar tracks (:mod:`analysis.flights`); :func:`with_run_sd` floors their sd at one twin run's
scatter. An optional column ``shared_sd`` states the part of a row's sd that every row of its
condition with a shared_sd shares (one film's length scale: its lengths and speeds read off by
one factor together): the data's covariance is then diag(sd**2) plus shared_sd_i shared_sd_j
between two rows of one condition, and every fit is scored in that metric.

The method
----------
1. *baseline*: the model at the given starting parameters, every effect off.
2. *calibrated*: the base parameters fitted (bounded Gauss-Newton / trust-region,
   scipy.optimize.least_squares) with every effect off. Its whitened Jacobian ``J`` (n x p).
3. For each candidate effect k:

   * signature ``g_k``: finite-difference derivative of every whitened prediction with respect to
     the strength, at the calibrated base and null strength (step ``effect_step_frac`` of the way
     to the far bound);
   * projection: ``g_perp = (I - J J^+) g_k`` removes what a recalibration of the base parameters
     would absorb; ``absorbed_frac = 1 - |g_perp|^2 / |g_k|^2``;
   * score test ``S = (g_perp . r)^2 / |g_perp|^2`` (r = whitened residual, measured - model), the
     linearised strength ``s_lin = null + (g_perp . r) / |g_perp|^2 +- 1 / |g_perp|``;
   * joint fit of base parameters and strength (bounded; started from s_lin, from near null
     and from the best local minima of a scan over the strength's range with the base
     parameters profiled out, each such start refitted at its strength first; the best optimum
     kept: an interpolated response can have several minima), chi2 gain ``delta_chi2`` and its
     covariance (Gauss-Newton, ``(J_full^T J_full)^-1``): strength +- se, max |correlation| of
     the strength with a base parameter; BIC gain ``delta_chi2 - ln n``;
   * identifiability: ``footprint`` = norm of the projected, whitened change of all predictions
     when the strength goes from null to its far bound, minus the part explained by the FD noise
     of the twin (``2 (1 - crn_correlation) model_se^2``); ``signature_snr`` = the signature's
     distance from pure twin noise, a chi-square test of the far-bound change against its own
     noise entry by entry, ``(T - n) / sqrt(2 n)`` with ``T = sum (change_i / noise_sd_i)^2``
     (a z-score of the excess; noise that sits in a few observables - the chaotic f_col of one
     condition - does not drown a clean signal in the others). An effect with footprint <
     ``min_footprint`` (default 2 sigma) or snr < ``min_snr`` (default 3) cannot be told from
     noise and is never significant.
4. Significance: p-value of ``delta_chi2`` under chi2_1 (halved when the null strength sits on a
   bound - the strength can only move one way - Self & Liang 1987), and, to protect against a
   residual that is over-dispersed for another reason, the F-test p-value of
   ``delta_chi2 / (chi2_after / dof_after)``; the larger of the two, Bonferroni-corrected for the
   number of candidates, must fall below ``alpha``; and BIC must improve.
5. Verdict: the best significant effect, or when none: "nothing missing" if the calibrated chi2
   is consistent with its dof (p >= alpha), else a description of the residual's structure
   (trend with frequency, ball-size split, offset of one observable, single outliers), tested in
   the same projected way, Bonferroni over the descriptors.

Noise of a stochastic twin: with fresh replicate noise at every call (``crn_correlation=0``)
finite differences carry sqrt(2) x the replicate-mean noise; the identifiability gate then asks
for a footprint >= 3 x that noise, which costs power (toy model: rank-1 rate fell from 100 % to
~65 % at the same strengths) but never names a decoy. Use common random numbers or more
replicates for the differences.

The loop (:mod:`analysis.loop`, ``python -m analysis.loop``) runs these functions on the one
model of the twin; this module has no command line of its own.

References: Self, S.G., Liang, K.-Y. (1987) JASA 82, 605 (boundary LR tests); Rao score test;
Schwarz (1978) BIC.
"""
from __future__ import annotations

import functools
import math
import sys
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from scipy import optimize, stats

from analysis.linalg import solve_lower
from analysis.measurements import (DEFAULT_F_COL_SD_HZ, DEFAULT_V_REL_SD, DEFAULT_YIELD_SD_PCT,
                                   Dataset, measurement_table, yield_table)

EFFECT_KINDS = ("dem", "kinetics", "observation")
#: strengths scanned (evenly over each effect's range) for the fit's starting points
SCAN_POINTS = 13
_OBS_WORDS = {"v_mean_m_s": "speed", "f_col_hz": "collision frequency", "yield_pct": "yield"}


# --------------------------------------------------------------------------- declarations

@dataclass(frozen=True)
class BaseParameter:
    """A calibratable base parameter: starting value and bounds (physical units)."""

    name: str
    value: float
    lower: float
    upper: float

    def __post_init__(self):
        if not (np.isfinite(self.lower) and np.isfinite(self.upper) and self.lower < self.upper):
            raise ValueError("base parameter %s: bounds must be finite with lower < upper"
                             % self.name)
        if not self.lower <= self.value <= self.upper:
            raise ValueError("base parameter %s: value %g outside [%g, %g]"
                             % (self.name, self.value, self.lower, self.upper))


@dataclass(frozen=True)
class Effect:
    """A candidate effect: strength bounds, the null strength (effect off) and its kind.

    kind : 'dem' (acts in the ball dynamics), 'kinetics' (acts in the yield model) or
        'observation' (acts in the measurement chain, on the twin's outputs)
    """

    name: str
    lower: float
    upper: float
    null: float = 0.0
    kind: str = "dem"
    description: str = ""

    def __post_init__(self):
        if not (np.isfinite(self.lower) and np.isfinite(self.upper) and self.lower < self.upper):
            raise ValueError("effect %s: bounds must be finite with lower < upper" % self.name)
        if not self.lower <= self.null <= self.upper:
            raise ValueError("effect %s: null strength %g outside [%g, %g]"
                             % (self.name, self.null, self.lower, self.upper))
        if self.kind not in EFFECT_KINDS:
            raise ValueError("effect %s: kind must be one of %s" % (self.name, EFFECT_KINDS))

    @property
    def far(self) -> float:
        """The bound farther from the null strength."""
        return self.upper if self.upper - self.null >= self.null - self.lower else self.lower

    @property
    def null_on_bound(self) -> bool:
        return self.null in (self.lower, self.upper)


# --------------------------------------------------------------------------- results

@dataclass
class FitResult:
    """A bounded least-squares fit in the whitened metric.

    Attributes
    ----------
    params : dict name -> value (base parameters, and the effect strength when fitted)
    stderr : dict name -> standard error (Gauss-Newton, sigmas taken as known)
    cov : DataFrame, shape (k, k)
    chi2 : float;  dof : int (n - k)
    prediction : Series, model mean per key
    residuals : Series, z = (model - measured) / sigma per key
    jac : DataFrame, shape (n, k), d(whitened prediction) / d(param) at the solution
    at_bound : list of parameter names that ended on a bound
    sigma : ndarray or None, the sigma per key the fit was scored with
    chol : ndarray (n, n) or None, the lower Cholesky factor of the covariance the fit was
        scored with when the model's errors correlate between observations (then chi2 is
        the Mahalanobis distance |chol^-1 (measured - model)|^2, not the sum of residuals^2);
        None: the covariance is diag(sigma^2)
    mode : ndarray or None, per key the motion mode the fit scored it in (a model with
        modes: the likelihood's mixture, :class:`Problem`); None without modes
    penalty : float, sum log(sigma^2 / sd^2) at the optimum when sigma depends on the
        parameters (a callable model_se), else 0 (sd the data's
        own, the same reference in every fit on these observations); ``objective`` = chi2 + penalty (-2 log likelihood up
        to a constant) is what fits are compared by
    """

    params: dict
    stderr: dict
    cov: pd.DataFrame
    chi2: float
    dof: int
    prediction: pd.Series
    residuals: pd.Series
    jac: pd.DataFrame
    at_bound: list
    sigma: np.ndarray | None = None
    penalty: float = 0.0
    chol: np.ndarray | None = None
    mode: np.ndarray | None = None

    def whiten(self, v):
        """A pattern in units of sigma per key (a z-vector, or columns of them) in the metric
        the fit was scored in: chol^-1 (sigma v); v itself without a chol."""
        v = np.asarray(v, float)
        if self.chol is None:
            return v
        s = self.sigma if v.ndim == 1 else self.sigma[:, None]
        return solve_lower(self.chol, s * v)

    @property
    def whitened(self) -> np.ndarray:
        """The whitened residual, measured - model, in the metric of the fit (|.|^2 = chi2)."""
        return self.whiten(-self.residuals.to_numpy(float))

    @property
    def objective(self) -> float:
        return self.chi2 + self.penalty

    @property
    def chi2_dof(self) -> float:
        return self.chi2 / self.dof if self.dof > 0 else float("nan")

    @property
    def p_value(self) -> float:
        return float(stats.chi2.sf(self.chi2, self.dof)) if self.dof > 0 else float("nan")

    def to_frame(self) -> pd.DataFrame:
        return pd.DataFrame({"value": pd.Series(self.params),
                             "stderr": pd.Series(self.stderr)})


@dataclass
class Diagnosis:
    """Result of :func:`diagnose`.

    Attributes
    ----------
    table : DataFrame, one row per candidate, ranked (rank 1 first)
        rank, effect, kind, delta_chi2, score, p_value, p_bonferroni, bic_gain, strength,
        strength_se, strength_lin, strength_at_bound, signature_norm, projected_norm,
        absorbed_frac, footprint, signature_snr, corr_base_max, identifiable, significant,
        chi2_dof_after
    baseline : FitResult-like stage at the starting parameters (no fit; stderr empty)
    calibrated : FitResult (base parameters fitted, effects off)
    fits : dict effect -> FitResult of the joint fit
    structure : DataFrame of residual-structure tests (descriptor, observable, z_score, p_value,
        p_bonferroni, significant, words)
    status : 'effect' | 'effect_partial' | 'nothing_missing' | 'unexplained'
    best : str or None, the reported effect
    verdict : str, plain words
    alpha : float; threshold_delta_chi2 : float (chi2 gain needed at the Bonferroni level)
    """

    table: pd.DataFrame
    baseline: FitResult
    calibrated: FitResult
    fits: dict
    structure: pd.DataFrame
    status: str
    best: str | None
    verdict: str
    alpha: float
    threshold_delta_chi2: float
    projected_signatures: pd.DataFrame = field(repr=False, default=None)

    def to_frame(self) -> pd.DataFrame:
        return self.table.copy()


# --------------------------------------------------------------------------- the problem

def observations_from_dataset(dataset: Dataset, v_rel_sd=DEFAULT_V_REL_SD,
                              f_col_sd_hz=DEFAULT_F_COL_SD_HZ,
                              yield_sd_pct=DEFAULT_YIELD_SD_PCT) -> pd.DataFrame:
    """Observations table (condition_id, observable, value, sd) of a dataset; yields become
    observables ``'yield_pct@<t>min'`` (e.g. 'yield_pct@12.5min')."""
    obs = measurement_table(dataset, v_rel_sd=v_rel_sd, f_col_sd_hz=f_col_sd_hz)
    obs = obs[["condition_id", "observable", "value", "sd"]]
    if dataset.yields is not None:
        y = yield_table(dataset, yield_sd_pct=yield_sd_pct)
        obs = pd.concat([obs, pd.DataFrame({
            "condition_id": y["condition_id"].to_numpy(),
            "observable": ["yield_pct@%gmin" % t for t in y["time_min"]],
            "value": y["value"].to_numpy(float), "sd": y["sd"].to_numpy(float)})],
            ignore_index=True)
    return obs


def dataset_observations(dataset: Dataset, flights=True):
    """(observations, flight condition ids, flight observations) of ``dataset``: its summary
    and yields (:func:`observations_from_dataset`), and with ``flights`` the impact
    observables of its tracks that carry the jar (:func:`analysis.flights.dataset_flights`;
    None and no ids when there are none)."""
    from analysis.flights import dataset_flights
    obs = observations_from_dataset(dataset)
    fl, fl_ids = None, []
    if flights and dataset.tracks:
        fl = dataset_flights(dataset)
        if len(fl):
            obs = pd.concat([obs, fl], ignore_index=True)
            fl_ids = list(dict.fromkeys(fl["condition_id"]))
    return obs, fl_ids, fl


def shared_sd_of(obs: pd.DataFrame) -> np.ndarray:
    """The observations' ``shared_sd`` per row, 0 where empty or without the column."""
    if "shared_sd" not in obs.columns:
        return np.zeros(len(obs))
    return np.nan_to_num(obs["shared_sd"].to_numpy(float), nan=0.0)


def shared_covariance(obs: pd.DataFrame) -> np.ndarray | None:
    """The off-diagonal covariance the observations' ``shared_sd`` states: shared_sd_i
    shared_sd_j between two rows of one condition, 0 elsewhere and on the diagonal; None
    without a shared error."""
    s = shared_sd_of(obs)
    sd = obs["sd"].to_numpy(float)
    if not np.all(np.isfinite(s)) or np.any(s < 0) or np.any(s > sd * (1 + 1e-9)):
        i = int(np.argmax(~np.isfinite(s) | (s < 0) | (s > sd * (1 + 1e-9))))
        raise ValueError("observations: shared_sd must be finite and between 0 and sd, "
                         "not %r at (%r, %r)" % (float(s[i]), obs["condition_id"].iloc[i],
                                                 obs["observable"].iloc[i]))
    if not np.any(s > 0):
        return None
    cond = obs["condition_id"].to_numpy()
    C = np.where(cond[:, None] == cond[None, :], np.outer(s, s), 0.0)
    C[np.diag_indices_from(C)] = 0.0
    return C


def with_run_sd(obs: pd.DataFrame, run_sd: pd.Series) -> pd.DataFrame:
    """``obs`` whose own error (sd less the ``shared_sd`` a film's rows share) is at least one
    twin run's scatter (``run_sd``, a Series by (condition_id, observable)) where it names one:
    a track is one realisation of a chaotic motion. The operator's standard error over the
    record and the scatter of one run's record mean both measure that realisation's chaos -
    the larger is kept (adding them in quadrature counted it twice: on 11 no-effect datasets
    the impact observables' mean z^2 was 0.23-0.45 for e_app and the impact phase); the film's
    scale error is another error and stays in quadrature."""
    key = list(zip(obs["condition_id"], obs["observable"]))
    add = np.array([run_sd.get(k, 0.0) for k in key])
    sd = obs["sd"].to_numpy(float)
    shared = shared_sd_of(obs)
    own = np.sqrt(np.maximum(sd ** 2 - shared ** 2, 0.0))
    out = obs.copy()
    out["sd"] = np.hypot(np.fmax(own, add), shared)
    return out


def prefetcher(predict):
    """The batch hook of a model's ``predict``, or None: ``predict.prefetch`` or, for a bound
    method ``model.predict``, ``model.prefetch`` - called with every (theta, effects) a
    finite-difference Jacobian is about to ask for, so that a model which evaluates many points
    at once (an emulator) does so in one call."""
    f = getattr(predict, "prefetch", None)
    owner = getattr(predict, "__self__", None)
    if f is None and owner is not None and getattr(owner, "predict", None) == predict:
        f = getattr(owner, "prefetch", None)
    return f


#: the global search of a fit (:meth:`Problem.global_starts`): Sobol points over the base
#: parameters and the effect's range, and how many of the lowest -2 log L start a local fit
GLOBAL_POINTS = 128
GLOBAL_STARTS = 3
#: the global starts lie at least this far apart (largest difference of any parameter, in units
#: of its range): the best points of a sample crowd into one minimum
GLOBAL_APART = 0.2
#: a global start this close (largest difference of any parameter, in units of its range) to
#: a point already fitted is not fitted again
GLOBAL_SAME_BASIN = 0.1

#: a motion mode whose probability at a condition is below exp(this) is not scored there
LOG_P_NEGLIGIBLE = -20.0


def _cholesky(S):
    """Lower Cholesky factor of a covariance, what rounding left not positive dropped."""
    try:
        return np.linalg.cholesky(S)
    except np.linalg.LinAlgError:
        w, U = np.linalg.eigh(S)
        floor = 1e-12 * max(float(np.min(np.diag(S))), 1e-300)
        return np.linalg.cholesky((U * np.maximum(w, floor)) @ U.T)


def _cholesky_each(mats) -> list:
    """:func:`_cholesky` of each matrix of a list of equal shapes, in one LAPACK loop (NumPy
    factors a stack matrix by matrix, as one by one); one by one where one is not positive."""
    if not mats:
        return []
    try:
        return list(np.linalg.cholesky(np.stack(mats)))
    except np.linalg.LinAlgError:
        return [_cholesky(S) for S in mats]


@dataclass(frozen=True)
class _ModeFit:
    """A motion-mode mixture scored against the data at one point: per observation the mean,
    the mode it is scored in and sigma (sqrt of the covariance's diagonal); the covariance's
    Cholesky factor; the rows that complete each condition's -2 log density."""
    mean: np.ndarray
    chol: np.ndarray
    sigma: np.ndarray
    mode: np.ndarray
    rows: np.ndarray


class Problem:
    """Whitened least-squares problem around a black-box ``predict``."""

    def __init__(self, predict, observations, base_params, effects, model_se, fixed_effects,
                 base_step_frac, conditions):
        if isinstance(observations, Dataset):
            conditions = observations.conditions if conditions is None else conditions
            observations = observations_from_dataset(observations)
        for col in ("condition_id", "observable", "value", "sd"):
            if col not in observations.columns:
                raise ValueError("observations: required column %r is missing" % col)
        obs = observations.reset_index(drop=True)
        self.keys = pd.MultiIndex.from_frame(obs[["condition_id", "observable"]])
        if self.keys.has_duplicates:
            raise ValueError("observations: duplicate (condition_id, observable) %r"
                             % (self.keys[self.keys.duplicated()][0],))
        self.y = obs["value"].to_numpy(float)
        sd = obs["sd"].to_numpy(float)
        if not np.all(np.isfinite(self.y)) or not np.all(np.isfinite(sd)) or np.any(sd < 0):
            raise ValueError("observations: value and sd must be finite, sd >= 0")
        self._shared = shared_covariance(obs)
        self.predict = predict
        self._prefetch = prefetcher(predict)
        self.base = list(base_params)
        names = [p.name for p in self.base]
        if len(set(names)) != len(names):
            raise ValueError("base parameters: duplicate names")
        self.effects = {e.name: e for e in effects}
        if len(self.effects) != len(effects):
            raise ValueError("effects: duplicate names")
        self.fixed = dict(fixed_effects or {})
        self.base_step_frac = base_step_frac
        self._cache = {}
        self._index_seen, self._indexer = None, None
        self.conditions = conditions
        self._modes_fn = None
        mu0 = self.mu({p.name: p.value for p in self.base}, {})     # predict checked
        # a callable model_se(theta, effects) -> Series: the model's uncertainty depends on
        # where it is asked (an emulator's), and every fit's likelihood carries it there
        self._se_fn = model_se if callable(model_se) else None
        # ... and with .cov, how its errors at one point correlate between the observations
        self._cov_fn = getattr(self._se_fn, "cov", None)
        # ... and with .modes, its response per motion mode (ModeComponents): the likelihood
        # is their mixture, scored per condition in the mode the data make most probable
        self._modes_fn = getattr(self._se_fn, "modes", None)
        self._mix = {}
        self._layout = None
        self._chols = {}
        if self._se_fn is not None:
            model_se = self._se_fn({p.name: p.value for p in self.base}, {})
        if model_se is None:
            se = np.zeros_like(self.y)
        elif np.isscalar(model_se):
            se = float(model_se) * np.abs(mu0)
        else:
            ms = pd.Series(model_se)
            missing = [k for k in self.keys if k not in ms.index]
            if missing:
                raise ValueError("model_se: no value for %r" % (missing[0],))
            se = ms.reindex(self.keys).to_numpy(float)
        self.model_se = se
        self.sd = sd
        self.sigma = np.sqrt(sd ** 2 + se ** 2)
        # the log-sigma penalty's reference, the same in every Problem on these observations
        # - so the objectives of fits made in different Problems (a calibration, a selection
        # step, a profile's inner fits) can be compared: with a model_se that depends on where
        # it is asked, the data's own sd (sigma >= sd; sigma only where no sd is stated), else
        # the constant sigma
        self._sigma_ref = (np.where(sd > 0, sd, self.sigma) if self._se_fn is not None
                           else self.sigma)
        self._esig = {}
        if np.any(self.sigma <= 0):
            raise ValueError("observations: zero uncertainty (sd and model_se both 0) at %r"
                             % (self.keys[int(np.argmin(self.sigma))],))

    @property
    def n(self):
        return len(self.y)

    def _full_effects(self, effects):
        eff = {e.name: e.null for e in self.effects.values()}
        eff.update(self.fixed)
        eff.update(effects)
        return eff

    def prefetch(self, points):
        """Hand the model's batch hook (:func:`prefetcher`) the (theta, effects) points not
        yet computed; nothing without a hook."""
        if self._prefetch is None:
            return
        todo = []
        for theta, effects in points:
            eff = self._full_effects(effects)
            if (tuple(sorted(theta.items())), tuple(sorted(eff.items()))) not in self._cache:
                todo.append((dict(theta), eff))
        if len(todo) > 1:
            self._prefetch(todo)

    def mu(self, theta, effects):
        """Model mean at base parameters ``theta`` and effect strengths ``effects`` (others null)."""
        if self._modes_fn is not None:
            return self._mixture(theta, effects).mean
        eff = self._full_effects(effects)
        key = (tuple(sorted(theta.items())), tuple(sorted(eff.items())))
        if key not in self._cache:
            out = self.predict(dict(theta), dict(eff))
            if not isinstance(out, pd.Series):
                raise TypeError("predict must return a pandas Series indexed by "
                                "(condition_id, observable)")
            if out.index is not self._index_seen:      # map keys once per index object
                if not out.index.is_unique:
                    raise ValueError("predict returned a Series with duplicate keys")
                indexer = out.index.get_indexer(self.keys)
                if np.any(indexer < 0):
                    raise ValueError("predict returned no value for %r"
                                     % (self.keys[int(np.argmin(indexer))],))
                self._index_seen, self._indexer = out.index, indexer
            vals = out.to_numpy(float)[self._indexer]
            if not np.all(np.isfinite(vals)):
                raise ValueError("predict returned a non-finite value at %r"
                                 % (self.keys[int(np.argmin(np.isfinite(vals)))],))
            self._cache[key] = vals
        return self._cache[key]

    def _mixture(self, theta, effects) -> "_ModeFit":
        """The model's motion-mode mixture at a point (:meth:`_mixture_of`), remembered."""
        eff = self._full_effects(effects)
        key = (tuple(sorted(theta.items())), tuple(sorted(eff.items())))
        hit = self._mix.get(key)
        if hit is None:
            if len(self._mix) >= 4096:
                self._mix.clear()
            hit = self._mix[key] = self._mixture_of(self._modes_fn(dict(theta), eff))
        return hit

    def _mixture_of(self, mc) -> "_ModeFit":
        """The likelihood of a mixture over motion modes, per condition: the twin's one
        realisation there is in mode k with probability p_k, so the data's density is
        sum_k p_k N(y; m_k, C_k + diag(sd^2)) - not one Gaussian of the mixture's moments,
        which lets a fit sit between two modes the twin never occupies. Each condition is
        scored in the mode of largest p_k N_k (the mixture's discrete latent at its most
        probable value: the fit's mean and covariance are that mode's, its errors correlated
        across the conditions in the same mode), and one row per condition adds what makes the
        rows' sum of squares that condition's exact -2 log of the mixture density:
        -2 log p_k* - 2 log sum_k exp(a_k - a_k*) + 2 log K >= 0 (a_k the log of p_k N_k; the
        constant 2 log K, the same at every point, keeps the row real)."""
        idx, blocks = self._mode_layout(mc)
        mean, cov = mc.mean[:, idx], mc.cov[:, idx][:, :, idx]
        if not (np.all(np.isfinite(mean)) and np.all(np.isfinite(cov))):
            raise ValueError("model_se.modes returned a non-finite value")
        K = len(mc.modes)
        n = len(self.y)
        pick = np.zeros(n, int)
        rows = []
        for g, on, ix, dvar in blocks:
            a = np.full(K, -np.inf)
            ks = [k for k in range(K) if not mc.log_p[k, g] < LOG_P_NEGLIGIBLE]
            for k, L in zip(ks, _cholesky_each([cov[k][ix] + dvar for k in ks])):
                w = solve_lower(L, self.y[on] - mean[k, on])
                a[k] = -0.5 * (w @ w) - np.sum(np.log(np.diag(L))) + mc.log_p[k, g]
            best = int(np.argmax(a))
            pick[on] = best
            rows.append(-2.0 * mc.log_p[best, g] - 2.0 * np.log(np.sum(np.exp(a - a[best])))
                        + 2.0 * np.log(K))
        S = np.where(pick[:, None] == pick[None, :], cov[pick, np.arange(n)], 0.0)
        S[np.diag_indices_from(S)] += self.sd ** 2
        if self._shared is not None:
            S += self._shared
        L = _cholesky(S)
        return _ModeFit(mean=mean[pick, np.arange(n)], chol=L, sigma=np.sqrt(np.diag(S)),
                        mode=np.asarray(mc.modes, object)[pick],
                        rows=np.sqrt(np.maximum(np.array(rows), 0.0)))

    def _mode_layout(self, mc):
        """Where ``mc``'s keys sit among the observations and, per condition, its rows with
        their index block and diag(sd^2): worked out once per keys and conditions object (a
        model hands the same ones at every point)."""
        seen = self._layout
        if seen is not None and seen[0] is mc.keys and seen[1] is mc.condition:
            return seen[2], seen[3]
        idx = pd.Index(mc.keys).get_indexer(self.keys)
        if np.any(idx < 0):
            raise ValueError("model_se.modes returned no value for %r"
                             % (self.keys[int(np.argmin(idx))],))
        cond = mc.condition[idx]
        D = self.data_cov()
        blocks = []
        for g in np.unique(cond):
            on = np.flatnonzero(cond == g)
            ix = np.ix_(on, on)
            blocks.append((g, on, ix, D[ix]))
        self._layout = (mc.keys, mc.condition, idx, blocks)
        return idx, blocks

    def profiled_start(self, theta, name, strength):
        """Base parameters refitted with effect ``name`` held at ``strength``: a starting point
        for a joint fit that does not begin where the calibration without the effect sat (an
        interpolated response can pull the strength back into a nearer minimum from there)."""
        keep = dict(self.fixed)
        self.fixed[name] = strength
        try:
            f = self.fit(theta)
        finally:
            self.fixed = keep
        return {p.name: f.params[p.name] for p in self.base}

    @property
    def varying_sigma(self):
        """sigma depends on the parameters (a callable model_se) or on the strengths."""
        return self._se_fn is not None

    def penalty(self, effects, theta=None):
        """sum log(sigma^2 / sd^2) at these effect strengths (and base parameters, with a
        callable model_se), sd the data's own: -2 log L = chi2 + penalty up to a constant
        common to every fit on these observations; 0 when sigma is constant."""
        if not self.varying_sigma:
            return 0.0
        return float(np.sum(2.0 * np.log(self._scale_diag(effects, theta) / self._sigma_ref))
                     + np.sum(self.mode_rows(effects, theta) ** 2))

    def modes_at(self, effects, theta):
        """Per key the motion mode the mixture scores it in at this point; None without."""
        if self._modes_fn is None:
            return None
        return self._mixture(theta, effects or {}).mode

    def mode_rows(self, effects, theta=None) -> np.ndarray:
        """The rows a motion-mode mixture adds to the objective, one per condition
        (:meth:`_mixture_of`); none without modes."""
        if self._modes_fn is None or theta is None:
            return np.zeros(0)
        return self._mixture(theta, effects or {}).rows

    def data_cov(self) -> np.ndarray:
        """The data's covariance: diag(sd^2), and shared_sd_i shared_sd_j between two rows
        of one condition (the observations' ``shared_sd``)."""
        D = np.diag(self.sd ** 2)
        return D if self._shared is None else D + self._shared

    def chol(self, effects, theta=None):
        """The lower Cholesky factor of the covariance D + K at these strengths and base
        parameters, D the data's (:meth:`data_cov`), K the model's own (its ``.cov``; else
        its sd^2 on the diagonal); None when neither correlates two observations (the
        covariance is diag(sigma^2))."""
        if self._modes_fn is not None and theta is not None:
            return self._mixture(theta, effects or {}).chol
        model_cov = self._cov_fn is not None and theta is not None
        if not model_cov and self._shared is None:
            return None
        eff = dict(self.fixed)
        eff.update(effects or {})
        key = (tuple(sorted((theta or {}).items())), tuple(sorted(eff.items())))
        if key not in self._chols:
            if len(self._chols) >= 4096:
                self._chols.clear()
            S = self._model_cov(theta, eff) if model_cov else np.zeros((self.n, self.n))
            S[np.diag_indices_from(S)] = self.sigma_for(effects, theta) ** 2
            if self._shared is not None:
                S += self._shared
            self._chols[key] = _cholesky(S)
        return self._chols[key]

    def _model_cov(self, theta, eff) -> np.ndarray:
        """The model's own covariance (its ``.cov``) at a point, in the observations' order."""
        K, index = self._cov_fn(dict(theta), eff)
        idx = (self._indexer if index is self._index_seen
               else pd.Index(index).get_indexer(self.keys))
        if np.any(idx < 0):
            raise ValueError("model_se.cov returned no value for %r"
                             % (self.keys[int(np.argmin(idx))],))
        S = np.asarray(K, float)[np.ix_(idx, idx)]
        if not np.all(np.isfinite(S)):
            raise ValueError("model_se.cov returned a non-finite value")
        return S

    def white(self, v, effects, theta=None):
        """measured-minus-model vectors (or the columns of an array) whitened at these
        strengths and base parameters: chol^-1 v, or v / sigma without a covariance."""
        L = self.chol(effects, theta)
        v = np.asarray(v, float)
        if L is None:
            s = self.sigma_for(effects, theta)
            return v / (s if v.ndim == 1 else s[:, None])
        return solve_lower(L, v)

    def _scale_diag(self, effects, theta=None):
        """Per key, the factor whose logs sum to half the log-determinant: sigma, or the
        Cholesky factor's diagonal (each >= sd: a covariance added to diag(sd^2) only
        raises the conditional variances)."""
        L = self.chol(effects, theta)
        return self.sigma_for(effects, theta) if L is None else np.diag(L)

    def sigma_for(self, effects, theta=None):
        """sigma: the data's sd and the model's uncertainty in quadrature - with a callable
        model_se, the model's uncertainty at ``theta`` and these strengths."""
        if self._modes_fn is not None and theta is not None:
            return self._mixture(theta, effects or {}).sigma
        if self._se_fn is not None and theta is not None:
            eff = dict(self.fixed)
            eff.update(effects or {})
            key = (tuple(sorted(theta.items())), tuple(sorted(eff.items())))
            if key not in self._esig:
                out = self._se_fn(dict(theta), eff)
                if isinstance(out, pd.Series) and out.index is self._index_seen:
                    se = out.to_numpy(float)[self._indexer]     # predict's keys: mapped once
                else:
                    se = pd.Series(out).reindex(self.keys).to_numpy(float)
                se = np.nan_to_num(se, nan=0.0)
                if not np.all(np.isfinite(se)) or np.any(se < 0):
                    raise ValueError("model_se returned a negative or non-finite value")
                self._esig[key] = np.sqrt(self.sd ** 2 + se ** 2)
            return self._esig[key]
        return self.sigma

    # ---- fitting in normalised coordinates u in [0, 1]
    def fit(self, start_theta, effect=None, start_strength=None, max_nfev=200) -> FitResult:
        """Fit the base parameters (and the strength of ``effect`` when given).

        With a callable model_se sigma depends on the point, and the fit maximises the Gaussian
        likelihood: besides the whitened residuals, the objective holds sum log(sigma^2 /
        sd^2) (as residual rows sqrt(log(...)) >= 0, sigma >= sd), so a point is not preferred
        for the uncertainty it adds. ``chi2`` is the residuals' part at the optimum."""
        names = [p.name for p in self.base]
        lo = np.array([p.lower for p in self.base], float)
        hi = np.array([p.upper for p in self.base], float)
        x0 = np.array([start_theta[k] for k in names], float)
        if effect is not None:
            e = self.effects[effect]
            names = names + [effect]
            lo = np.append(lo, e.lower)
            hi = np.append(hi, e.upper)
            x0 = np.append(x0, e.null if start_strength is None else start_strength)
        span = hi - lo
        nb = len(self.base)
        varying = self._se_fn is not None
        sigma_0 = self._sigma_ref

        def unpack(u):
            x = lo + span * np.clip(u, 0.0, 1.0)
            theta = dict(zip(names[:nb], x[:nb]))
            eff = {effect: x[nb]} if effect is not None else {}
            return theta, eff

        def whitened(u):
            theta, eff = unpack(u)
            return self.white(self.y - self.mu(theta, eff), eff, theta)

        def fun(u):
            r = whitened(u)
            if not varying:
                return r
            theta, eff = unpack(u)
            pen = 2.0 * np.log(self._scale_diag(eff, theta) / sigma_0)
            return np.concatenate([r, np.sqrt(np.maximum(pen, 0.0)),
                                   self.mode_rows(eff, theta)])

        def fd_jac(f, u):
            steps = []
            for j in range(len(u)):
                h = self.base_step_frac
                uj = u.copy()
                uj[j] = u[j] + h if u[j] + h <= 1.0 else u[j] - h
                steps.append(uj)
            self.prefetch([unpack(v) for v in [u] + steps])
            f0 = f(u)
            J = np.empty((len(f0), len(u)))
            for j, uj in enumerate(steps):
                J[:, j] = (f(uj) - f0) / (uj[j] - u[j])
            return J

        def jac(u):
            return fd_jac(fun, u)

        u0 = np.clip((x0 - lo) / span, 0.0, 1.0)
        sol = optimize.least_squares(fun, u0, jac=jac, bounds=(0.0, 1.0), method="trf",
                                     x_scale=1.0, xtol=1e-10, ftol=1e-12, gtol=1e-10,
                                     max_nfev=max_nfev)
        u = np.clip(sol.x, 0.0, 1.0)
        theta, eff = unpack(u)
        mu = self.mu(theta, eff)
        sigma = self.sigma_for(eff, theta)
        penalty = self.penalty(eff, theta) if varying else 0.0
        # d(whitened mu) / du, and how the motion modes' probabilities move (their rows)
        Ju = -fd_jac(lambda v: np.concatenate([whitened(v), self.mode_rows(*unpack(v)[::-1])]),
                     u)
        Jx = Ju / span                     # per physical unit
        cov = np.linalg.pinv(Jx.T @ Jx)
        x = lo + span * u
        params = dict(zip(names, x))
        stderr = dict(zip(names, np.sqrt(np.maximum(np.diag(cov), 0.0))))
        z = (mu - self.y) / sigma
        at_bound = [nm for nm, ui in zip(names, u) if ui <= 1e-9 or ui >= 1 - 1e-9]
        return FitResult(params=params, stderr=stderr,
                         cov=pd.DataFrame(cov, index=names, columns=names),
                         chi2=float(np.sum(whitened(u) ** 2)), dof=self.n - len(names),
                         prediction=pd.Series(mu, index=self.keys),
                         residuals=pd.Series(z, index=self.keys),
                         jac=pd.DataFrame(Jx[:self.n], index=self.keys, columns=names),
                         at_bound=at_bound,
                         sigma=sigma, penalty=penalty, chol=self.chol(eff, theta),
                         mode=self.modes_at(eff, theta))

    def global_starts(self, theta, effect=None, n_points=None, n_best=None, seed=0) -> list:
        """(theta, effects) starting points of a fit that do not depend on where the last fit
        sat: the ``n_best`` of lowest -2 log L among ``n_points`` Sobol points over the base
        parameters' bounds and ``effect``'s range (the kinetics line's parameters, linear and
        fitted from any start, held at ``theta``), each :data:`GLOBAL_APART` from the better
        ones. The likelihood on an emulator has several minima (an effect that a shifted stroke
        and friction half mimic), and a local fit from the calibrated point finds the nearest."""
        from scipy.stats import qmc
        free, lo, hi = self._searched(effect)
        if not len(lo):
            return []
        n_points = GLOBAL_POINTS if n_points is None else int(n_points)
        n_best = GLOBAL_STARTS if n_best is None else int(n_best)
        u = qmc.Sobol(len(lo), rng=np.random.default_rng(seed)).random(n_points)
        x = lo + u * (hi - lo)
        pts = [({**theta, **{p.name: float(r[i]) for i, p in enumerate(free)}},
                {} if effect is None else {effect: float(r[-1])}) for r in x]
        self.prefetch(pts)
        obj = [self.objective_at(t, e) for t, e in pts]
        picked = []
        for i in np.argsort(obj):
            if all(np.max(np.abs(u[i] - u[j])) >= GLOBAL_APART for j in picked):
                picked.append(i)
            if len(picked) == n_best:
                break
        return [pts[i] for i in picked]

    def objective_at(self, theta, eff) -> float:
        """-2 log L (chi2 + penalty, as :attr:`FitResult.objective`) at a point, no fit."""
        w = self.white(self.y - self.mu(theta, eff), eff, theta)
        return float(np.sum(w ** 2)) + (self.penalty(eff, theta) if self.varying_sigma else 0.0)

    def best_fit(self, theta, effect=None, start_strength=None) -> FitResult:
        """The best of the fit from ``theta`` (and ``start_strength``) and the fits from
        :meth:`global_starts`."""
        fit = self.fit(theta, effect=effect, start_strength=start_strength)
        seen = [self._unit(fit.params, fit.params, effect)]
        for t, e in self.global_starts(theta, effect):
            u = self._unit(t, e, effect)
            if min(np.max(np.abs(u - v)) for v in seen) < GLOBAL_SAME_BASIN:
                continue                  # next to a point already fitted: the same minimum
            f = self.fit(t, effect=effect, start_strength=e.get(effect))
            seen += [u, self._unit(f.params, f.params, effect)]
            if f.objective < fit.objective:
                fit = f
        return fit

    def _searched(self, effect):
        """What the global search spans: the base parameters but the kinetics line's, and the
        bounds of those and of ``effect``'s strength (arrays)."""
        from analysis.parameter_space import KINETICS_LINE
        free = [p for p in self.base if p.name not in KINETICS_LINE]
        ranges = [(p.lower, p.upper) for p in free]
        if effect is not None:
            ranges.append((self.effects[effect].lower, self.effects[effect].upper))
        lo, hi = (np.array(v, float) for v in zip(*ranges)) if ranges else (np.zeros(0),) * 2
        return free, lo, hi

    def _unit(self, theta, eff, effect):
        """A point's searched coordinates (:meth:`_searched`) on their unit ranges."""
        free, lo, hi = self._searched(effect)
        x = [theta[p.name] for p in free] + ([eff[effect]] if effect is not None else [])
        return (np.array(x, float) - lo) / (hi - lo)

    def stage(self, theta, eff=None) -> FitResult:
        """Model at fixed parameters (no fit): a FitResult with dof = n."""
        mu = self.mu(theta, eff or {})
        sig = self.sigma_for(eff or {}, theta)
        z = (mu - self.y) / sig
        w = self.white(self.y - mu, eff or {}, theta)
        return FitResult(params=dict(theta), stderr={}, cov=pd.DataFrame(),
                         chi2=float(np.sum(w ** 2)), dof=self.n,
                         prediction=pd.Series(mu, index=self.keys),
                         residuals=pd.Series(z, index=self.keys), jac=pd.DataFrame(),
                         at_bound=[], sigma=sig,
                         penalty=self.penalty(eff or {}, theta) if self.varying_sigma else 0.0,
                         chol=self.chol(eff or {}, theta), mode=self.modes_at(eff or {}, theta))


def _scan_starts(prob, theta, name, J=None, n_scan=None, n_best=2, exclude=()):
    """Starting strengths for the fit of effect ``name``: the ``n_best`` points of lowest
    profile chi2 on an even grid of ``n_scan`` strengths over its range, null excluded, as
    (strength, profile chi2) pairs; local minima only, none within half a grid step of
    ``exclude``. The base parameters are profiled out linearly: the whitened residual at
    (``theta``, strength) with its component along ``J`` (the whitened Jacobian of the base
    parameters at ``theta``, rescaled to that strength's sigma) removed, so a calibration that
    absorbed part of the effect does not hide a distant minimum; with a callable model_se the
    likelihood's log-sigma penalty is added."""
    e = prob.effects[name]
    n_scan = SCAN_POINTS if n_scan is None else int(n_scan)
    grid = np.linspace(e.lower, e.upper, n_scan)
    grid = grid[np.abs(grid - e.null) > 1e-12 * max(abs(e.upper - e.lower), 1e-300)]
    if not len(grid):
        return []
    J = np.zeros((prob.n, 0)) if J is None else np.asarray(J, float)
    L0 = prob.chol({}, theta)
    raw = J * prob.sigma_for({}, theta)[:, None] if L0 is None else L0 @ J
    chi2 = []
    for g in grid:
        Jg = prob.white(raw, {name: g}, theta)   # J was whitened at null: whiten it at g
        r = prob.white(prob.mu(theta, {name: g}) - prob.y, {name: g}, theta)
        chi2.append(float(np.sum(_project_out(Jg, r) ** 2))
                    + prob.penalty({name: g}, theta))
    chi2 = np.array(chi2)
    step = (e.upper - e.lower) / max(n_scan - 1, 1)
    out = []
    for i in np.argsort(chi2):
        left = chi2[i - 1] if i > 0 else np.inf
        right = chi2[i + 1] if i + 1 < len(grid) else np.inf
        if chi2[i] > min(left, right):
            continue                                    # not a local minimum of the scan
        if any(abs(grid[i] - x) < 0.5 * step for x in list(exclude) + [o[0] for o in out]):
            continue
        out.append((float(grid[i]), float(chi2[i])))
        if len(out) == n_best:
            break
    return out


def _project_out(J, v):
    """Component of v orthogonal to the columns of J (least squares), and the absorbed part."""
    if J.size == 0:
        return v.copy()
    coef, *_ = np.linalg.lstsq(J, v, rcond=None)
    return v - J @ coef


# --------------------------------------------------------------------------- diagnosis

def diagnose(predict, observations, base_params, effects, *, model_se=None,
             crn_correlation: float = 1.0, fixed_effects: dict | None = None,
             conditions: pd.DataFrame | None = None, alpha: float = 0.01,
             min_footprint: float = 2.0, min_snr: float = 3.0,
             effect_step_frac: float = 0.25, base_step_frac: float = 1e-3,
             structure: bool = True, noise_observables=None, progress=None,
             n_jobs: int = 1) -> Diagnosis:
    """Rank candidate effects by how well each explains the residual after calibration.

    Parameters
    ----------
    predict : callable (theta_base: dict, effects: dict) -> Series
        model mean, indexed by (condition_id, observable)
    observations : Dataset or DataFrame (condition_id, observable, value, sd)
    base_params : list of BaseParameter
        calibratable parameters (starting values = the "baseline" stage)
    effects : list of Effect
        candidates (including decoys); each tested alone with the base refitted
    model_se : None, float, Series or callable
        the twin's replicate noise: standard error of its mean prediction. A float is read as a
        fraction of the baseline prediction; a Series is indexed by (condition_id, observable)
        (sd / sqrt(replicates) per observation); a callable (theta, effects) -> Series is the
        model's uncertainty where it is asked (an emulator's), carried into every fit's
        likelihood (with its log-sigma term). None: a deterministic model.
    crn_correlation : float in [0, 1]
        correlation of the twin's noise between two predict calls (1: deterministic or common
        random numbers; 0: independent seeds) - sets the noise of finite differences
    fixed_effects : dict or None
        effects held at a given strength throughout (e.g. one already added)
    conditions : DataFrame or None
        condition_id, frequency_hz, ball_diameter_mm for the residual-structure description
        (taken from the Dataset when one is given)
    alpha : float
        family-wise significance level (Bonferroni over the candidates)
    min_footprint : float
        smallest noise-corrected projected footprint [sigma] for an identifiable effect
    min_snr : float
        smallest footprint / FD-noise ratio for an identifiable effect
    effect_step_frac : float
        FD step of the signature, as a fraction of the way from null to the far bound
    base_step_frac : float
        FD step for the base-parameter Jacobian, fraction of each parameter's range
    structure : bool
        run the residual-structure tests
    noise_observables : set of str or None
        observables whose twin noise is independent draws (e.g. {'v_mean_m_s', 'f_col_hz'});
        the identifiability chi-square counts only these (derived observables such as yields,
        computed from the same draws, would count the same noise several times). None: all.
        A 'kinetics' effect acts after the twin, on the same draws: its signature carries no
        twin noise.
    progress : str or None
        a progress bar's label: a bar over the candidates' fits on stderr (None: no bar)
    n_jobs : int
        processes for the candidates' fits (one candidate each; the same answers for any
        n_jobs: :func:`analysis.processes.in_processes`)

    Returns
    -------
    Diagnosis
    """
    prob = Problem(predict, observations, base_params, effects, model_se, fixed_effects,
                    base_step_frac, conditions)
    theta0 = {p.name: p.value for p in prob.base}
    baseline = prob.stage(theta0)
    cal = prob.best_fit(theta0)
    noise = _FDNoise.of(prob, crn_correlation, noise_observables)
    rules = _Rules(alpha, min_footprint, min_snr, effect_step_frac)
    from analysis.processes import in_processes
    tested = in_processes(functools.partial(_test_named, prob, cal, noise, rules),
                          list(prob.effects.items()), n_jobs, progress or "", "candidate",
                          bool(progress))
    rows = [row for row, _, _ in tested]
    fits = {name: fit for name, (_, fit, _) in zip(prob.effects, tested)}
    sigs = {name: sig for name, (_, _, sig) in zip(prob.effects, tested)}
    table = _ranked(rows)
    threshold = float(stats.chi2.isf(2.0 * alpha / max(len(prob.effects), 1), 1))
    struct = (residual_structure(cal, prob.conditions, alpha=alpha) if structure
              else pd.DataFrame())
    status, best, verdict = _verdict(table, cal, fits, struct, sigs, alpha, prob)
    return Diagnosis(table=table, baseline=baseline, calibrated=cal, fits=fits, structure=struct,
                     status=status, best=best, verdict=verdict, alpha=alpha,
                     threshold_delta_chi2=threshold,
                     projected_signatures=pd.DataFrame(sigs, index=prob.keys))


@dataclass(frozen=True)
class _Rules:
    """:func:`diagnose`'s tests: family-wise level, identifiability bars, the signature's FD
    step."""
    alpha: float
    min_footprint: float
    min_snr: float
    effect_step_frac: float


@dataclass(frozen=True)
class _FDNoise:
    """The twin's noise in a finite difference of two predictions, per whitened observation
    (``var``), its sum projected off the base parameters (``projected``), and which
    observables are independent draws (``indep``)."""
    var: np.ndarray
    projected: float
    indep: np.ndarray

    @classmethod
    def of(cls, prob, crn_correlation, noise_observables):
        n, p = prob.n, len(prob.base)
        var = 2.0 * (1.0 - crn_correlation) * (prob.model_se / prob.sigma) ** 2
        names = np.asarray(prob.keys.get_level_values(1))
        indep = (np.ones(n, bool) if noise_observables is None
                 else np.isin(names, list(noise_observables)))
        return cls(var, float(np.sum(var)) * max(n - p, 1) / n, indep)

    def snr(self, e, vfar, fp2) -> float:
        """The signature against its own noise, entry by entry (matched chi-square test over
        the independently drawn observables); a kinetics or observation effect's change is a
        function of the model's mean and carries no noise."""
        if e.kind in ("kinetics", "observation"):
            return math.inf if fp2 > 0 else 0.0
        nz = (self.var > 0) & self.indep
        free = (self.var == 0) & self.indep
        if free.any() and np.any(vfar[free] != 0):
            return math.inf                      # a noise-free entry moved
        if nz.any():
            T = float(np.sum(vfar[nz] ** 2 / self.var[nz]))
            return (T - nz.sum()) / math.sqrt(2.0 * nz.sum())
        return 0.0


def _test_named(prob, cal, noise, rules, item):
    """:func:`_test_candidate` of ``item``, a (name, Effect) pair."""
    return _test_candidate(prob, cal, *item, noise, rules)


def _test_candidate(prob, cal, name, e, noise, rules):
    """One candidate beside the calibrated base: (its row of the table, its best fit, its
    signature projected off the base parameters)."""
    theta_c = {p.name: cal.params[p.name] for p in prob.base}
    r, J = cal.whitened, cal.jac.to_numpy()
    travel = e.far - e.null
    h = rules.effect_step_frac * travel
    g = (prob.mu(theta_c, {name: e.null + h}) - prob.mu(theta_c, {name: e.null})) / h
    gw = prob.white(g, {}, theta_c)
    gp = _project_out(J, gw)
    vfar = prob.white(prob.mu(theta_c, {name: e.far}) - prob.mu(theta_c, {name: e.null}),
                      {}, theta_c)
    vp = _project_out(J, vfar)
    fp2 = float(vp @ vp)
    footprint = (math.sqrt(fp2) if e.kind in ("kinetics", "observation")
                 else math.sqrt(max(fp2 - noise.projected, 0.0)))
    gn2, gpn2 = float(gw @ gw), float(gp @ gp)
    U = float(gp @ r)
    if gpn2 > 0:
        s_lin = e.null + U / gpn2
        score = U * U / gpn2
    else:
        s_lin, score = e.null, 0.0
    # one-sided: a strength that cannot move the wanted way gives no score
    if (s_lin - e.null) * travel < 0 and e.null_on_bound:
        score = 0.0
    fit = _candidate_fit(prob, theta_c, name, e, J, float(np.clip(s_lin, e.lower, e.upper)), h)
    d = max(cal.objective - fit.objective, 0.0)   # 2 x the log-likelihood gain
    cov = fit.cov.to_numpy()
    sd = np.sqrt(np.maximum(np.diag(cov), 1e-300))
    corr = cov[-1, :-1] / (sd[-1] * sd[:-1]) if len(prob.base) else np.zeros(0)
    pv = _gain_p_value(d, fit, e.null_on_bound)
    p_bonf = min(1.0, len(prob.effects) * pv)
    bic_gain = d - math.log(prob.n)
    snr = noise.snr(e, vfar, fp2)
    identifiable = footprint >= rules.min_footprint and snr >= rules.min_snr
    row = {
        "effect": name, "kind": e.kind, "delta_chi2": d, "score": score,
        "p_value": pv, "p_bonferroni": p_bonf, "bic_gain": bic_gain,
        "strength": fit.params[name], "strength_se": fit.stderr[name],
        "strength_lin": s_lin, "strength_lin_se": (1.0 / math.sqrt(gpn2) if gpn2 > 0
                                                  else math.inf),
        "strength_at_bound": (name in fit.at_bound
                              and abs(fit.params[name] - e.null) > 1e-9 * abs(travel)),
        "signature_norm": math.sqrt(gn2), "projected_norm": math.sqrt(gpn2),
        "absorbed_frac": 1.0 - gpn2 / gn2 if gn2 > 0 else float("nan"),
        "footprint": footprint, "signature_snr": snr,
        "corr_base_max": float(np.max(np.abs(corr))) if corr.size else 0.0,
        "identifiable": identifiable,
        "significant": bool(identifiable and p_bonf < rules.alpha and bic_gain > 0),
        "chi2_dof_after": fit.chi2_dof}
    return row, fit, gp


def _candidate_fit(prob, theta_c, name, e, J, start, h):
    """The candidate's best fit: from its linear estimate ``start``, from null and from the
    best points of a scan over the strength's range (a library-interpolated response can have
    several minima); the best optimum."""
    fit = prob.best_fit(theta_c, effect=name, start_strength=start)
    if start != e.null:
        f0 = prob.fit(theta_c, effect=name, start_strength=e.null + 0.1 * h)
        if f0.objective < fit.objective:
            fit = f0
    for s0, c0 in _scan_starts(prob, theta_c, name, J, exclude=(start,)):
        if c0 >= fit.objective:
            continue                  # its (linear) profile is already worse: no fit
        f0 = prob.fit(prob.profiled_start(theta_c, name, s0), effect=name, start_strength=s0)
        if f0.objective < fit.objective:
            fit = f0
    return fit


def _gain_p_value(d, fit, null_on_bound) -> float:
    """The larger of the likelihood-ratio and the F test's p-values of a chi2 gain ``d`` (one
    parameter added); halved when the null strength is on its bound."""
    if d <= 0:
        return 1.0
    dof_after = max(fit.dof, 1)
    p_lr = float(stats.chi2.sf(d, 1))
    p_f = float(stats.f.sf(d / max(fit.chi2 / dof_after, 1e-300), 1, dof_after))
    if null_on_bound:
        p_lr, p_f = 0.5 * p_lr, 0.5 * p_f
    return max(p_lr, p_f)


def _ranked(rows) -> pd.DataFrame:
    """The candidates' rows, identifiable ones first, by chi2 gain; a rank column."""
    table = pd.DataFrame(rows)
    table = table.sort_values(["identifiable", "delta_chi2"], ascending=[False, False],
                              kind="stable").reset_index(drop=True)
    table.insert(0, "rank", np.arange(1, len(table) + 1))
    return table


def _verdict(table, cal, fits, struct, sigs, alpha, prob):
    sig = table.loc[table["significant"]]
    gof = cal.p_value
    head = "calibrated chi2/dof = %.2f (dof %d, p = %.2g)" % (cal.chi2_dof, cal.dof, gof)
    struct_words = ([w for w in struct.loc[struct["significant"], "words"]]
                    if len(struct) else [])
    if len(sig):
        b = sig.iloc[0]
        fit = fits[b["effect"]]
        words = ("missing effect: %s (%s), strength %.3g +- %.2g; chi2/dof %.2f -> %.2f "
                 "(chi2 gain %.1f, Bonferroni p = %.2g)"
                 % (b["effect"], b["kind"], b["strength"], b["strength_se"], cal.chi2_dof,
                    fit.chi2_dof, b["delta_chi2"], b["p_bonferroni"]))
        if b["strength_at_bound"]:
            words += "; the strength sits on its bound - the effect may be stronger than allowed"
        if len(sig) > 1:
            o = sig.iloc[1]
            a, c = sigs[b["effect"]], sigs[o["effect"]]
            cos = abs(float(a @ c)) / math.sqrt(float(a @ a) * float(c @ c))
            if b["delta_chi2"] - o["delta_chi2"] < 2.0:
                words += ("; %s explains it about as well (chi2 gain %.1f, signature overlap "
                          "%.2f) - the data cannot tell them apart"
                          % (o["effect"], o["delta_chi2"], cos))
        if fit.p_value >= alpha:
            return "effect", b["effect"], "%s; %s" % (words, head)
        rest = "; the residual after it is still beyond noise (chi2/dof %.2f, p = %.2g)" % (
            fit.chi2_dof, fit.p_value)
        return "effect_partial", b["effect"], "%s; %s%s" % (words, head, rest) + (
            (": " + "; ".join(struct_words)) if struct_words else "")
    if gof >= alpha:
        return "nothing_missing", None, ("nothing missing: %s is consistent with noise; no "
                                         "candidate effect is significant" % head)
    words = ("unexplained misfit: %s, and no candidate effect explains it beyond noise"
             % head)
    if struct_words:
        words += "; residual structure: " + "; ".join(struct_words)
    else:
        z = cal.residuals
        top = z.abs().sort_values(ascending=False).head(3)
        words += ("; no simple structure (frequency trend, ball-size split, offset, single "
                  "outlier) is significant; largest residuals: "
                  + ", ".join("%s %s z=%+.1f" % (k[0], k[1], z[k]) for k in top.index))
    return "unexplained", None, words


# --------------------------------------------------------------------------- residual structure

def residual_structure(fit: FitResult, conditions: pd.DataFrame | None,
                       alpha: float = 0.01, max_terms: int = 3,
                       min_unabsorbed: float = 0.3) -> pd.DataFrame:
    """Describe the calibrated residual by simple shapes, chosen greedily like effect signatures.

    Descriptors, per observable: offset (all conditions), linear trend with frequency, linear
    trend with ball diameter (= the ball-size split for two sizes); and every single point as a
    possible outlier. Each descriptor is projected onto the orthogonal complement of the base
    Jacobian (and of the descriptors already chosen); a descriptor that the base parameters
    absorb to more than ``1 - min_unabsorbed`` of its norm is not testable and skipped. Forward
    selection: the descriptor with the largest projected score is tested (two-sided normal,
    Bonferroni over all descriptors); if significant it is kept and the next one is sought in
    the residual with it removed, up to ``max_terms``.

    Returns
    -------
    DataFrame, one row per step (the last row is the first non-significant candidate):
        step, descriptor, observable, condition_id, z_score (signed: + means the model is
        high), p_value, p_bonferroni, significant, words
    """
    z = fit.residuals
    keys = z.index
    zv = -fit.whitened                 # model - measured, in the fit's metric
    J = fit.jac.to_numpy() if fit.jac.size else np.zeros((len(zv), 0))
    obs = keys.get_level_values(1)
    cids = keys.get_level_values(0)
    freq = diam = None
    if conditions is not None:
        c = conditions.set_index("condition_id")
        freq = np.array([float(c.at[k, "frequency_hz"]) if k in c.index else np.nan for k in cids])
        diam = np.array([float(c.at[k, "ball_diameter_mm"]) if k in c.index else np.nan
                         for k in cids])
    base_obs = np.array([o.split("@")[0] for o in obs])
    labels = {}
    if freq is not None:
        labels = {k: "%g mm ball at %g Hz" % (dd, ff) for k, ff, dd in zip(cids, freq, diam)
                  if np.isfinite(ff) and np.isfinite(dd)}
    descs = []
    for o in dict.fromkeys(base_obs):
        m = base_obs == o
        descs.append(("offset", o, None, m.astype(float)))
        if freq is not None and len(np.unique(freq[m])) > 1:
            descs.append(("frequency trend", o, None,
                          np.where(m, freq - np.nanmean(freq[m]), 0.0)))
        if diam is not None and len(np.unique(diam[m])) > 1:
            descs.append(("ball-size split", o, None,
                          np.where(m, diam - np.nanmean(diam[m]), 0.0)))
    for i in range(len(zv)):
        e = np.zeros(len(zv))
        e[i] = 1.0
        descs.append(("outlier", base_obs[i], cids[i], e))
    # each shape is a pattern in units of sigma per key: in the fit's metric like zv and J
    descs = [(k, o, c_, fit.whiten(np.nan_to_num(d))) for k, o, c_, d in descs]
    testable = []
    for k, o, c_, d in descs:
        dp = _project_out(J, d)
        if float(dp @ dp) >= min_unabsorbed ** 2 * float(d @ d) > 0:
            testable.append((k, o, c_, d))
    n_tests = max(len(testable), 1)
    out, chosen = [], []
    for step in range(1, max_terms + 1):
        A = np.column_stack([J] + [d for *_, d in chosen]) if (J.size or chosen) else J
        r = _project_out(A, zv) if A.size else zv
        best = None
        for k, o, c_, d in testable:
            if any(d is cd for *_, cd in chosen):
                continue
            dp = _project_out(A, d) if A.size else d
            nn = float(dp @ dp)
            if nn < 1e-12 * float(d @ d):
                continue
            sc = float(dp @ r) / math.sqrt(nn)
            if best is None or abs(sc) > abs(best[4]):
                best = (k, o, c_, d, sc)
        if best is None:
            break
        k, o, c_, d, sc = best
        p = float(2 * stats.norm.sf(abs(sc)))
        pb = min(1.0, n_tests * p)
        out.append({"step": step, "descriptor": k, "observable": o, "condition_id": c_,
                    "z_score": sc, "p_value": p, "p_bonferroni": pb,
                    "significant": pb < alpha,
                    "words": _structure_words(k, o, labels.get(c_, c_), sc)})
        if pb >= alpha:
            break
        chosen.append((k, o, c_, d))
    return pd.DataFrame(out, columns=["step", "descriptor", "observable", "condition_id",
                                      "z_score", "p_value", "p_bonferroni", "significant",
                                      "words"])


def _structure_words(kind, o, cid, s):
    word = _OBS_WORDS.get(o, o)
    side = "high" if s > 0 else "low"
    if kind == "offset":
        return "%s is %s at all conditions (%.1f sigma)" % (word, side, abs(s))
    if kind == "frequency trend":
        return ("%s residual trends with frequency: the model is increasingly %s toward high "
                "frequency (%.1f sigma)" % (word, side, abs(s)))
    if kind == "ball-size split":
        return ("%s residual splits by ball size: the model is %s for the larger ball relative "
                "to the smaller (%.1f sigma)" % (word, side, abs(s)))
    return "one outlier: %s, %s, model %s (%.1f sigma)" % (cid, word, side, abs(s))


# --------------------------------------------------------------------------- add an effect

def calibrate_base(predict, observations, base_params, *, model_se=None,
                   fixed_effects: dict | None = None, base_step_frac: float = 1e-3):
    """(baseline, calibrated) FitResults: the model at the base parameters' starting values, and
    with the base parameters fitted (effects off, ``fixed_effects`` held) - the calibration step
    of :func:`diagnose` on its own, for a loop that re-anchors its model before it diagnoses."""
    prob = Problem(predict, observations, base_params, [], model_se, fixed_effects,
                    base_step_frac, None)
    theta0 = {p.name: p.value for p in prob.base}
    return prob.stage(theta0), prob.best_fit(theta0)


#: a profile interval's end is found to this fraction of its bracketing step (the fit's se, at
#: least 1 % of the range): 2 % of an se is far below what the interval's own coverage resolves
PROFILE_TOL_STEPS = 0.02
#: the spacing of the scan past an interval's edge for a second region inside, as a fraction of
#: the parameter's range
PROFILE_SCAN_FRAC = 1.0 / 16


@dataclass(frozen=True)
class ProfileInterval:
    """A profile-likelihood interval of one fitted parameter.

    lower, upper : the interval's ends (a bound of the parameter where the profile never
        rises by ``threshold`` before it: ``open_lower`` / ``open_upper``)
    level : its coverage (e.g. 0.95); threshold : the rise of -2 log L that bounds it
    """
    name: str
    value: float
    lower: float
    upper: float
    level: float
    threshold: float
    open_lower: bool
    open_upper: bool


def profile_interval(predict, observations, base_params, name, fit: FitResult, *,
                     model_se=None, level=0.95, base_step_frac: float = 1e-3,
                     max_steps=40) -> ProfileInterval:
    """The ``level`` profile-likelihood interval of parameter ``name`` of ``fit``.

    The other parameters of ``base_params`` are refitted with ``name`` held at each trial
    value (by the fit's objective); the interval is where the misfit - chi2 in the metric of
    the data's sd and the model's uncertainty, and the motion modes' rows - rises by less than
    the chi-square(1) quantile above its value at the fit - the interval of Wilks' theorem,
    which follows the likelihood along a curved ridge where the curvature at the optimum
    (``fit.stderr``) does not. The log-determinant of the model's own uncertainty (what
    ``fit.penalty`` adds to chi2) is left out of the rise: an emulator refined where the fits
    lay is surest there, and that term would rule a value out for the runs not made near it:
    a value the model cannot tell from the fit stays in the interval (model_se is read as the
    model's uncertainty about its mean, not as a scatter of the data). Each end is bracketed
    outwards in steps of the fit's standard error (at least 1 % of the range) and found by
    bisection, the bracket's outer point reported (wide by at most the tolerance); then the
    rest of the range is scanned (:data:`PROFILE_SCAN_FRAC`) for values
    inside again - the interval is the hull of the region the profile allows, since an
    emulated response can bump up between values the data allow alike (measured on blind
    datasets: the true friction behind such a bump, 2.7 above the minimum). At each value the
    others are refitted from where the last value's fit ended and from the fit's own values,
    the better kept.
    """
    bp = {p.name: p for p in base_params}
    if name not in bp:
        raise ValueError("profile_interval: %r is not a fitted parameter (%s)"
                         % (name, ", ".join(bp)))
    if not 0.0 < level < 1.0:
        raise ValueError("profile_interval: level must lie in (0, 1), got %g" % level)
    p0 = bp[name]
    thr = float(stats.chi2.ppf(level, 1))
    x_hat = float(np.clip(fit.params[name], p0.lower, p0.upper))
    prof = _Profile(predict, observations, p0,
                    [BaseParameter(q.name, float(np.clip(fit.params[q.name], q.lower, q.upper)),
                                   q.lower, q.upper) for q in base_params if q.name != name],
                    model_se, base_step_frac)
    ref = prof.misfit(x_hat)
    se = float(fit.stderr.get(name, np.nan))
    step = max(se if np.isfinite(se) and se > 0 else 0.0, 0.01 * (p0.upper - p0.lower))
    edges = _ProfileEdges(lambda x: prof.misfit(x) - ref - thr, p0, step, max_steps)

    def end(direction):
        prof.restart()
        return edges.end(x_hat, direction)

    lo, open_lo = end(-1.0) if x_hat > p0.lower else (p0.lower, True)
    hi, open_hi = end(+1.0) if x_hat < p0.upper else (p0.upper, True)
    return ProfileInterval(name, x_hat, lo, hi, level, thr, open_lo, open_hi)


class _Profile:
    """The misfit profile of one parameter (``p0``): at each value of it the ``others``
    refitted from where the last value's fit ended and from the fit's own values, the better
    kept (one local fit follows a ridge and can lose it; a profile made of such fits jumps up
    and down between values the data allow alike); chi2 plus the motion modes' rows."""

    def __init__(self, predict, observations, p0, others, model_se, base_step_frac):
        self.predict, self.observations, self.p0 = predict, observations, p0
        self.others, self.model_se, self.base_step_frac = others, model_se, base_step_frac
        self.fit_others = {q.name: q.value for q in others}
        self.start = dict(self.fit_others)
        self.batch = prefetcher(predict)

    def restart(self):
        """The next value's fit starts from the fit's own values."""
        self.start.update(self.fit_others)

    def _held(self, x):
        """The model and its uncertainty with the parameter held at ``x``."""
        name, predict, model_se, batch = self.p0.name, self.predict, self.model_se, self.batch

        def pred(theta, effects=None):
            return predict(dict(theta, **{name: float(x)}), effects)
        if batch is not None:
            pred.prefetch = lambda pairs: batch([(dict(t, **{name: float(x)}), e)
                                                 for t, e in pairs])

        def se_fn(theta, effects=None):
            return model_se(dict(theta, **{name: float(x)}), effects)
        for hook in ("cov", "modes"):
            if getattr(model_se, hook, None) is not None:
                setattr(se_fn, hook, lambda theta, effects=None, f=getattr(model_se, hook):
                        f(dict(theta, **{name: float(x)}), effects))
        return pred, (se_fn if callable(model_se) else model_se)

    def misfit(self, x) -> float:
        pred, ms = self._held(x)
        starts = [BaseParameter(q.name, float(np.clip(self.start[q.name], q.lower, q.upper)),
                                q.lower, q.upper) for q in self.others]
        if not starts:
            prob = Problem(pred, self.observations, [BaseParameter("_none", 0.5, 0.0, 1.0)],
                           [], ms, None, self.base_step_frac, None)
            f = prob.stage({"_none": 0.5})
            return f.chi2 + float(np.sum(prob.mode_rows({}, f.params) ** 2))
        prob = Problem(pred, self.observations, starts, [], ms, None, self.base_step_frac,
                       None)
        begins = [{q.name: q.value for q in starts}]
        if begins[0] != self.fit_others:
            begins.append(self.fit_others)
        best = None
        for begin in begins:
            f = prob.fit(begin)
            v = f.chi2 + float(np.sum(prob.mode_rows({}, f.params) ** 2))
            if best is None or v < best[0]:
                best = (v, f)
        self.start.update({q.name: best[1].params[q.name] for q in starts})
        return best[0]


@dataclass(frozen=True)
class _ProfileEdges:
    """Where a profile's ``rise`` (its misfit less the fit's, less the threshold) crosses 0,
    for a parameter ``p0`` bracketed in growing steps from ``step``."""
    rise: object
    p0: BaseParameter
    step: float
    max_steps: int

    def crossing(self, a, direction):
        """From ``a`` (inside), outwards in growing steps to where the misfit has risen by
        the threshold, that edge bisected: (edge, reached the bound)."""
        p0, width = self.p0, self.step
        for _ in range(self.max_steps):
            b = float(np.clip(a + direction * width, p0.lower, p0.upper))
            if self.rise(b) >= 0:
                # bisection on the signs seen (each inner fit starts where the last ended, so
                # a point's value may differ slightly between two calls: no re-evaluation)
                for _ in range(40):
                    if abs(b - a) <= PROFILE_TOL_STEPS * self.step:
                        break
                    c = 0.5 * (a + b)
                    if self.rise(c) >= 0:
                        b = c
                    else:
                        a = c
                # the bracket's outer end (the misfit seen at or above the threshold there):
                # the interval errs wide by at most the tolerance, never narrow
                return b, False
            if b in (p0.lower, p0.upper):
                return b, True
            a, width = b, 1.5 * width
        return a, True

    def end(self, x_hat, direction):
        """The interval's end on one side of ``x_hat``: (end, open at the bound)."""
        p0 = self.p0
        edge, at_bound = self.crossing(x_hat, direction)
        while not at_bound:
            # past the edge, does the misfit fall below the threshold again? (an emulator's
            # response can bump between two values the data allow alike): a scan to the
            # bound, and from the farthest value inside, the edge again
            bound = p0.upper if direction > 0 else p0.lower
            n = int(np.ceil(abs(bound - edge) / (PROFILE_SCAN_FRAC * (p0.upper - p0.lower))))
            inside = [x for x in np.linspace(edge, bound, n + 1)[1:] if self.rise(float(x)) < 0]
            if not inside:
                break
            edge, at_bound = self.crossing(float(inside[-1]), direction)
        return edge, at_bound

if __name__ == "__main__":
    # the plug-in command line (--model package.module:factory) is retired (2026-12-03): one
    # loop on one model of the twin, python -m analysis.loop, runs the diagnosis
    print("analysis.diagnose: error: no command line any more (its --model plug-in was "
          "retired); run the loop: python -m analysis.loop --dataset DIR --out DIR",
          file=sys.stderr)
    sys.exit(2)
