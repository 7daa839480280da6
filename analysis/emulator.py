"""Gaussian-process emulator of the twin: (parameters, operating conditions) -> outputs.

One scikit-learn ``GaussianProcessRegressor`` per output, kernel
``C * Matern(nu, ARD length scales) + WhiteKernel``, inputs scaled to the unit cube from
declared bounds, outputs normalised. The WhiteKernel's noise level is the twin's own replicate
scatter (DEM runs are chaotic; two seeds give different speeds), learned as a nugget from the
design, so :meth:`GPEmulator.predict` can return the sd of a *new twin run* (latent + nugget) or
of the twin's *mean* response (latent only).

Quality is reported by closed-form leave-one-out (Rasmussen & Williams 2006, Sec. 5.4.2, eq.
5.12, with the fitted hyperparameters held fixed): RMSE, relative RMSE and the coverage of the
95 % predictive interval, and by :meth:`GPEmulator.score` on held-out runs.

References
----------
Rasmussen, C. E. & Williams, C. K. I. (2006). Gaussian Processes for Machine Learning. MIT Press.
Kennedy, M. C. & O'Hagan, A. (2001). Bayesian calibration of computer models. JRSS B 63, 425.
"""
from __future__ import annotations

import argparse
import sys
import warnings

import numpy as np
import pandas as pd
from scipy.linalg import cho_solve
from sklearn.exceptions import ConvergenceWarning
from sklearn.gaussian_process import GaussianProcessRegressor
from sklearn.gaussian_process.kernels import ConstantKernel, Matern, WhiteKernel


class GPEmulator:
    """GP emulator with inputs scaled to the unit cube.

    Parameters
    ----------
    bounds : dict name -> (lower, upper) - input names (their order is the column order of
        array inputs) and ranges used for scaling [their own units]
    outputs : sequence of str - output names, e.g. ("v_mean_m_s", "f_col_hz")
    nu : float - Matern smoothness (1.5 or 2.5)
    n_restarts_optimizer : int - restarts of the hyperparameter optimiser
    random_state : int or None

    Attributes
    ----------
    gps_ : list of fitted GaussianProcessRegressor, one per output
    n_train_ : int - number of training runs
    loo_ : DataFrame - leave-one-out report (see :meth:`loo_report`)
    """

    def __init__(self, bounds, outputs=("v_mean_m_s", "f_col_hz"), nu=2.5,
                 n_restarts_optimizer=2, random_state=None):
        self.bounds = bounds
        self.outputs = outputs
        self.nu = nu
        self.n_restarts_optimizer = n_restarts_optimizer
        self.random_state = random_state

    # ---------------------------------------------------------------------------- helpers
    @property
    def inputs(self):
        return list(self.bounds)

    def _scale(self, X):
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
        lo = np.array([self.bounds[k][0] for k in self.inputs], float)
        hi = np.array([self.bounds[k][1] for k in self.inputs], float)
        if np.any(hi <= lo):
            raise ValueError("emulator bounds must have upper > lower: %s" % self.bounds)
        return (X - lo) / (hi - lo)

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
        return Y

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
        Xs = self._scale(X)
        Y = self._targets(Y)
        if len(Xs) != len(Y):
            raise ValueError("X has %d rows, Y has %d" % (len(Xs), len(Y)))
        if len(Xs) < len(self.inputs) + 2:
            raise ValueError("need at least %d training runs, got %d"
                             % (len(self.inputs) + 2, len(Xs)))
        d = Xs.shape[1]
        self.gps_ = []
        for j in range(Y.shape[1]):
            kernel = (ConstantKernel(1.0, (1e-3, 1e3))
                      * Matern(length_scale=np.full(d, 0.5), length_scale_bounds=(1e-2, 1e2),
                               nu=self.nu)
                      + WhiteKernel(1e-2, (1e-8, 1.0)))
            gp = GaussianProcessRegressor(kernel=kernel, normalize_y=True,
                                          n_restarts_optimizer=self.n_restarts_optimizer,
                                          random_state=self.random_state)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", ConvergenceWarning)
                gp.fit(Xs, Y[:, j])
            self.gps_.append(gp)
        self.n_train_ = len(Xs)
        self.loo_ = self.loo_report()
        return self

    # ---------------------------------------------------------------------------- predict
    def noise_sd(self):
        """Fitted nugget sd per output (the twin's replicate scatter) [output units]."""
        return np.array([np.sqrt(gp.kernel_.k2.noise_level) * gp._y_train_std
                         for gp in self.gps_])

    def predict(self, X, return_std=False, include_noise=True):
        """Emulated outputs.

        Parameters
        ----------
        X : DataFrame or ndarray, shape (n, n_inputs)
        return_std : bool
        include_noise : bool - True: sd of one new twin run (latent + replicate nugget);
            False: sd of the twin's mean response (latent only)

        Returns
        -------
        mean : ndarray, shape (n, n_outputs)
        std : ndarray, shape (n, n_outputs) - only with return_std
        """
        Xs = self._scale(X)
        mean = np.empty((len(Xs), len(self.gps_)))
        std = np.empty_like(mean)
        for j, gp in enumerate(self.gps_):
            if return_std:
                m, s = gp.predict(Xs, return_std=True)
                if not include_noise:
                    s = np.sqrt(np.maximum(s ** 2 - self.noise_sd()[j] ** 2, 0.0))
                std[:, j] = s
            else:
                m = gp.predict(Xs)
            mean[:, j] = m
        return (mean, std) if return_std else mean

    # ------------------------------------------------------------------------- validation
    def loo_predictions(self):
        """Closed-form leave-one-out mean and sd at the training runs.

        Returns
        -------
        y : ndarray, shape (n, n_outputs) - training outputs
        mean, std : ndarray, shape (n, n_outputs) - LOO predictive mean and sd (of a new run)
        """
        ys, ms, ss = [], [], []
        for gp in self.gps_:
            n = len(gp.alpha_)
            kinv = cho_solve((gp.L_, True), np.eye(n))
            dinv = np.diag(kinv)
            yn = gp.y_train_
            resid = gp.alpha_ / dinv                 # y_i - mu_{-i}, normalised units
            sd = np.sqrt(1.0 / dinv)
            scale, shift = gp._y_train_std, gp._y_train_mean
            y = yn * scale + shift
            ys.append(y)
            ms.append(y - resid * scale)
            ss.append(sd * scale)
        return np.column_stack(ys), np.column_stack(ms), np.column_stack(ss)

    def loo_report(self):
        """Leave-one-out error per output.

        Returns
        -------
        DataFrame indexed by output: n, rmse, rel_rmse_pct (RMSE / mean |y|), max_abs_err,
        noise_sd (fitted nugget), coverage95 (fraction of LOO 95 % intervals holding the run),
        mean_abs_z.
        """
        y, m, s = self.loo_predictions()
        return _error_table(self.outputs, y, m, s, self.noise_sd())

    def score(self, X, Y):
        """Held-out error table (same columns as :meth:`loo_report`)."""
        Y = self._targets(Y)
        m, s = self.predict(X, return_std=True)
        return _error_table(self.outputs, Y, m, s, self.noise_sd())


def _error_table(outputs, y, m, s, noise):
    err = y - m
    z = err / s
    rows = []
    for j, name in enumerate(outputs):
        rmse = float(np.sqrt(np.mean(err[:, j] ** 2)))
        rows.append({"output": name, "n": len(y), "rmse": rmse,
                     "rel_rmse_pct": 100.0 * rmse / float(np.mean(np.abs(y[:, j]))),
                     "max_abs_err": float(np.max(np.abs(err[:, j]))),
                     "noise_sd": float(noise[j]),
                     "coverage95": float(np.mean(np.abs(z[:, j]) <= 1.959964)),
                     "mean_abs_z": float(np.mean(np.abs(z[:, j])))})
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
        em = GPEmulator(bounds, outputs=args.outputs, random_state=args.seed)
        em.fit(df, df)
    except (OSError, ValueError) as exc:
        print("analysis.emulator: error: %s" % exc, file=sys.stderr)
        return 2
    print(em.loo_.to_string())
    return 0


if __name__ == "__main__":
    sys.exit(main())
