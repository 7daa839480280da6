"""The one GP emulator of the twin: (parameters, effect strengths, conditions) -> outputs; and
the classifier of the twin's motion mode with the mixture of one emulator per mode
(:class:`ModeClassifier`, :func:`mix_modes`; used by :mod:`analysis.emulated_twin`).

One scikit-learn ``GaussianProcessRegressor`` per output. Inputs are scaled to the centred unit
cube [-0.5, 0.5] from declared bounds; outputs are normalised (``log_outputs`` are modelled as
the log of their value: relative changes that multiply). The kernel::

    C * Matern(nu, ARD length scales)  [+ C_lin * DotProduct(sigma_0)]  + WhiteKernel

is the history-matching emulator of Vernon, Goldstein & Bower (2010) and Andrianakis et al.
(2015) in Bayesian form: the optional linear part (``trend=True``) is a regression on the inputs
whose coefficients carry their own uncertainty (a linear kernel is Bayesian linear regression),
the Matern part the smooth departure from it, the nugget what neither explains.

**The twin's chaos.** A twin run is one realisation of a chaotic motion: two seeds at one input
give different outputs, with a scatter that differs by condition and observable. Two ways to
carry it, chosen by what the runs hold:

* ``noise_keys`` names the columns that set the noise (the condition's, e.g. ``frequency_hz``,
  ``ball_diameter_m``): wherever runs repeat one input with several seeds (replicates), the
  replicate variance is pooled per noise group and per output - each group's own estimate
  shrunk towards the pooled relative variance (:data:`SHRINK_DOF` pseudo-degrees of freedom;
  3 seeds leave one group's variance uncertain by a factor 2) - and enters the GP as a known
  per-run noise (``alpha``); a group without replicates takes the pooled one. The WhiteKernel
  holds what scatter remains beyond it, common to all groups;
* without replicates (one seed per input, a Latin hypercube) the WhiteKernel alone is the chaos,
  learned from the design.

In both, the WhiteKernel's level is scatter of the runs about the smooth response - chaos, and
near a motion-mode jump the jump's share that the smooth kernel does not follow - and is
counted in the chaos of a new run, not in the emulator's uncertainty about the mean.

:meth:`GPEmulator.predict_parts` separates the two: the latent sd (what more runs would remove:
the emulator's uncertainty about the twin's mean response) and the chaos sd of one new run, so
a mean of ``n`` new runs has variance ``latent^2 + chaos^2 / n``.

Quality: closed-form leave-out with the fitted hyperparameters held (Rasmussen & Williams 2006,
Sec. 5.4.2, eq. 5.12; for a block of runs left out together - every run of one design point,
all its seeds and conditions - the block form of the same identity), reported as RMSE, the
coverage of the 95 % interval of a new run and the mean z^2 (1 when the stated uncertainty is
right); :meth:`GPEmulator.score` on held-out runs.

References
----------
Rasmussen, C. E. & Williams, C. K. I. (2006). Gaussian Processes for Machine Learning. MIT Press.
Kennedy, M. C. & O'Hagan, A. (2001). Bayesian calibration of computer models. JRSS B 63, 425.
Vernon, I., Goldstein, M. & Bower, R. G. (2010). Galaxy formation: a Bayesian uncertainty
analysis. Bayesian Analysis 5, 619.
Andrianakis, I. et al. (2015). Bayesian history matching of complex infectious disease models
using emulation. PLoS Comput. Biol. 11, e1003968.
"""
from __future__ import annotations

import argparse
import math
import sys
import warnings
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy.linalg import cho_solve
from scipy.spatial.distance import cdist, pdist, squareform
from sklearn.exceptions import ConvergenceWarning
from sklearn.gaussian_process import GaussianProcessRegressor
from sklearn.gaussian_process.kernels import (ConstantKernel, DotProduct, Matern, Product,
                                              Sum, WhiteKernel)

from analysis.fit_cache import Replay, Search, hyperparameters, kernels_with
from analysis.linalg import solve_lower


#: two-sided 95 % normal quantile
Z95 = 1.959964
#: noise groups with replicates needed to carry the chaos as a known per-run noise (fewer: the
#: nugget learns it instead)
_MIN_REPLICATE_GROUPS = 1
#: pseudo-degrees of freedom of the pooled relative chaos variance in each group's estimate
SHRINK_DOF = 4.0


@dataclass(frozen=True)
class Prediction:
    """Emulated outputs at n inputs, each array of shape (n, n_outputs), in output units.

    mean : the twin's mean response
    latent_sd : the emulator's uncertainty about that mean (more runs would shrink it)
    chaos_sd : the scatter of one new twin run about its mean (the twin's chaos)
    latent_corr : None, or shape (n // block, n_outputs, block, block) - the correlation of the
        emulator's errors between the rows of each block of ``block`` consecutive inputs (one
        design point's conditions: one smooth response, so its errors at neighbouring
        conditions move together; :meth:`GPEmulator.predict_parts` with ``block``)
    mode_dev : None, or shape (n, n_outputs, n_modes) - of a mixture over motion modes
        (:func:`mix_modes`): sqrt(p_k) (mean_k - mean), whose sum of squares over the modes is
        the between-mode share of ``latent_sd`` squared; the same run is in one mode for every
        observable, so these deviations of two observables at one input are correlated
    """
    mean: np.ndarray
    latent_sd: np.ndarray
    chaos_sd: np.ndarray
    latent_corr: np.ndarray | None = None
    mode_dev: np.ndarray | None = None

    def sd(self, n_runs=1):
        """sd of the mean of ``n_runs`` new twin runs (np.inf: the mean response itself)."""
        chaos = 0.0 if np.isinf(n_runs) else self.chaos_sd ** 2 / float(n_runs)
        return np.sqrt(self.latent_sd ** 2 + chaos)


@dataclass(frozen=True)
class ModeComponents:
    """A model's response at one point per motion mode - the mixture a likelihood scores
    (:class:`analysis.diagnose.Problem`): one run, and the data's one realisation, is in one
    mode at each condition, with its probability there.

    modes : the K modes' names; keys : the n observations (condition_id, observable)
    mean : (K, n) each mode's mean; cov : (K, n, n) each mode's emulator covariance (its errors
        correlated across the conditions; the modes' emulators independent of one another)
    log_p : (K, n_conditions) log p(mode) per condition; condition : (n,) each key's condition
        (a column of ``log_p``)
    """
    modes: tuple
    keys: pd.Index
    mean: np.ndarray
    cov: np.ndarray
    log_p: np.ndarray
    condition: np.ndarray


class _UnitCube:
    """Inputs named by ``bounds`` (name -> (lower, upper)), scaled to the centred unit cube."""

    @property
    def inputs(self):
        return list(self.bounds)

    def _raw_inputs(self, X):
        if isinstance(X, pd.DataFrame):
            missing = [c for c in self.inputs if c not in X.columns]
            if missing:
                raise ValueError("emulator input table lacks column(s) %s" % ", ".join(missing))
            X = X[self.inputs].to_numpy(float)
        X = np.atleast_2d(np.asarray(X, float))
        if X.shape[1] != len(self.inputs):
            raise ValueError("emulator inputs need %d columns (%s), got %d"
                             % (len(self.inputs), ", ".join(self.inputs), X.shape[1]))
        if not np.isfinite(X).all():
            raise ValueError("emulator inputs hold NaN or inf")
        return X

    def _scale(self, X):
        X = self._raw_inputs(X)
        lo = np.array([self.bounds[k][0] for k in self.inputs], float)
        hi = np.array([self.bounds[k][1] for k in self.inputs], float)
        if np.any(hi <= lo):
            raise ValueError("emulator bounds must have upper > lower: %s" % self.bounds)
        return (X - lo) / (hi - lo) - 0.5


class GPEmulator(_UnitCube):
    """GP emulator with inputs scaled to the centred unit cube.

    Parameters
    ----------
    bounds : dict name -> (lower, upper) - input names (their order is the column order of
        array inputs) and ranges used for scaling [their own units]
    outputs : sequence of str - output names, e.g. ("v_mean_m_s", "f_col_hz")
    nu : float - Matern smoothness (0.5, 1.5 or 2.5)
    trend : bool - add the linear (Bayesian regression) part to the kernel
    log_outputs : sequence of str - outputs modelled as log(value) (must be > 0)
    noise_keys : sequence of str or None - input columns that set the chaos' noise group (see
        the module docstring); None: the nugget learns one chaos level per output
    n_restarts_optimizer : int - restarts of the hyperparameter optimiser
    random_state : int or None
    fit_cache : :class:`analysis.fit_cache.FitCache` or None - where earlier fits'
        hyperparameters are kept (a fit of the same data reuses them: the same model, faster)

    Attributes
    ----------
    gps_ : list of fitted GaussianProcessRegressor, one per output
    n_train_ : int - number of training runs
    noise_table_ : DataFrame or None - pooled replicate sd per noise group and output
    loo_ : DataFrame - leave-one-out report (see :meth:`loo_report`)
    """

    def __init__(self, bounds, outputs=("v_mean_m_s", "f_col_hz"), nu=2.5, trend=False,
                 log_outputs=(), noise_keys=None, n_restarts_optimizer=2, random_state=None,
                 fit_cache=None):
        self.bounds = bounds
        self.fit_cache = fit_cache
        self.outputs = outputs
        self.nu = nu
        self.trend = trend
        self.log_outputs = log_outputs
        self.noise_keys = noise_keys
        self.n_restarts_optimizer = n_restarts_optimizer
        self.random_state = random_state

    # ---------------------------------------------------------------------------- helpers
    def _is_log(self):
        return np.array([o in tuple(self.log_outputs) for o in self.outputs])

    def _targets(self, Y):
        if isinstance(Y, pd.DataFrame):
            missing = [c for c in self.outputs if c not in Y.columns]
            if missing:
                raise ValueError("emulator output table lacks column(s) %s" % ", ".join(missing))
            Y = Y[list(self.outputs)].to_numpy(float)
        Y = np.asarray(Y, float)
        if Y.ndim == 1:
            Y = Y[:, None]
        if Y.shape[1] != len(self.outputs):
            raise ValueError("emulator outputs need %d columns, got %d"
                             % (len(self.outputs), Y.shape[1]))
        if not np.isfinite(Y).all():
            bad = np.argwhere(~np.isfinite(Y))[0]
            raise ValueError("emulator training output %s is not finite in row %d"
                             % (self.outputs[bad[1]], bad[0]))
        L = self._is_log()
        if L.any():
            if np.any(Y[:, L] <= 0):
                bad = [o for o, l in zip(self.outputs, L) if l]
                raise ValueError("emulator log output(s) %s must be > 0" % ", ".join(bad))
            Y = Y.copy()
            Y[:, L] = np.log(Y[:, L])
        return Y

    def _kernel(self, d):
        k = (ConstantKernel(1.0, (1e-3, 1e3))
             * Matern(length_scale=np.full(d, 0.5), length_scale_bounds=(1e-2, 1e2), nu=self.nu))
        if self.trend:
            k = k + ConstantKernel(1.0, (1e-4, 1e3)) * DotProduct(1.0, (1e-3, 1e2))
        nug_lo = 1e-8 if self.noise_keys is None else 1e-10
        return k + WhiteKernel(1e-2, (nug_lo, 1.0))

    # ----------------------------------------------------------------------- chaos' noise
    def _groups(self, X):
        """Noise-group key per row (a tuple of the noise_keys' values)."""
        idx = [self.inputs.index(k) for k in self.noise_keys]
        return [tuple(np.round(r, 12)) for r in X[:, idx]]

    def _replicate_noise(self, X, Y):
        """Pooled replicate variance per noise group and output: (table, {group: var row})."""
        keys = [tuple(np.round(r, 12)) for r in X]
        groups = self._groups(X)
        df = pd.DataFrame(Y, columns=list(self.outputs))
        df["_x"], df["_g"] = keys, groups
        ss, dof = {}, {}
        for (x, g), part in df.groupby(["_x", "_g"], sort=False):
            if len(part) < 2:
                continue
            vals = part[list(self.outputs)].to_numpy(float)
            ss[g] = ss.get(g, 0.0) + ((vals - vals.mean(0)) ** 2).sum(0)
            dof[g] = dof.get(g, 0) + len(part) - 1
        if len(ss) < _MIN_REPLICATE_GROUPS:
            return None, None
        raw = {g: ss[g] / dof[g] for g in ss}
        # relative to the squared mean level of the group's outputs (absolute for log outputs,
        # which are relative already): the pooled relative variance, and each group's own
        # shrunk towards it with SHRINK_DOF pseudo-degrees of freedom (empirical Bayes: 2 dof
        # of one group's 3 seeds leave its variance uncertain by a factor 2); a group without
        # replicates takes the pooled one
        level = {g: np.maximum(np.abs(part[list(self.outputs)].to_numpy(float).mean(0)), 1e-30)
                 for g, part in df.groupby("_g", sort=False)}
        L = self._is_log()

        def rel(g, v):
            return np.where(L, v, v / level[g] ** 2)

        def absolute(g, r):
            return np.where(L, r, r * level[g] ** 2)

        pooled = (sum(rel(g, raw[g]) * dof[g] for g in raw)
                  / sum(dof.values()))
        var = {}
        for g in level:
            d = dof.get(g, 0)
            r = (rel(g, raw[g]) * d if d else 0.0) + pooled * SHRINK_DOF
            var[g] = absolute(g, r / (d + SHRINK_DOF))
            dof[g] = d
        rows = [{**dict(zip(self.noise_keys, g)), "replicate_dof": dof[g],
                 **{o + "_sd": float(np.sqrt(v)) for o, v in zip(self.outputs, var[g])}}
                for g in var]
        return pd.DataFrame(rows), var

    def _chaos_var(self, X):
        """(n, n_outputs) replicate-estimated chaos variance of one run at raw inputs X (model
        units: log for log outputs); a noise group never seen takes the median over the seen
        groups. Remembered by the rows' noise keys (a fit asks for the same conditions at
        every point); read-only."""
        key = X[:, [self.inputs.index(k) for k in self.noise_keys]].tobytes()
        memo = self.__dict__.setdefault("_chaos_memo", {})
        hit = memo.get(key)
        if hit is None:
            med = np.median(np.array(list(self.chaos_var_.values())), axis=0)
            hit = np.array([self.chaos_var_.get(g, med) for g in self._groups(X)])
            hit.flags.writeable = False
            if len(memo) >= 256:
                memo.clear()
            memo[key] = hit
        return hit

    # -------------------------------------------------------------------------------- fit
    def fit(self, X, Y):
        """Fit one GP per output.

        Parameters
        ----------
        X : DataFrame with the input columns, or ndarray, shape (n, n_inputs)
        Y : DataFrame with the output columns, or ndarray, shape (n, n_outputs)

        Returns
        -------
        self
        """
        Xr = self._raw_inputs(X)
        Xs = self._scale(Xr)
        Y = self._targets(Y)
        if len(Xs) != len(Y):
            raise ValueError("X has %d rows, Y has %d" % (len(Xs), len(Y)))
        if len(Xs) < len(self.inputs) + 2:
            raise ValueError("need at least %d training runs, got %d"
                             % (len(self.inputs) + 2, len(Xs)))
        self.chaos_var_, self.noise_table_, self._chaos_memo = None, None, {}
        if self.noise_keys is not None:
            missing = [k for k in self.noise_keys if k not in self.inputs]
            if missing:
                raise ValueError("noise key(s) %s are not emulator inputs" % ", ".join(missing))
            self.noise_table_, self.chaos_var_ = self._replicate_noise(Xr, Y)
        alpha = None if self.chaos_var_ is None else self._chaos_var(Xr)
        self.gps_ = []
        for j in range(Y.shape[1]):
            y_sd = float(np.std(Y[:, j])) or 1.0
            a = 1e-10 if alpha is None else np.maximum(alpha[:, j], 1e-12) / y_sd ** 2
            self.gps_.append(self._fit_gp(Xs, Y[:, j], a))
        self.nugget_var_ = np.array([gp.kernel_.k2.noise_level * gp._y_train_std ** 2
                                     for gp in self.gps_])
        self.smooth_ = [SmoothKernel(gp.kernel_.k1, gp.X_train_) for gp in self.gps_]
        self.n_train_ = len(Xs)
        self.loo_ = self.loo_report()
        return self

    def _fit_gp(self, Xs, y, alpha) -> GaussianProcessRegressor:
        """One output's GP on scaled inputs; its hyperparameters optimised, or replayed from
        ``fit_cache`` when these data were fitted before (the same model, bit for bit)."""
        kernel, cache = self._kernel(Xs.shape[1]), self.fit_cache
        key = cache and cache.key("gpr", kernel, Xs, y, alpha, restarts=self.n_restarts_optimizer,
                                  seed=self.random_state)
        replay = cache and Replay.of(cache.get(key), kernel)
        search = replay or Search()
        gp = GaussianProcessRegressor(kernel=kernel, alpha=alpha, normalize_y=True,
                                      optimizer=search,
                                      n_restarts_optimizer=self.n_restarts_optimizer,
                                      random_state=self.random_state)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ConvergenceWarning)
            gp.fit(Xs, y)
        if cache and not replay:
            cache.put(key, search.best())
        return gp

    # ---------------------------------------------------------------------------- predict
    def noise_sd(self):
        """One run's chaos sd per output, pooled over the noise groups [model units]."""
        if self.chaos_var_ is None:
            return np.sqrt(self.nugget_var_)
        med = np.median(np.array(list(self.chaos_var_.values())), axis=0)
        return np.sqrt(med + self.nugget_var_)

    def _predict_model_units(self, X, block=None):
        """(mean, latent variance, chaos variance), each (n, n_outputs) in model units, and
        with ``block`` the latent correlations within each block of rows (else None).

        The latent part is the smooth kernel's posterior alone (Rasmussen & Williams 2006,
        eq. 2.24 without the white term): the nugget is scatter of the runs about the smooth
        response - the twin's chaos beyond what the replicates estimated (a 3-seed variance is
        uncertain by a factor 2) - not the emulator's uncertainty about the mean, which shrinks
        as runs come in."""
        Xr = self._raw_inputs(X)
        Xs = self._scale(Xr)
        n, k = len(Xs), len(self.gps_)
        if block is not None and (block < 1 or n % block):
            raise ValueError("predict_parts: %d inputs do not split into blocks of %s"
                             % (n, block))
        mean = np.empty((n, k))
        var = np.empty_like(mean)
        corr = None if block is None else np.empty((n // block, k, block, block))
        for j, (gp, smooth) in enumerate(zip(self.gps_, self.smooth_)):
            Kt = smooth.cross(Xs)
            V = solve_lower(gp.L_, Kt.T)
            y_sd = float(np.atleast_1d(gp._y_train_std)[0])
            mean[:, j] = (Kt @ gp.alpha_) * y_sd + float(np.atleast_1d(gp._y_train_mean)[0])
            var[:, j] = np.maximum(smooth.diag(Xs) - np.einsum("ij,ij->j", V, V), 0.0) * y_sd ** 2
            if corr is not None:
                corr[:, j] = _block_corr(smooth, Xs, V, block)
        nugget = self.nugget_var_[None, :]
        chaos = nugget if self.chaos_var_ is None else self._chaos_var(Xr) + nugget
        return mean, var, np.broadcast_to(chaos, var.shape).copy(), corr

    def predict_parts(self, X, block=None) -> Prediction:
        """The twin's mean response, the emulator's sd of it and one run's chaos sd at X, in
        output units (a log output's sds are those of its value, to first order); with
        ``block`` (the number of conditions of a design point: X's rows in consecutive blocks
        of that many) also the correlations of the emulator's errors within each block (a
        log output's are those of its value, to first order: a correlation does not change
        when each row is rescaled)."""
        mean, var, chaos, corr = self._predict_model_units(X, block)
        L = self._is_log()
        lat, ch = np.sqrt(var), np.sqrt(chaos)
        if L.any():
            mean = mean.copy()
            mean[:, L] = np.exp(mean[:, L])
            lat[:, L] = lat[:, L] * mean[:, L]
            ch[:, L] = ch[:, L] * mean[:, L]
        return Prediction(mean, lat, ch, corr)

    def predict(self, X, return_std=False, include_noise=True):
        """Emulated outputs (the mean only, without ``return_std``: no variance computed).

        Parameters
        ----------
        X : DataFrame or ndarray, shape (n, n_inputs)
        return_std : bool
        include_noise : bool - True: sd of one new twin run (latent + chaos);
            False: sd of the twin's mean response (latent only)

        Returns
        -------
        mean : ndarray, shape (n, n_outputs)
        std : ndarray, shape (n, n_outputs) - only with return_std
        """
        if not return_std:
            Xs = self._scale(X)
            mean = np.column_stack([gp.predict(Xs) for gp in self.gps_])
            L = self._is_log()
            if L.any():
                mean[:, L] = np.exp(mean[:, L])
            return mean
        p = self.predict_parts(X)
        return p.mean, p.sd(1 if include_noise else np.inf)

    # ------------------------------------------------------------------------- validation
    def leave_out(self, groups=None):
        """Closed-form leave-out predictions at the training runs (hyperparameters held).

        Parameters
        ----------
        groups : array-like of length n_train, optional - runs with one label are left out
            together (block leave-out); None: one run at a time

        Returns
        -------
        y, mean, sd : ndarray, shape (n, n_outputs) - training outputs and the leave-out
            predictive mean and sd of a new run there, in model units (log for log outputs)
        """
        labels = np.arange(self.n_train_) if groups is None else np.asarray(groups)
        if len(labels) != self.n_train_:
            raise ValueError("groups has %d labels for %d training runs"
                             % (len(labels), self.n_train_))
        blocks = [np.flatnonzero(labels == g) for g in pd.unique(labels)]
        ys, ms, ss = [], [], []
        for gp in self.gps_:
            n = len(gp.alpha_)
            kinv = cho_solve((gp.L_, True), np.eye(n))
            scale, shift = gp._y_train_std, gp._y_train_mean
            y = gp.y_train_ * scale + shift
            mean, sd = np.empty(n), np.empty(n)
            for b in blocks:
                cov = np.linalg.inv(kinv[np.ix_(b, b)])     # covariance of y_b given the rest
                mean[b] = gp.y_train_[b] - cov @ gp.alpha_[b]
                sd[b] = np.sqrt(np.diag(cov))
            ys.append(y)
            ms.append(mean * scale + shift)
            ss.append(sd * scale)
        return np.column_stack(ys), np.column_stack(ms), np.column_stack(ss)

    def loo_report(self, groups=None):
        """Leave-out error per output.

        Returns
        -------
        DataFrame indexed by output: n, rmse, rel_rmse_pct (RMSE / mean |y|; a log output's
        RMSE is of its log, x100 a relative error in %), max_abs_err, noise_sd (one run's
        chaos), coverage95 (fraction of leave-out 95 % intervals of a new run holding the run),
        mean_abs_z, mean_z2 (1 when the stated sd is right).
        """
        y, m, s = self.leave_out(groups)
        return _error_table(self.outputs, y, m, s, self.noise_sd(), self._is_log())

    def score(self, X, Y):
        """Held-out error table of new runs (same columns as :meth:`loo_report`)."""
        Y = self._targets(Y)
        mean, var, chaos, _ = self._predict_model_units(X)
        return _error_table(self.outputs, Y, mean, np.sqrt(var + chaos), self.noise_sd(),
                            self._is_log())


class ModeClassifier(_UnitCube):
    """The twin's motion mode at an input: p(mode | x) from a Gaussian-process classifier.

    The single ball's motion falls into modes (end-to-end flights, chatter at one end, ...)
    whose observables differ by far more than a run's chaos - chatter's collision rate is
    70 /s where the end-to-end flights at the same condition give 50 /s - and which mode a run
    takes changes with the contact parameters and the condition, sharply but not at one clean
    boundary (two seeds near it can land in different modes). One smooth emulator across the
    modes averages them and states the average as sure: at a point deep in chatter it predicts
    the mid-way value with an sd a tenth of the miss. With this classifier each mode has its
    own emulator and the prediction is their mixture (:func:`mix_modes`).

    scikit-learn's ``GaussianProcessClassifier`` (Laplace approximation, one-vs-rest for more
    than two modes) with a Matern 5/2 ARD kernel on the unit cube; its probabilities hold both
    the seed-to-seed chance of a mode and the classifier's ignorance where runs are few.

    Parameters
    ----------
    bounds : dict name -> (lower, upper) - inputs, as :class:`GPEmulator`'s
    random_state : int or None
    n_restarts_optimizer : int
    fit_cache : :class:`analysis.fit_cache.FitCache` or None - as :class:`GPEmulator`'s

    Attributes (after :meth:`fit`)
    ----------
    modes_ : list of str - the modes, in the order of :meth:`predict_proba`'s columns
    """

    def __init__(self, bounds, random_state=None, n_restarts_optimizer=1, fit_cache=None):
        self.bounds = bounds
        self.random_state = random_state
        self.n_restarts_optimizer = n_restarts_optimizer
        self.fit_cache = fit_cache

    def fit(self, X, modes):
        """Learn p(mode | x) from runs' inputs X and their modes (a sequence of labels)."""
        from sklearn.gaussian_process import GaussianProcessClassifier
        Xs = self._scale(X)
        labels = np.asarray(modes, dtype=object).astype(str)
        if len(labels) != len(Xs):
            raise ValueError("X has %d rows, modes %d" % (len(Xs), len(labels)))
        self.modes_ = sorted(set(labels))
        self.gpc_ = None
        if len(self.modes_) < 2:
            return self
        kern = (ConstantKernel(1.0, (1e-2, 1e3))
                * Matern(length_scale=np.full(Xs.shape[1], 0.5),
                         length_scale_bounds=(1e-2, 1e2), nu=2.5))
        cache, n_bin = self.fit_cache, (1 if len(self.modes_) == 2 else len(self.modes_))
        key = cache and cache.key("gpc", kern, Xs, labels, restarts=self.n_restarts_optimizer,
                                  seed=self.random_state)
        found = cache and cache.get(key, kind=list)
        known = found and kernels_with(kern, found, n_bin)
        self.gpc_ = GaussianProcessClassifier(
            known[0] if known else kern, optimizer=None if known else "fmin_l_bfgs_b",
            n_restarts_optimizer=self.n_restarts_optimizer, random_state=self.random_state)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ConvergenceWarning)
            self.gpc_.fit(Xs, labels)
            binaries = self._binaries()
            if known and n_bin > 1:         # one-vs-rest: each mode's classifier its own kernel
                for est, k, mode in zip(binaries, known, self.gpc_.classes_):
                    est.set_params(kernel=k).fit(Xs, (labels == mode).astype(int))
        if cache and not known:
            cache.put(key, [hyperparameters(est.kernel_) for est in binaries])
        self.smooth_ = [SmoothKernel(est.kernel_, est.X_train_) for est in binaries]
        return self

    def _binaries(self) -> list:
        """The fitted binary classifiers: one, or one per mode (one-vs-rest)."""
        base = self.gpc_.base_estimator_
        return list(getattr(base, "estimators_", [base]))

    def predict_proba(self, X) -> np.ndarray:
        """(n, n_modes) probabilities of each mode at X (columns in the order of ``modes_``)."""
        Xs = self._scale(X)
        if self.gpc_ is None:
            return np.ones((len(Xs), 1))
        ests = list(zip(self._binaries(), self.smooth_))
        if len(ests) == 1:
            pi = _laplace_proba(*ests[0], Xs)
            p = np.vstack((1 - pi, pi)).T
        else:                               # one-vs-rest, normalised as scikit-learn does
            p = np.array([_laplace_proba(e, k, Xs) for e, k in ests]).T
            sums = np.sum(p, axis=1)[:, np.newaxis]
            np.divide(p, sums, out=p, where=sums != 0)
        order = [list(self.gpc_.classes_).index(k) for k in self.modes_]
        return p[:, order]


def _laplace_proba(est, kernel, X) -> np.ndarray:
    """p(class 1) of one fitted binary Laplace GP classifier of scikit-learn (``kernel``: its
    fitted kernel, a :class:`SmoothKernel`) at X: its
    ``predict_proba`` (Algorithm 3.2 of Rasmussen and Williams, the logistic's integral by
    its five error functions) to the last digit, with the triangular solve made as one:
    scikit-learn's general ``solve`` detects the structure and estimates the condition on
    every call, a sixth of a cached loop's time. Its solution is C-ordered, and so is this
    one, since the einsum's sums follow the order."""
    from scipy.special import erf
    from sklearn.gaussian_process._gpc import COEFS, LAMBDAS
    K_star = kernel.cross(X, train_first=True)
    f_star = K_star.T.dot(est.y_train_ - est.pi_)
    v = np.ascontiguousarray(solve_lower(est.L_, est.W_sr_[:, np.newaxis] * K_star))
    var = kernel.diag(X) - np.einsum("ij,ij->j", v, v)
    alpha = 1 / (2 * var)
    gamma = LAMBDAS * f_star
    integrals = (np.sqrt(np.pi / alpha) * erf(gamma * np.sqrt(alpha / (alpha + LAMBDAS ** 2)))
                 / (2 * np.sqrt(var * 2 * np.pi)))
    return (COEFS * integrals).sum(axis=0) + 0.5 * COEFS.sum()


class SmoothKernel:
    """One fitted GP's smooth kernel - ``C * Matern(nu)`` [``+ C_lin * DotProduct``], the kernel
    without its white term - against its training inputs, evaluated by scikit-learn's formulas
    in scikit-learn's order of operations (the same bits as ``kernel_.k1``; tested), without
    its per-call checks and with the training inputs divided by the length scales once: a
    loop's fits ask the emulators ~10^5 times for a handful of points, where those checks were
    a quarter of the time. Another kernel is evaluated by its own object."""

    def __init__(self, kernel, X_train):
        self.kernel, self.X_train = kernel, X_train
        mat, lin = (kernel.k1, kernel.k2) if isinstance(kernel, Sum) else (kernel, None)
        self._fast = (_is_scaled(mat, Matern) and mat.k2.nu in _MATERN
                      and (lin is None or _is_scaled(lin, DotProduct)))
        if not self._fast:
            return
        self.c, self.nu = mat.k1.constant_value, mat.k2.nu
        self.ls = np.squeeze(mat.k2.length_scale).astype(float)
        self.Y = X_train / self.ls
        self.lin = None if lin is None else (lin.k1.constant_value, lin.k2.sigma_0 ** 2)

    def _sum(self, K, X, Y):
        """The linear part added, as scikit-learn's Sum and Product do."""
        if self.lin is None:
            return K
        c, s0sq = self.lin
        return K + np.full(K.shape, c) * (np.inner(X, Y) + s0sq)

    def cross(self, X, train_first=False) -> np.ndarray:
        """k(X, X_train), shape (len(X), n_train); k(X_train, X) with ``train_first``."""
        A, B = (self.X_train, X) if train_first else (X, self.X_train)
        if not self._fast:
            return self.kernel(A, B)
        Xl = X / self.ls
        d = cdist(*((self.Y, Xl) if train_first else (Xl, self.Y)), metric="euclidean")
        return self._sum(np.full(d.shape, self.c) * _MATERN[self.nu](d), A, B)

    def gram(self, X) -> np.ndarray:
        """k(X, X), shape (len(X), len(X))."""
        if not self._fast:
            return self.kernel(X)
        K = squareform(_MATERN[self.nu](pdist(X / self.ls, metric="euclidean")))
        np.fill_diagonal(K, 1)
        return self._sum(np.full(K.shape, self.c) * K, X, X)

    def diag(self, X) -> np.ndarray:
        """The diagonal of k(X, X)."""
        if not self._fast:
            return self.kernel.diag(X)
        K = np.full(len(X), self.c)         # c x the Matern's diagonal of ones
        if self.lin is None:
            return K
        c, s0sq = self.lin
        return K + c * (np.einsum("ij,ij->i", X, X) + s0sq)


def _is_scaled(kernel, kind) -> bool:
    """``kernel`` is ConstantKernel * ``kind``."""
    return (isinstance(kernel, Product) and type(kernel.k1) is ConstantKernel
            and type(kernel.k2) is kind)


def _matern_25(d):
    K = d * math.sqrt(5)
    return (1.0 + K + K ** 2 / 3.0) * np.exp(-K)


def _matern_15(d):
    K = d * math.sqrt(3)
    return (1.0 + K) * np.exp(-K)


#: scikit-learn's Matern as a function of the scaled distance, for the nu it has closed forms of
_MATERN = {0.5: lambda d: np.exp(-d), 1.5: _matern_15, 2.5: _matern_25,
           np.inf: lambda d: np.exp(-(d ** 2) / 2.0)}


#: rows of one call of the kernel in :func:`_block_corr` (its square is the memory it takes)
_BLOCK_CHUNK_ROWS = 512


def _block_corr(smooth, Xs, V, block) -> np.ndarray:
    """(n // block, block, block) correlations of the GP's latent posterior within each block
    of ``block`` consecutive rows: the prior covariance ``smooth`` (the fitted kernel without
    its white term, a :class:`SmoothKernel`) less V^T V (V = L^-1 K(train, X)). A row whose posterior sd is ~0 (a
    training input) is uncorrelated. The kernel is called on chunks of whole blocks, its
    diagonal blocks kept."""
    nb = len(Xs) // block
    out = np.empty((nb, block, block))
    per = max(1, _BLOCK_CHUNK_ROWS // block)
    idx = np.arange(block)
    for b0 in range(0, nb, per):
        k = min(per, nb - b0)
        rows = slice(b0 * block, (b0 + k) * block)
        K = smooth.gram(Xs[rows]).reshape(k, block, k, block)[np.arange(k), :, np.arange(k), :]
        Vb = V[:, rows].reshape(len(V), k, block)
        c = K - np.einsum("tki,tkj->kij", Vb, Vb)
        d = np.sqrt(np.maximum(c[:, idx, idx], 0.0))
        ok = d > 1e-12 * np.maximum(d.max(axis=1, keepdims=True), 1e-300)
        both = ok[:, :, None] & ok[:, None, :]
        with np.errstate(invalid="ignore", divide="ignore"):
            r = np.where(both, np.clip(c / (d[:, :, None] * d[:, None, :]), -1, 1), 0.0)
        r[:, idx, idx] = 1.0
        out[b0:b0 + k] = r
    return out


def mix_modes(parts, probs, block=None) -> Prediction:
    """The mixture over motion modes of one output's per-mode predictions.

    parts : list of Prediction, one per mode, each of shape (n, 1) (with ``latent_corr`` in
        blocks of ``block`` rows when given); probs : (n, n_modes) - p(mode | x)

    A new run at x is in mode k with probability p_k: its mean is sum p_k m_k, and the
    uncertainty about the twin's value there is each mode's emulator uncertainty weighted by
    p_k plus the spread between the modes' means, sum p_k (m_k - m)^2 - counted as the
    emulator's (latent) uncertainty: it is what the data's one realisation may differ by,
    and what more runs about x shrink by sharpening p. Each mode's chaos is weighted by p_k.
    Between two rows of a block (one point's conditions) the modes are taken independent and
    each mode's emulator errors correlated as its GP says: sum_k p_ik p_jk C_k(i, j).
    """
    P = np.asarray(probs, float)
    if len(parts) != P.shape[1]:
        raise ValueError("mix_modes: %d predictions for %d modes" % (len(parts), P.shape[1]))
    M = np.stack([q.mean[:, 0] for q in parts], axis=1)           # (n, K)
    mean = np.sum(P * M, axis=1)
    dev = np.sqrt(P) * (M - mean[:, None])
    within = np.sum(P * np.stack([q.latent_sd[:, 0] ** 2 for q in parts], axis=1), axis=1)
    lat = np.sqrt(within + np.sum(dev ** 2, axis=1))
    chaos = np.sqrt(np.sum(P * np.stack([q.chaos_sd[:, 0] ** 2 for q in parts], axis=1),
                           axis=1))
    corr = None
    if block is not None and all(q.latent_corr is not None for q in parts):
        n_b = len(mean) // block
        corr = np.empty((n_b, 1, block, block))
        for b in range(n_b):
            r = slice(b * block, (b + 1) * block)
            c = sum(np.outer(P[r, k], P[r, k]) * q.latent_corr[b, 0]
                    * np.outer(q.latent_sd[r, 0], q.latent_sd[r, 0])
                    for k, q in enumerate(parts))
            sd = lat[r]
            ok = sd > 1e-300
            cc = np.eye(block)
            cc[np.ix_(ok, ok)] = np.clip(c[np.ix_(ok, ok)] / np.outer(sd[ok], sd[ok]), -1, 1)
            np.fill_diagonal(cc, 1.0)
            corr[b, 0] = cc
    return Prediction(mean[:, None], lat[:, None], chaos[:, None], corr, dev[:, None, :])


def _error_table(outputs, y, m, s, noise, is_log):
    err = y - m
    z = err / s
    rows = []
    for j, name in enumerate(outputs):
        rmse = float(np.sqrt(np.mean(err[:, j] ** 2)))
        ref = 1.0 if is_log[j] else float(np.mean(np.abs(y[:, j])))
        rows.append({"output": name, "n": len(y), "rmse": rmse,
                     "rel_rmse_pct": 100.0 * rmse / ref,
                     "max_abs_err": float(np.max(np.abs(err[:, j]))),
                     "noise_sd": float(noise[j]),
                     "coverage95": float(np.mean(np.abs(z[:, j]) <= Z95)),
                     "mean_abs_z": float(np.mean(np.abs(z[:, j]))),
                     "mean_z2": float(np.mean(z[:, j] ** 2))})
    return pd.DataFrame(rows).set_index("output")


def main(argv=None):
    p = argparse.ArgumentParser(prog="python -m analysis.emulator",
                                description="Fit the GP emulator to a sweep table (CSV with "
                                            "input and output columns) and print its "
                                            "leave-one-out error.",
                                epilog="example: python -m analysis.emulator "
                                       "results/twin_tables/twin_table.csv --inputs frequency_hz "
                                       "ball_diameter_m")
    p.add_argument("table", help="CSV of runs (e.g. from python -m analysis.sweep --out)")
    p.add_argument("--inputs", nargs="+", required=True, help="input columns")
    p.add_argument("--outputs", nargs="+", default=["v_mean_m_s", "f_col_hz"],
                   help="output columns (default: %(default)s)")
    p.add_argument("--noise-keys", nargs="+", default=None,
                   help="input columns that set the chaos' noise group (replicates pooled "
                        "per group); default: one learned nugget per output")
    p.add_argument("--trend", action="store_true", help="add the linear regression part")
    p.add_argument("--seed", type=int, default=0,
                   help="random seed of the hyperparameter optimiser's restarts [-] "
                        "(default %(default)s)")
    args = p.parse_args(argv)
    try:
        df = pd.read_csv(args.table)
        for c in args.inputs + args.outputs:
            if c not in df.columns:
                raise ValueError("%s has no column %s" % (args.table, c))
        df = df.dropna(subset=args.outputs)
        bounds = {c: (float(df[c].min()), float(df[c].max())) for c in args.inputs}
        em = GPEmulator(bounds, outputs=args.outputs, random_state=args.seed, trend=args.trend,
                        noise_keys=args.noise_keys)
        em.fit(df, df)
    except (OSError, ValueError) as exc:
        print("analysis.emulator: error: %s" % exc, file=sys.stderr)
        return 2
    print(em.loo_.to_string())
    return 0


if __name__ == "__main__":
    sys.exit(main())
