"""Surrogates of the twin: (frequency, BVR) -> (v_mean, f_col) (paper Section 5, eqs 6-9,
Table 5, Figure 13).

Inputs x = [frequency_hz, bvr] with BVR = ball volume / jar volume (25 mL); outputs
y = [v_mean_m_s, f_col_hz]. Three regressors, all following the scikit-learn estimator contract
(fit(X, Y) returns self, predict(X) -> (n, 2)):

* ``"lr"`` - ordinary linear regression (the paper's preferred model);
* ``"rf"`` - random forest tuned by GridSearchCV (the paper's second model);
* ``"gp"`` - beyond the paper: one Gaussian process per output on standardised inputs
  (:class:`GPSurrogate`), with predictive standard deviations.

The training data is a table of twin outputs (CSV: frequency_hz, ball_diameter_m, bvr,
v_mean_m_s, f_col_hz, optional run_id); rows that repeat a (frequency, ball) point are replicate
runs (other seeds / start positions) and are averaged into one training point
(:func:`average_replicates`, which records n_replicates). :func:`design_27` gives the 27-run design (9 frequencies
20-30 Hz x 3 balls). We use 14.3, 17.5 and 20.6 mm: the paper's 14.3 and 17.5 mm and the
measured 20.6 mm ball in place of the paper's 20 mm, so that the Table 5 validation cases
(10 mm ball RADIUS, i.e. d = 20 mm, at 25 / 27.5 / 30 Hz) are interpolations, not training runs,
and the twin's largest ball can be checked against Table 3.

A :class:`DomainCheck` flags inputs outside the training domain (per-input range and convex
hull); every prediction carries the flag.

CLI::

    python -m analysis.surrogate [--twin-table CSV | --synthetic] [--validation-table CSV]

Without a twin table the CLI trains on the paper's Table 3 MEASUREMENTS (8 rows, labelled as
such) - a stand-in until the twin's 27 runs exist.
"""
from __future__ import annotations

import argparse
import json
import sys
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
from sklearn.base import BaseEstimator, RegressorMixin
from sklearn.ensemble import RandomForestRegressor
from sklearn.exceptions import ConvergenceWarning
from sklearn.gaussian_process import GaussianProcessRegressor
from sklearn.gaussian_process.kernels import RBF, ConstantKernel, WhiteKernel
from sklearn.linear_model import LinearRegression
from sklearn.model_selection import GridSearchCV, KFold, train_test_split
from sklearn.preprocessing import StandardScaler
from threadpoolctl import threadpool_limits

from analysis import config

JAR_VOLUME_M3 = 25e-6
INPUTS = ("frequency_hz", "bvr")
OUTPUTS = ("v_mean_m_s", "f_col_hz")
KINDS = ("lr", "rf", "gp")
DESIGN_FREQUENCIES_HZ = tuple(np.linspace(20.0, 30.0, 9).round(4))
DESIGN_BALL_DIAMETERS_M = (0.0143, 0.0175, 0.0206)
#: paper Table 5 validation cases: ball RADIUS 10 mm (d = 20 mm) at 25, 27.5, 30 Hz
VALIDATION_CASES = ((25.0, 0.020), (27.5, 0.020), (30.0, 0.020))
DEFAULT_RF_GRID = {"n_estimators": [100, 300], "max_depth": [None, 4],
                   "min_samples_leaf": [1, 2, 4]}
TABLE3_LABEL = "paper Table 3 MEASUREMENTS used as a stand-in for twin outputs (8 rows)"
SYNTHETIC_LABEL = "SYNTHETIC smooth truth (analysis.surrogate.synthetic_truth) + noise"


class SurrogateInputError(ValueError):
    """Bad surrogate input (names file, row and column where known)."""


# --------------------------------------------------------------------------------------------
# inputs, design and tables
# --------------------------------------------------------------------------------------------
def ball_volume_m3(ball_diameter_m):
    """Sphere volume pi d^3 / 6 [m3]."""
    d = np.asarray(ball_diameter_m, dtype=float)
    if np.any(~np.isfinite(d)) or np.any(d <= 0):
        raise SurrogateInputError(f"ball_diameter_m must be finite and > 0, got {ball_diameter_m!r}")
    return np.pi / 6.0 * d ** 3


def bvr(ball_diameter_m, jar_volume_m3: float = JAR_VOLUME_M3):
    """Ball-to-reactor volume ratio (one ball) [-]."""
    if not (np.isfinite(jar_volume_m3) and jar_volume_m3 > 0):
        raise SurrogateInputError(f"jar_volume_m3 must be > 0, got {jar_volume_m3!r}")
    vol = ball_volume_m3(ball_diameter_m)
    out = vol / jar_volume_m3
    if np.any(out >= 1):
        i = int(np.flatnonzero(np.atleast_1d(out) >= 1)[0])
        raise SurrogateInputError(
            "ball volume (%.3g mL for a %.4g mm ball) exceeds the jar volume (%.3g mL)"
            % (np.atleast_1d(vol)[i] * 1e6, np.atleast_1d(ball_diameter_m)[i] * 1e3,
               jar_volume_m3 * 1e6))
    return out


def design_27(frequencies_hz=DESIGN_FREQUENCIES_HZ, ball_diameters_m=DESIGN_BALL_DIAMETERS_M):
    """The surrogate's training design: list of (frequency_hz, ball_diameter_m), 9 x 3 = 27.

    Frequencies 20, 21.25, ..., 30 Hz (9 equally spaced); balls 14.3, 17.5, 20.6 mm.
    """
    return [(float(f), float(d)) for d in ball_diameters_m for f in frequencies_hz]


def synthetic_truth(frequency_hz, ball_diameter_m):
    """A smooth, known map (f, d) -> (v_mean, f_col) near the paper's Table 3, for tests/demos.

    v = 2.13 (f/25)^0.88 (d/20.6 mm)^-0.335 [m/s] (exponents from Table 3's 25/30 Hz and
    17.5/20.6 mm values); f_col = 2 f - 0.02 (f - 25)^2 - 20 (d - 17.5 mm)... in Hz, i.e. close
    to the measured 2 f with a mild curvature. NOT physics; SYNTHETIC.

    Returns
    -------
    v_mean_m_s, f_col_hz : ndarray, shape broadcast(f, d)
    """
    f = np.asarray(frequency_hz, dtype=float)
    d = np.asarray(ball_diameter_m, dtype=float)
    v = 2.13 * (f / 25.0) ** 0.88 * (d / 0.0206) ** -0.335
    fcol = 2.0 * f - 0.02 * (f - 25.0) ** 2 - 20.0 * (d - 0.0175)
    return v, fcol


def synthetic_twin_table(design=None, v_rel_sd: float = 0.01, f_col_sd_hz: float = 0.3,
                         n_replicates: int = 1, jar_volume_m3: float = JAR_VOLUME_M3,
                         truth=synthetic_truth, seed=0) -> pd.DataFrame:
    """Twin-output table drawn from a known function plus Gaussian noise (SYNTHETIC).

    Parameters
    ----------
    design : list of (frequency_hz, ball_diameter_m), default :func:`design_27`
    v_rel_sd : float - relative sd of v_mean noise [-]
    f_col_sd_hz : float - sd of f_col noise [Hz]
    truth : callable (f, d) -> (v, f_col)

    Returns
    -------
    DataFrame, shape (len(design) * n_replicates, 7): run_id, frequency_hz, ball_diameter_m,
    bvr, v_mean_m_s, f_col_hz, source
    """
    design = design_27() if design is None else design
    rng = np.random.default_rng(seed)
    f = np.repeat([p[0] for p in design], n_replicates).astype(float)
    d = np.repeat([p[1] for p in design], n_replicates).astype(float)
    v, fc = truth(f, d)
    v = v * (1.0 + rng.normal(0.0, v_rel_sd, v.shape))
    fc = fc + rng.normal(0.0, f_col_sd_hz, fc.shape)
    return pd.DataFrame({"run_id": [f"synthetic-{i:03d}" for i in range(f.size)],
                         "frequency_hz": f, "ball_diameter_m": d, "bvr": bvr(d, jar_volume_m3),
                         "v_mean_m_s": v, "f_col_hz": fc, "source": SYNTHETIC_LABEL})


def table3_twin_table(jar_volume_m3: float = JAR_VOLUME_M3) -> pd.DataFrame:
    """Paper Table 3 measurements in the twin-table format (a stand-in, labelled)."""
    cond = pd.read_csv(config.PAPER_TABLE3_DIR / "conditions.csv")
    summ = pd.read_csv(config.PAPER_TABLE3_DIR / "summary.csv")
    t = cond.merge(summ, on="condition_id")
    d = t["ball_diameter_mm"].to_numpy(float) * 1e-3
    return pd.DataFrame({"run_id": t["condition_id"], "frequency_hz": t["frequency_hz"].astype(float),
                         "ball_diameter_m": d, "bvr": bvr(d, jar_volume_m3),
                         "v_mean_m_s": t["v_mean_m_s"].astype(float),
                         "f_col_hz": t["f_col_hz"].astype(float), "source": TABLE3_LABEL})


def validate_twin_table(df: pd.DataFrame, source: str = "twin table",
                        jar_volume_m3: float = JAR_VOLUME_M3) -> pd.DataFrame:
    """Check a twin-output table; adds bvr from the diameter when the column is absent.

    Raises
    ------
    SurrogateInputError naming source, row (file line, header = 1) and column.
    """
    df = df.copy()
    for col in ("frequency_hz", "ball_diameter_m", "v_mean_m_s", "f_col_hz"):
        if col not in df.columns:
            raise SurrogateInputError(f"{source}: missing column '{col}'")
    cols = ["frequency_hz", "ball_diameter_m", "v_mean_m_s", "f_col_hz"] + \
        (["bvr"] if "bvr" in df.columns else [])
    for col in cols:
        vals = pd.to_numeric(df[col], errors="coerce").to_numpy(float)
        bad = np.flatnonzero(~np.isfinite(vals))
        if bad.size:
            raise SurrogateInputError(f"{source}: row {bad[0] + 2}, column '{col}': missing or "
                                      "not a number")
        neg = np.flatnonzero(vals <= 0) if col != "v_mean_m_s" else np.flatnonzero(vals < 0)
        if neg.size:
            raise SurrogateInputError(f"{source}: row {neg[0] + 2}, column '{col}': must be "
                                      f"{'>= 0' if col == 'v_mean_m_s' else '> 0'}, got {vals[neg[0]]}")
        df[col] = vals
    if "bvr" not in df.columns:
        df["bvr"] = bvr(df["ball_diameter_m"].to_numpy(), jar_volume_m3)
    if len(df) < 3:
        raise SurrogateInputError(f"{source}: need >= 3 runs, got {len(df)}")
    return df


def load_twin_table(path, jar_volume_m3: float = JAR_VOLUME_M3) -> pd.DataFrame:
    """Read and validate a twin-output CSV (see :func:`validate_twin_table`)."""
    path = Path(path)
    if not path.is_file():
        raise SurrogateInputError(f"{path}: file not found")
    try:
        df = pd.read_csv(path)
    except Exception as exc:
        raise SurrogateInputError(f"{path}: cannot parse CSV ({exc})") from exc
    df = validate_twin_table(df, str(path), jar_volume_m3)
    if "source" not in df.columns:
        df["source"] = f"twin outputs ({path.name})"
    return df


def average_replicates(df: pd.DataFrame) -> pd.DataFrame:
    """One row per design point: the mean of its replicate runs (seeds / start positions).

    Rows with the same (frequency_hz, ball_diameter_m) are replicates (keys rounded to 1e-6 Hz and
    1e-7 m). The twin is chaotic - one run's v_mean scatters by ~1 % between start positions - so
    the surrogates are trained and split on design points, never on single runs (a 70/30 split
    over runs would put replicates of a test point into the training set). Points keep the order
    of their first run, so a table with one run per point is returned unchanged apart from the
    added columns.

    Parameters
    ----------
    df : DataFrame - frequency_hz, ball_diameter_m, v_mean_m_s, f_col_hz [, bvr, e_kin_j,
        run_id, motion_mode, source, ...]; already averaged rows carry n_replicates

    Returns
    -------
    DataFrame, one row per point: the input columns (numeric ones averaged, run_id and
    motion_mode joined with '/', others taken from the first run) plus n_replicates,
    v_mean_sd_m_s and f_col_sd_hz (sample sd over the replicates; NaN for a single run).
    A table that is already one row per point keeps its n_replicates and sd columns.

    Raises
    ------
    SurrogateInputError if a point repeats in a table that is already averaged (n_replicates).
    """
    for col in ("frequency_hz", "ball_diameter_m", "v_mean_m_s", "f_col_hz"):
        if col not in df.columns:
            raise SurrogateInputError(f"average_replicates: missing column '{col}'")
    keys = pd.DataFrame({"f_key": pd.to_numeric(df["frequency_hz"]).round(6).to_numpy(),
                         "d_key": pd.to_numeric(df["ball_diameter_m"]).round(7).to_numpy()})
    point = keys.groupby(["f_key", "d_key"], sort=False).ngroup().to_numpy()
    n_points = int(point.max()) + 1 if len(point) else 0
    if n_points == len(df):           # one row per point: nothing to average
        out = df.copy().reset_index(drop=True)
        if "n_replicates" not in out.columns:
            out["n_replicates"] = 1
        for sd in ("v_mean_sd_m_s", "f_col_sd_hz"):
            if sd not in out.columns:
                out[sd] = np.nan
        return out
    if "n_replicates" in df.columns:
        raise SurrogateInputError("average_replicates: the table already has n_replicates (rows "
                                  "are means) but repeats a (frequency_hz, ball_diameter_m) point")
    df = df.reset_index(drop=True)
    g = df.groupby(point, sort=True)  # group labels number the points by first appearance
    out = {}
    for col in df.columns:
        if col in ("run_id", "motion_mode"):
            out[col] = g[col].agg(lambda s: "/".join(map(str, s)) if col == "run_id"
                                  else "/".join(sorted(set(map(str, s)))))
        elif pd.api.types.is_numeric_dtype(df[col]) and col != "seed":
            out[col] = g[col].mean()
        elif col == "seed":
            out[col] = g[col].agg(lambda s: "/".join(map(str, s)))
        else:
            out[col] = g[col].first()
    out = pd.DataFrame(out)
    out["n_replicates"] = g.size()
    out["v_mean_sd_m_s"] = g["v_mean_m_s"].std()
    out["f_col_sd_hz"] = g["f_col_hz"].std()
    return out.reset_index(drop=True)


def features(df: pd.DataFrame) -> np.ndarray:
    """X, shape (n, 2): [frequency_hz, bvr]."""
    return df[list(INPUTS)].to_numpy(float)


def targets(df: pd.DataFrame) -> np.ndarray:
    """Y, shape (n, 2): [v_mean_m_s, f_col_hz]."""
    return df[list(OUTPUTS)].to_numpy(float)


# --------------------------------------------------------------------------------------------
# estimators
# --------------------------------------------------------------------------------------------
#: Smallest tolerance of :class:`DomainCheck`, as a fraction of each input's range. Twin tables
#: store their inputs as CSV with 6 significant digits (a BVR of 0.18308817 is read back as
#: 0.183088), so a training point recomputed from its ball diameter may sit just beyond the
#: stored extreme; 1e-5 of the range (1e-4 Hz in frequency, ~1e-6 in BVR) absorbs that.
DOMAIN_MIN_REL_TOL = 1e-5


class DomainCheck(BaseEstimator):
    """Training-domain check: per-input range (with relative tolerance) and convex hull.

    Parameters
    ----------
    rel_tol : float - tolerance on each input range, as a fraction of the range (never below
        :data:`DOMAIN_MIN_REL_TOL`, also for bundles saved with a smaller one)

    Attributes
    ----------
    min_, max_ : ndarray, shape (d,) - training input bounds
    hull_ : scipy.spatial.Delaunay or None (None when the points span no full-dimensional hull)
    """

    def __init__(self, rel_tol: float = 1e-6):
        self.rel_tol = rel_tol

    def fit(self, X, y=None):
        from scipy.spatial import Delaunay, QhullError

        X = np.asarray(X, dtype=float)
        self.min_, self.max_ = X.min(axis=0), X.max(axis=0)
        span = np.where(self.max_ > self.min_, self.max_ - self.min_, 1.0)
        self.scale_ = span
        try:
            self.hull_ = Delaunay((X - self.min_) / span)
        except (QhullError, ValueError):
            self.hull_ = None
        return self

    def input_in_range(self, X):
        """Per row and input: inside that input's training range (with the tolerance)?

        Returns
        -------
        ndarray of bool, shape (n, d)
        """
        X = np.atleast_2d(np.asarray(X, dtype=float))
        tol = max(self.rel_tol, DOMAIN_MIN_REL_TOL) * self.scale_
        return (X >= self.min_ - tol) & (X <= self.max_ + tol)

    def check(self, X):
        """numpy core of :meth:`flags`: (in_range, in_hull), boolean arrays of shape (n,)."""
        X = np.atleast_2d(np.asarray(X, dtype=float))
        in_range = np.all(self.input_in_range(X), axis=1)
        if self.hull_ is not None:
            Z = (X - self.min_) / self.scale_
            in_hull = self.hull_.find_simplex(Z, tol=max(self.rel_tol, DOMAIN_MIN_REL_TOL)) >= 0
        else:
            in_hull = in_range
        return in_range, in_hull

    def flags(self, X) -> pd.DataFrame:
        """Per row: in_range, in_hull, out_of_domain (bool columns), shape (n, 3)."""
        in_range, in_hull = self.check(X)
        return pd.DataFrame({"in_range": in_range, "in_hull": in_hull,
                             "out_of_domain": ~(in_range & in_hull)})


class GPSurrogate(RegressorMixin, BaseEstimator):
    """One Gaussian process per output on standardised inputs, with predictive sd.

    Kernel: Constant * RBF (one length scale per input) + White noise; ``normalize_y``.

    Parameters
    ----------
    n_restarts_optimizer : int
    random_state : int or None

    Attributes
    ----------
    scaler_ : StandardScaler
    gps_ : list of GaussianProcessRegressor, one per output
    """

    def __init__(self, n_restarts_optimizer: int = 3, random_state=None):
        self.n_restarts_optimizer = n_restarts_optimizer
        self.random_state = random_state

    def fit(self, X, Y):
        X = np.asarray(X, dtype=float)
        Y = np.asarray(Y, dtype=float)
        Y2 = Y.reshape(len(Y), -1)
        self.scaler_ = StandardScaler().fit(X)
        Z = self.scaler_.transform(X)
        self.gps_ = []
        for j in range(Y2.shape[1]):
            kernel = (ConstantKernel(1.0, (1e-2, 1e2))
                      * RBF(np.ones(X.shape[1]), (1e-1, 1e3))
                      + WhiteKernel(1e-2, (1e-6, 1e0)))
            gp = GaussianProcessRegressor(kernel=kernel, normalize_y=True,
                                          n_restarts_optimizer=self.n_restarts_optimizer,
                                          random_state=self.random_state)
            # hyperparameters at a bound (e.g. an input the output does not depend on -> long
            # length scale; noise-free outputs such as f_col = 2 f) are expected here
            # one BLAS thread: these matrices are tiny and threading overhead dominates (5x)
            with warnings.catch_warnings(), threadpool_limits(1):
                warnings.simplefilter("ignore", ConvergenceWarning)
                self.gps_.append(gp.fit(Z, Y2[:, j]))
        self._1d = Y.ndim == 1
        return self

    def predict(self, X, return_std: bool = False):
        """Mean, shape (n, n_outputs); with return_std also the sd (same shape)."""
        Z = self.scaler_.transform(np.atleast_2d(np.asarray(X, dtype=float)))
        res = [gp.predict(Z, return_std=True) for gp in self.gps_]
        mu = np.column_stack([r[0] for r in res])
        sd = np.column_stack([r[1] for r in res])
        if self._1d:
            mu, sd = mu[:, 0], sd[:, 0]
        return (mu, sd) if return_std else mu


def make_surrogate(kind: str, random_state=0, rf_param_grid: dict | None = None, cv: int = 3):
    """An unfitted surrogate estimator of the given kind ('lr', 'rf' or 'gp')."""
    if kind == "lr":
        return LinearRegression()
    if kind == "rf":
        grid = DEFAULT_RF_GRID if rf_param_grid is None else rf_param_grid
        return GridSearchCV(RandomForestRegressor(random_state=random_state), grid,
                            cv=KFold(cv, shuffle=True, random_state=random_state),
                            scoring="neg_mean_squared_error")
    if kind == "gp":
        return GPSurrogate(random_state=random_state)
    raise SurrogateInputError(f"unknown surrogate kind {kind!r} (use one of {KINDS})")


# --------------------------------------------------------------------------------------------
# training and evaluation
# --------------------------------------------------------------------------------------------
def error_metrics(Y_true, Y_pred) -> pd.DataFrame:
    """Per output: r2, mape_pct, max_ape_pct, rmse. Rows indexed by OUTPUTS."""
    from sklearn.metrics import r2_score

    Y_true = np.asarray(Y_true, float).reshape(-1, len(OUTPUTS))
    Y_pred = np.asarray(Y_pred, float).reshape(-1, len(OUTPUTS))
    ape = 100 * np.abs(Y_pred - Y_true) / np.abs(Y_true)
    rows = []
    for j, name in enumerate(OUTPUTS):
        r2 = r2_score(Y_true[:, j], Y_pred[:, j]) if len(Y_true) > 1 else np.nan
        rows.append(dict(output=name, r2=r2, mape_pct=ape[:, j].mean(), max_ape_pct=ape[:, j].max(),
                         rmse=float(np.sqrt(np.mean((Y_pred[:, j] - Y_true[:, j]) ** 2)))))
    return pd.DataFrame(rows).set_index("output")


@dataclass
class SurrogateFitResult:
    """One surrogate trained on a 70/30 split.

    Attributes
    ----------
    kind : str
    model : fitted estimator (trained on the training split)
    params : dict - best hyperparameters (RF grid search) or learned kernel / coefficients
    metrics : DataFrame - (split, output) -> r2, mape_pct, max_ape_pct, rmse
    predictions : DataFrame - run rows with split, inputs, true and predicted outputs
    residuals : ndarray, shape (n, 2) - predicted - true
    """

    kind: str
    model: object
    params: dict
    metrics: pd.DataFrame
    predictions: pd.DataFrame
    residuals: np.ndarray

    @property
    def stderr(self) -> pd.Series:
        """RMSE on the test split per output (the surrogate's error scale)."""
        return self.metrics.xs("test")["rmse"]

    def to_frame(self) -> pd.DataFrame:
        df = self.metrics.reset_index()
        df.insert(0, "kind", self.kind)
        return df


def _model_params(kind, model) -> dict:
    if kind == "lr":
        return {"intercept": np.atleast_1d(model.intercept_).tolist(), "coef": model.coef_.tolist()}
    if kind == "rf":
        return dict(model.best_params_)
    return {f"kernel_{o}": str(gp.kernel_) for o, gp in zip(OUTPUTS, model.gps_)}


def train_surrogates(table: pd.DataFrame, kinds=KINDS, test_size: float = 0.3, random_state=0,
                     rf_param_grid: dict | None = None) -> dict:
    """Fit each surrogate kind on a (1 - test_size)/test_size split of the twin table.

    Replicate runs are averaged first (:func:`average_replicates`): the split, seeded by
    ``random_state`` (sklearn ``train_test_split``), is over design points.

    Returns
    -------
    dict kind -> SurrogateFitResult
    """
    table = average_replicates(validate_twin_table(table))
    X, Y = features(table), targets(table)
    idx = np.arange(len(table))
    tr, te = train_test_split(idx, test_size=test_size, random_state=random_state)
    out = {}
    for kind in kinds:
        model = make_surrogate(kind, random_state, rf_param_grid).fit(X[tr], Y[tr])
        P = model.predict(X)
        split = np.where(np.isin(idx, tr), "train", "test")
        pred = table[["frequency_hz", "ball_diameter_m", "bvr", "n_replicates"]].copy()
        pred["split"] = split
        for j, o in enumerate(OUTPUTS):
            pred[o] = Y[:, j]
            pred[o + "_pred"] = P[:, j]
        met = pd.concat({"train": error_metrics(Y[tr], P[tr]), "test": error_metrics(Y[te], P[te])},
                        names=["split"])
        out[kind] = SurrogateFitResult(kind=kind, model=model, params=_model_params(kind, model),
                                       metrics=met, predictions=pred, residuals=P - Y)
    return out


def validation_errors(models: dict, validation: pd.DataFrame) -> pd.DataFrame:
    """Paper Table 5: % error of each surrogate at validation cases with known twin outputs.

    Parameters
    ----------
    models : dict kind -> fitted estimator (or SurrogateFitResult)
    validation : DataFrame - frequency_hz, ball_diameter_m, bvr, v_mean_m_s, f_col_hz

    Returns
    -------
    DataFrame, one row per case: case, frequency_hz, ball_radius_mm, (n_replicates when the
    validation table has it), and v_err_<kind>_pct, fcol_err_<kind>_pct (absolute % errors)
    """
    X, Y = features(validation), targets(validation)
    out = pd.DataFrame({"case": np.arange(1, len(validation) + 1),
                        "frequency_hz": validation["frequency_hz"].to_numpy(),
                        "ball_radius_mm": validation["ball_diameter_m"].to_numpy() * 500.0})
    if "n_replicates" in validation.columns:
        out["n_replicates"] = validation["n_replicates"].to_numpy()
    for kind, m in models.items():
        m = getattr(m, "model", m)
        P = np.asarray(m.predict(X)).reshape(-1, 2)
        err = 100 * np.abs(P - Y) / np.abs(Y)
        out[f"v_err_{kind}_pct"] = err[:, 0]
        out[f"fcol_err_{kind}_pct"] = err[:, 1]
    return out


def learning_curve(table: pd.DataFrame, kinds=("lr", "gp"), train_sizes=None, n_repeats: int = 5,
                   test_size: float = 0.3, random_state=0, rf_param_grid=None,
                   truth=None) -> pd.DataFrame:
    """Test error vs number of training runs.

    A fixed test split (test_size) is held out; for each size n, ``n_repeats`` random subsets
    of n training runs are drawn (seeded) and each surrogate is refit. With ``truth`` (callable
    (f, d) -> (v, f_col)) errors are measured against the noise-free truth at the test inputs.
    Replicates are averaged first: n_train counts design points.

    Returns
    -------
    DataFrame: kind, n_train, repeat, output, mape_pct, max_ape_pct, rmse
    """
    table = average_replicates(validate_twin_table(table))
    X, Y = features(table), targets(table)
    idx = np.arange(len(table))
    tr, te = train_test_split(idx, test_size=test_size, random_state=random_state)
    Yte = Y[te] if truth is None else np.column_stack(
        truth(table["frequency_hz"].to_numpy()[te], table["ball_diameter_m"].to_numpy()[te]))
    if train_sizes is None:
        train_sizes = sorted({int(s) for s in np.linspace(4, len(tr), 5)})
    rng = np.random.default_rng(random_state)
    rows = []
    for n in train_sizes:
        if n > len(tr) or n < 3:
            raise SurrogateInputError(f"train size {n} outside [3, {len(tr)}]")
        for r in range(n_repeats):
            sub = rng.choice(tr, size=n, replace=False)
            for kind in kinds:
                m = make_surrogate(kind, int(rng.integers(1 << 31)), rf_param_grid,
                                   cv=min(3, n)).fit(X[sub], Y[sub])
                met = error_metrics(Yte, m.predict(X[te]))
                for o in OUTPUTS:
                    rows.append(dict(kind=kind, n_train=n, repeat=r, output=o,
                                     mape_pct=met.loc[o, "mape_pct"],
                                     max_ape_pct=met.loc[o, "max_ape_pct"], rmse=met.loc[o, "rmse"]))
    return pd.DataFrame(rows)


# --------------------------------------------------------------------------------------------
# the deployable bundle (used by analysis.predict)
# --------------------------------------------------------------------------------------------
@dataclass
class SurrogateBundle:
    """Surrogates refit on all runs of a twin table + its domain check.

    Attributes
    ----------
    models : dict kind -> fitted estimator
    domain : DomainCheck - fitted on the training inputs [frequency_hz, bvr]
    jar_volume_m3 : float - jar volume the BVRs refer to
    source : str - what the training table was (twin / Table 3 stand-in / SYNTHETIC)
    n_runs : int - twin runs behind the training points (sum of n_replicates)
    """

    models: dict
    domain: DomainCheck
    jar_volume_m3: float
    source: str
    n_runs: int
    extra: dict = field(default_factory=dict)

    def predict(self, frequency_hz, ball_diameter_m, jar_volume_m3: float | None = None,
                kind: str = "lr") -> pd.DataFrame:
        """Surrogate outputs with the domain flag.

        Parameters
        ----------
        frequency_hz, ball_diameter_m : float or ndarray, shape (n,)
        jar_volume_m3 : float - defaults to the training jar volume

        Returns
        -------
        DataFrame, shape (n, ...): frequency_hz, ball_diameter_m, bvr, v_mean_m_s, f_col_hz,
        (v_mean_sd_m_s, f_col_sd_hz for 'gp'), in_range, in_hull, out_of_domain
        """
        out = self.predict_arrays(frequency_hz, ball_diameter_m, jar_volume_m3, kind)
        return pd.DataFrame(out)

    def predict_arrays(self, frequency_hz, ball_diameter_m, jar_volume_m3: float | None = None,
                       kind: str = "lr") -> dict:
        """numpy core of :meth:`predict`: dict of arrays, each shape (n,)."""
        if kind not in self.models:
            raise SurrogateInputError(f"surrogate kind {kind!r} not in bundle ({list(self.models)})")
        f = np.atleast_1d(np.asarray(frequency_hz, dtype=float))
        if np.any(~np.isfinite(f)) or np.any(f <= 0):
            raise SurrogateInputError(f"frequency_hz must be finite and > 0, got {frequency_hz!r}")
        d = np.broadcast_to(np.asarray(ball_diameter_m, dtype=float), f.shape)
        b = bvr(d, self.jar_volume_m3 if jar_volume_m3 is None else jar_volume_m3)
        X = np.column_stack([f, b])
        m = self.models[kind]
        out = {"frequency_hz": f, "ball_diameter_m": d, "bvr": b}
        if kind == "gp":
            mu, sd = m.predict(X, return_std=True)
            out.update(v_mean_m_s=mu[:, 0], f_col_hz=mu[:, 1], v_mean_sd_m_s=sd[:, 0],
                       f_col_sd_hz=sd[:, 1])
        else:
            mu = m.predict(X)
            out.update(v_mean_m_s=mu[:, 0], f_col_hz=mu[:, 1])
        in_range, in_hull = self.domain.check(X)
        out.update(in_range=in_range, in_hull=in_hull, out_of_domain=~(in_range & in_hull))
        return out

    def save(self, path: Path) -> Path:
        import joblib

        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(path.suffix + ".tmp")
        joblib.dump(self, tmp)
        tmp.replace(path)
        return path

    @classmethod
    def load(cls, path: Path) -> "SurrogateBundle":
        import joblib

        path = Path(path)
        if not path.is_file():
            raise SurrogateInputError(f"{path}: no trained surrogate (run python -m analysis.surrogate)")
        try:
            obj = joblib.load(path)
        except Exception as exc:
            raise SurrogateInputError(f"{path}: cannot load surrogate bundle ({exc}); retrain with "
                                      "python -m analysis.surrogate") from exc
        if not isinstance(obj, cls):
            raise SurrogateInputError(f"{path}: not a SurrogateBundle")
        return obj


def fit_bundle(table: pd.DataFrame, kinds=KINDS, random_state=0, rf_param_grid=None,
               jar_volume_m3: float = JAR_VOLUME_M3, source: str | None = None) -> SurrogateBundle:
    """Refit every surrogate kind on all points of the table (replicates averaged) and fit the
    domain check."""
    table = average_replicates(validate_twin_table(table, jar_volume_m3=jar_volume_m3))
    X, Y = features(table), targets(table)
    models = {k: make_surrogate(k, random_state, rf_param_grid).fit(X, Y) for k in kinds}
    if source is None:
        source = str(table["source"].iloc[0]) if "source" in table.columns else "twin table"
    return SurrogateBundle(models=models, domain=DomainCheck().fit(X), jar_volume_m3=jar_volume_m3,
                           source=source, n_runs=int(table["n_replicates"].sum()),
                           extra={"n_points": len(table),
                                  **{k: _model_params(k, m) for k, m in models.items()}})


# --------------------------------------------------------------------------------------------
# CLI
# --------------------------------------------------------------------------------------------
def _parser():
    p = argparse.ArgumentParser(prog="python -m analysis.surrogate",
                                description="Train (f, BVR) -> (v_mean, f_col) surrogates (paper Sec. 5).",
                                epilog="example: python -m analysis.surrogate --twin-table "
                                       "results/twin_tables/twin_table.csv --validation-table "
                                       "results/twin_tables/validation_table.csv")
    src = p.add_mutually_exclusive_group()
    src.add_argument("--twin-table", type=Path, help="CSV of twin outputs (frequency_hz, "
                     "ball_diameter_m, bvr, v_mean_m_s, f_col_hz[, run_id])")
    src.add_argument("--synthetic", action="store_true",
                     help="train on a SYNTHETIC table from synthetic_truth on design_27()")
    p.add_argument("--validation-table", type=Path, default=None,
                   help="CSV of twin outputs at validation cases (Table 5: d = 20 mm)")
    p.add_argument("--kinds", nargs="+", default=list(KINDS), choices=KINDS,
                   help="surrogate kinds to train (default: all)")
    p.add_argument("--seed", type=int, default=0,
                   help="random seed of the fits, subsets and the synthetic table [-] "
                        "(default %(default)s)")
    p.add_argument("--lc-repeats", type=int, default=5,
                   help="random training subsets per size in the learning curve [subsets] "
                        "(0: skip it)")
    p.add_argument("--jar-volume-ml", type=float, default=25.0,
                   help="jar volume [mL] (BVR = ball volume / jar volume; default %(default)s)")
    p.add_argument("--out", type=Path, default=config.SURROGATE_DIR,
                   help="output folder (default: results/surrogate)")
    return p


def _inputs(args):
    """The files ``run`` reads: never an output."""
    return [args.twin_table, args.validation_table]


def run(args) -> Path:
    from analysis.atomic_dir import check_out_dir, output_dir
    from analysis.plotting.surrogate_plots import write_surrogate_figures

    protected = _inputs(args)
    check_out_dir(args.out, protected)
    jar = args.jar_volume_ml * 1e-6
    truth = None
    if args.twin_table is not None:
        table = load_twin_table(args.twin_table, jar)
    elif args.synthetic:
        table = synthetic_twin_table(seed=args.seed, jar_volume_m3=jar)
        truth = synthetic_truth
    else:
        table = table3_twin_table(jar)
    table = average_replicates(table)   # one row per design point (mean of its runs)
    source = str(table["source"].iloc[0])
    if args.validation_table is not None:
        val = average_replicates(load_twin_table(args.validation_table, jar))
    elif truth is not None:
        f = np.array([c[0] for c in VALIDATION_CASES])
        d = np.array([c[1] for c in VALIDATION_CASES])
        v, fc = truth(f, d)
        val = pd.DataFrame({"frequency_hz": f, "ball_diameter_m": d, "bvr": bvr(d, jar),
                            "v_mean_m_s": v, "f_col_hz": fc})
    else:
        val = None
    results = train_surrogates(table, kinds=args.kinds, random_state=args.seed)
    bundle = fit_bundle(table, kinds=args.kinds, random_state=args.seed, jar_volume_m3=jar,
                        source=source)
    lc = None
    if len(table) >= 10 and args.lc_repeats > 0:
        lc = learning_curve(table, kinds=[k for k in args.kinds if k != "rf"] or args.kinds,
                            n_repeats=args.lc_repeats, random_state=args.seed, truth=truth)

    with output_dir(args.out, protected) as tmp:
        pd.concat([r.to_frame() for r in results.values()]).to_csv(tmp / "metrics.csv", index=False)
        pd.concat([r.predictions.assign(kind=k) for k, r in results.items()]).to_csv(
            tmp / "predictions.csv", index=False)
        table.to_csv(tmp / "training_table.csv", index=False)
        if val is not None:
            validation_errors({k: r.model for k, r in results.items()}, val).to_csv(
                tmp / "validation_errors.csv", index=False)
        if lc is not None:
            lc.to_csv(tmp / "learning_curve.csv", index=False)
        (tmp / "source.json").write_text(json.dumps(
            {"source": source, "n_points": len(table), "n_runs": int(table["n_replicates"].sum()),
             "n_replicates_per_point": sorted({int(n) for n in table["n_replicates"]}),
             "split": "70/30 over design points, sklearn train_test_split(random_state=seed)",
             "kinds": args.kinds, "seed": args.seed,
             "jar_volume_m3": jar, "params": {k: r.params for k, r in results.items()},
             "bundle_params": bundle.extra}, indent=1, default=str))
        if "lr" in bundle.models:
            lr = bundle.models["lr"]
            (tmp / "surrogate_lr.json").write_text(json.dumps(
                {"inputs": INPUTS, "outputs": OUTPUTS, "intercept": lr.intercept_.tolist(),
                 "coef": lr.coef_.tolist(), "jar_volume_m3": jar, "source": source,
                 "domain_min": bundle.domain.min_.tolist(), "domain_max": bundle.domain.max_.tolist()},
                indent=1))
        bundle.save(tmp / "surrogate.joblib")
        write_surrogate_figures(tmp, {k: r.predictions for k, r in results.items()}, lc,
                                source, outputs=OUTPUTS)
    return args.out


def main(argv=None) -> int:
    from analysis.atomic_dir import check_out_dir
    args = _parser().parse_args(argv)
    try:
        check_out_dir(args.out, _inputs(args))   # before any work
        out = run(args)
    except (SurrogateInputError, ValueError, FileNotFoundError) as exc:  # OutputError: ValueError
        print(f"analysis.surrogate: error: {exc}", file=sys.stderr)
        return 2
    met = pd.read_csv(out / "metrics.csv")
    print(f"source: {json.loads((out / 'source.json').read_text())['source']}")
    print(met[met["split"] == "test"].to_string(index=False, float_format=lambda v: f"{v:.4g}"))
    if (out / "validation_errors.csv").is_file():
        print("validation cases (Table 5 analogue, abs % error):")
        print(pd.read_csv(out / "validation_errors.csv").to_string(index=False,
                                                                    float_format=lambda v: f"{v:.3f}"))
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    # run through the importable module so pickled classes are analysis.surrogate.*, not __main__.*
    from analysis.surrogate import main as _main
    sys.exit(_main())
