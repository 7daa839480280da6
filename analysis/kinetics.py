"""Kinetics: collision energy -> PET depolymerisation yield (paper Section 4, eq 4, Table 4).

The energy descriptor of a run is the cumulative kinetic energy delivered by the ball,

    E_tot(t) = E_kin * f_col * t,     E_kin = 1/2 m v_mean^2,   m = rho * pi d^3 / 6,

and the yield in the powder regime is the straight line X[%] = a * E_tot[kJ] + b (Table 4:
a = 9.49 +- 1.00 %/kJ, b = -3.03 +- 1.70 %). Above a powder-to-wax boundary (4593 J) the yield
rises steeply through a mixed powder/wax regime to complete depolymerisation above 7126 J.

This module holds pure compute functions (energy, the OLS line with its 95 % confidence and
prediction bands, the two regime boundaries found from the data with bootstrap uncertainty, yield
prediction for a new condition) and a CLI::

    python -m analysis.kinetics [--yields DATASET] [--twin-table CSV] [--out DIR]

Until twin outputs exist the energy inputs come from the paper's Table 3 (measured v_mean of
the 17.5 and 20.6 mm balls, linearly interpolated in diameter to the 20 mm ball of the yield
experiments; f_col measured = 2 f). Every output says which source it used.

References
----------
Anglou et al., ACS Sustainable Chem. Eng. 2024, 12, 9003-9017, Section 4, eq 4, Table 4.
"""
from __future__ import annotations

import argparse
import json
import shutil
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
from scipy import stats

from analysis import config

STEEL_DENSITY_KG_M3 = 7800.0
#: ball of the paper's yield experiments (one stainless-steel ball, d = 20 mm)
YIELD_BALL_DIAMETER_MM = 20.0
REGIMES = ("powder", "wax", "complete")
#: paper Table 4 values (the published fit; used as truth for synthetic data and for labels)
PAPER_SLOPE_PCT_PER_KJ = 9.49
PAPER_INTERCEPT_PCT = -3.03
PAPER_POWDER_WAX_J = 4593.0
PAPER_WAX_COMPLETE_J = 7126.0

TABLE3_SOURCE_INTERP = ("paper Table 3 measured v_mean (17.5 and 20.6 mm balls) linearly "
                        "interpolated in ball diameter; f_col measured (= 2 f); NOT twin output")
TABLE3_SOURCE_AS_IS = ("paper Table 3 measured v_mean of the 20.6 mm ball used as is for the "
                       "requested ball; f_col measured (= 2 f); NOT twin output")


class KineticsInputError(ValueError):
    """Bad input to the kinetics stage (names the file/row/column where known)."""


# --------------------------------------------------------------------------------------------
# energy
# --------------------------------------------------------------------------------------------
def ball_mass_kg(ball_diameter_m, density_kg_m3: float = STEEL_DENSITY_KG_M3):
    """Mass of a solid sphere.

    Parameters
    ----------
    ball_diameter_m : float or ndarray, shape (n,) - ball diameter [m], > 0
    density_kg_m3 : float - material density [kg/m3] (steel 7800)

    Returns
    -------
    float or ndarray, shape (n,) - mass [kg]
    """
    d = np.asarray(ball_diameter_m, dtype=float)
    if np.any(~np.isfinite(d)) or np.any(d <= 0):
        raise KineticsInputError(f"ball_diameter_m must be finite and > 0, got {ball_diameter_m!r}")
    if not density_kg_m3 > 0:
        raise KineticsInputError(f"density_kg_m3 must be > 0, got {density_kg_m3!r}")
    return density_kg_m3 * np.pi / 6.0 * d ** 3


def kinetic_energy_j(ball_diameter_m, v_mean_m_s, density_kg_m3: float = STEEL_DENSITY_KG_M3):
    """Mean kinetic energy E_kin = 1/2 m v_mean^2 [J] (translational, as in the paper)."""
    v = np.asarray(v_mean_m_s, dtype=float)
    if np.any(~np.isfinite(v)) or np.any(v < 0):
        raise KineticsInputError(f"v_mean_m_s must be finite and >= 0, got {v_mean_m_s!r}")
    return 0.5 * ball_mass_kg(ball_diameter_m, density_kg_m3) * v ** 2


def cumulative_energy_j(e_kin_j, f_col_hz, time_s):
    """Cumulative energy E_tot = E_kin * f_col * t [J].

    Parameters
    ----------
    e_kin_j : float or ndarray - mean kinetic energy per collision [J]
    f_col_hz : float or ndarray - collision frequency [1/s]
    time_s : float or ndarray, shape (n,) - milling time [s], >= 0
    """
    e = np.asarray(e_kin_j, dtype=float)
    f = np.asarray(f_col_hz, dtype=float)
    t = np.asarray(time_s, dtype=float)
    for name, arr in (("e_kin_j", e), ("f_col_hz", f), ("time_s", t)):
        if np.any(~np.isfinite(arr)) or np.any(arr < 0):
            raise KineticsInputError(f"{name} must be finite and >= 0")
    return e * f * t


def _energy_frame(df: pd.DataFrame, density_kg_m3: float) -> pd.DataFrame:
    df = df.copy()
    df["e_kin_j"] = kinetic_energy_j(df["ball_diameter_m"].to_numpy(),
                                     df["v_mean_m_s"].to_numpy(), density_kg_m3)
    df["power_w"] = df["e_kin_j"] * df["f_col_hz"]
    return df


def table3_energy_inputs(ball_diameters_mm=(17.5, YIELD_BALL_DIAMETER_MM, 20.6),
                         assumption: str = "interp", table3_dir: Path | None = None,
                         density_kg_m3: float = STEEL_DENSITY_KG_M3) -> pd.DataFrame:
    """Energy inputs from the paper's Table 3 measurements (the stand-in for twin outputs).

    Parameters
    ----------
    ball_diameters_mm : sequence of float - balls to tabulate [mm]
    assumption : {"interp", "as_is"}
        "interp": v_mean linearly interpolated (or extrapolated) in diameter between the two
        measured balls (17.5, 20.6 mm) at each measured frequency. "as_is": the 20.6 mm ball's
        v_mean used for every requested diameter.
    table3_dir : Path, optional - dataset folder (default config.PAPER_TABLE3_DIR)

    Returns
    -------
    DataFrame, one row per (frequency, diameter): frequency_hz, ball_diameter_m, v_mean_m_s,
    f_col_hz, e_kin_j, power_w, measured (bool), source
    """
    if assumption not in ("interp", "as_is"):
        raise KineticsInputError(f"assumption must be 'interp' or 'as_is', got {assumption!r}")
    folder = Path(table3_dir) if table3_dir is not None else config.PAPER_TABLE3_DIR
    cond = pd.read_csv(folder / "conditions.csv")
    summ = pd.read_csv(folder / "summary.csv")
    t3 = cond.merge(summ, on="condition_id")
    rows = []
    for f_hz, grp in t3.groupby("frequency_hz"):
        grp = grp.sort_values("ball_diameter_mm")
        d_meas = grp["ball_diameter_mm"].to_numpy(float)
        v_meas = grp["v_mean_m_s"].to_numpy(float)
        fcol = float(grp["f_col_hz"].mean())
        for d_mm in ball_diameters_mm:
            measured = bool(np.any(np.isclose(d_meas, d_mm)))
            if measured:
                v = float(v_meas[np.isclose(d_meas, d_mm)][0])
                src = "paper Table 3 measured (NOT twin output)"
            elif assumption == "interp":
                slope = (v_meas[-1] - v_meas[0]) / (d_meas[-1] - d_meas[0])
                v = float(v_meas[0] + slope * (d_mm - d_meas[0]))
                src = TABLE3_SOURCE_INTERP
            else:
                v = float(v_meas[-1])
                src = TABLE3_SOURCE_AS_IS
            rows.append(dict(frequency_hz=float(f_hz), ball_diameter_m=d_mm * 1e-3,
                             v_mean_m_s=v, f_col_hz=fcol, measured=measured, source=src))
    return _energy_frame(pd.DataFrame(rows), density_kg_m3)


def load_twin_energy_table(path: Path, density_kg_m3: float = STEEL_DENSITY_KG_M3) -> pd.DataFrame:
    """Read a CSV of twin outputs and average replicate rows per (frequency, ball diameter).

    Parameters
    ----------
    path : Path - CSV with columns frequency_hz, ball_diameter_m, v_mean_m_s, f_col_hz
        (further columns are ignored)

    Returns
    -------
    DataFrame: frequency_hz, ball_diameter_m, v_mean_m_s, v_mean_sd_m_s, f_col_hz, n_runs,
    e_kin_j, power_w, measured (False), source
    """
    path = Path(path)
    if not path.is_file():
        raise KineticsInputError(f"{path}: twin table not found")
    try:
        df = pd.read_csv(path)
    except Exception as exc:  # malformed CSV
        raise KineticsInputError(f"{path}: cannot read CSV ({exc})") from exc
    need = ["frequency_hz", "ball_diameter_m", "v_mean_m_s", "f_col_hz"]
    for col in need:
        if col not in df.columns:
            raise KineticsInputError(f"{path}: missing column '{col}'")
    for col in need:
        vals = pd.to_numeric(df[col], errors="coerce")
        bad = np.flatnonzero(~np.isfinite(vals.to_numpy(float)))
        if bad.size:
            raise KineticsInputError(f"{path}: row {bad[0] + 2}, column '{col}': not a number")
        if col != "v_mean_m_s" and np.any(vals <= 0):
            row = int(np.flatnonzero(vals.to_numpy() <= 0)[0]) + 2
            raise KineticsInputError(f"{path}: row {row}, column '{col}': must be > 0")
        df[col] = vals.astype(float)
    if np.any(df["v_mean_m_s"] < 0):
        row = int(np.flatnonzero(df["v_mean_m_s"].to_numpy() < 0)[0]) + 2
        raise KineticsInputError(f"{path}: row {row}, column 'v_mean_m_s': must be >= 0")
    df["f_key"] = df["frequency_hz"].round(6)
    df["d_key"] = df["ball_diameter_m"].round(7)
    g = df.groupby(["f_key", "d_key"], sort=True)
    out = g.agg(frequency_hz=("frequency_hz", "mean"), ball_diameter_m=("ball_diameter_m", "mean"),
                v_mean_m_s=("v_mean_m_s", "mean"), v_mean_sd_m_s=("v_mean_m_s", "std"),
                f_col_hz=("f_col_hz", "mean"), n_runs=("v_mean_m_s", "size")).reset_index(drop=True)
    out["measured"] = False
    out["source"] = f"twin outputs ({path.name})"
    return _energy_frame(out, density_kg_m3)


def energy_for_conditions(conditions: pd.DataFrame, inputs: pd.DataFrame) -> pd.DataFrame:
    """Attach e_kin_j, f_col_hz, power_w and source to each yield condition.

    Parameters
    ----------
    conditions : DataFrame - condition_id, frequency_hz, ball_diameter_mm
    inputs : DataFrame - from :func:`table3_energy_inputs` or :func:`load_twin_energy_table`, or
        any table with frequency_hz, ball_diameter_m, v_mean_m_s, f_col_hz (e_kin_j and power_w
        are computed when absent)

    Raises
    ------
    KineticsInputError if a condition has no matching (frequency, diameter) row.
    """
    inputs = inputs.copy()
    if "e_kin_j" not in inputs.columns:
        inputs["e_kin_j"] = kinetic_energy_j(inputs["ball_diameter_m"].to_numpy(),
                                             inputs["v_mean_m_s"].to_numpy())
    inputs["power_w"] = inputs["e_kin_j"] * inputs["f_col_hz"]
    if "source" not in inputs.columns:
        inputs["source"] = "energy inputs (unlabelled)"
    rows = []
    for _, c in conditions.iterrows():
        m = inputs[np.isclose(inputs["frequency_hz"], c["frequency_hz"], atol=1e-6)
                   & np.isclose(inputs["ball_diameter_m"], c["ball_diameter_mm"] * 1e-3, atol=1e-6)]
        if m.empty:
            raise KineticsInputError(
                f"condition '{c['condition_id']}' ({c['frequency_hz']} Hz, "
                f"{c['ball_diameter_mm']} mm): no energy input (twin output) for it")
        r = m.iloc[0]
        rows.append(dict(condition_id=c["condition_id"], frequency_hz=float(c["frequency_hz"]),
                         ball_diameter_mm=float(c["ball_diameter_mm"]), v_mean_m_s=r["v_mean_m_s"],
                         e_kin_j=r["e_kin_j"], f_col_hz=r["f_col_hz"], power_w=r["power_w"],
                         source=r["source"]))
    return pd.DataFrame(rows)


def attach_cumulative_energy(yields: pd.DataFrame, energy: pd.DataFrame) -> pd.DataFrame:
    """yields (condition_id, time_min, yield_pct, ...) + energy per condition -> adds e_tot_j."""
    out = yields.merge(energy[["condition_id", "frequency_hz", "e_kin_j", "f_col_hz", "power_w"]],
                       on="condition_id", how="left", validate="many_to_one")
    if out["power_w"].isna().any():
        missing = sorted(out.loc[out["power_w"].isna(), "condition_id"].unique())
        raise KineticsInputError(f"no energy input for condition(s) {missing}")
    out["e_tot_j"] = cumulative_energy_j(out["e_kin_j"], out["f_col_hz"], out["time_min"] * 60.0)
    return out


# --------------------------------------------------------------------------------------------
# powder-regime line (OLS with bands)
# --------------------------------------------------------------------------------------------
_T_CACHE: dict = {}


def _t_quantile(q: float, df: int) -> float:
    key = (q, df)
    if key not in _T_CACHE:
        _T_CACHE[key] = float(stats.t.ppf(q, df))
    return _T_CACHE[key]

@dataclass
class LineFitResult:
    """OLS fit of X[%] = a * E_tot[kJ] + b.

    Attributes
    ----------
    params : Series - a_pct_per_kj, b_pct
    stderr : Series - standard errors, same index
    cov : ndarray, shape (2, 2) - parameter covariance (order b, a)
    sigma_pct : float - residual standard deviation [%]
    df_resid : int
    r2 : float
    residuals : ndarray, shape (n,) [%]
    e_tot_kj, yield_pct : ndarray, shape (n,) - the fitted points
    """

    params: pd.Series
    stderr: pd.Series
    cov: np.ndarray
    sigma_pct: float
    df_resid: int
    r2: float
    residuals: np.ndarray
    e_tot_kj: np.ndarray
    yield_pct: np.ndarray

    @property
    def n(self) -> int:
        return int(self.e_tot_kj.size)

    def conf_int(self, alpha: float = 0.05) -> pd.DataFrame:
        """(1 - alpha) confidence intervals of a and b (t distribution)."""
        t = stats.t.ppf(1 - alpha / 2, self.df_resid)
        return pd.DataFrame({"lower": self.params - t * self.stderr,
                             "upper": self.params + t * self.stderr})

    def bands(self, e_tot_j, alpha: float = 0.05):
        """numpy core of :meth:`predict`: (mean, ci_lo, ci_hi, pi_lo, pi_hi), each shape (m,)."""
        e_kj = np.atleast_1d(np.asarray(e_tot_j, dtype=float)) / 1e3
        b, a = self.params["b_pct"], self.params["a_pct_per_kj"]
        c = self.cov
        mean = b + a * e_kj
        se_mean = np.sqrt(c[0, 0] + 2 * c[0, 1] * e_kj + c[1, 1] * e_kj ** 2)
        se_pred = np.sqrt(se_mean ** 2 + self.sigma_pct ** 2)
        t = _t_quantile(1 - alpha / 2, self.df_resid)
        return (mean, mean - t * se_mean, mean + t * se_mean, mean - t * se_pred,
                mean + t * se_pred)

    def predict(self, e_tot_j, alpha: float = 0.05) -> pd.DataFrame:
        """Line value with its (1-alpha) confidence band (of the line) and prediction band
        (of a new observation).

        Parameters
        ----------
        e_tot_j : ndarray, shape (m,) - cumulative energy [J]

        Returns
        -------
        DataFrame, shape (m, 6): e_tot_j, yield_pct, ci_lo, ci_hi, pi_lo, pi_hi [%]
        """
        e = np.atleast_1d(np.asarray(e_tot_j, dtype=float))
        m, cl, ch, pl, ph = self.bands(e, alpha)
        return pd.DataFrame({"e_tot_j": e, "yield_pct": m, "ci_lo": cl, "ci_hi": ch,
                             "pi_lo": pl, "pi_hi": ph})

    def to_frame(self, alpha: float = 0.05) -> pd.DataFrame:
        ci = self.conf_int(alpha)
        t = stats.t.ppf(1 - alpha / 2, self.df_resid)
        return pd.DataFrame({"param": self.params.index, "value": self.params.to_numpy(),
                             "stderr": self.stderr.to_numpy(),
                             "ci95_halfwidth": t * self.stderr.to_numpy(),
                             "ci_lo": ci["lower"].to_numpy(), "ci_hi": ci["upper"].to_numpy(),
                             "r2": self.r2, "sigma_pct": self.sigma_pct, "n": self.n,
                             "df_resid": self.df_resid})

    def to_dict(self) -> dict:
        return {"params": self.params.to_dict(), "stderr": self.stderr.to_dict(),
                "cov": self.cov.tolist(), "sigma_pct": self.sigma_pct,
                "df_resid": self.df_resid, "r2": self.r2,
                "e_tot_kj": self.e_tot_kj.tolist(), "yield_pct": self.yield_pct.tolist(),
                "residuals": self.residuals.tolist()}

    @classmethod
    def from_dict(cls, d: dict) -> "LineFitResult":
        return cls(params=pd.Series(d["params"]), stderr=pd.Series(d["stderr"]),
                   cov=np.asarray(d["cov"], float), sigma_pct=float(d["sigma_pct"]),
                   df_resid=int(d["df_resid"]), r2=float(d["r2"]),
                   residuals=np.asarray(d["residuals"], float),
                   e_tot_kj=np.asarray(d["e_tot_kj"], float),
                   yield_pct=np.asarray(d["yield_pct"], float))


def fit_powder_line(e_tot_j, yield_pct) -> LineFitResult:
    """OLS (statsmodels) of yield on cumulative energy in kJ.

    Parameters
    ----------
    e_tot_j : ndarray, shape (n,) - cumulative energy [J], n >= 3
    yield_pct : ndarray, shape (n,) - yield [%]
    """
    import statsmodels.api as sm

    e = np.asarray(e_tot_j, dtype=float)
    x = np.asarray(yield_pct, dtype=float)
    if e.shape != x.shape or e.ndim != 1:
        raise KineticsInputError("e_tot_j and yield_pct must be 1-d arrays of equal length")
    if e.size < 3:
        raise KineticsInputError(f"need >= 3 powder-regime points for the line, got {e.size}")
    if not (np.all(np.isfinite(e)) and np.all(np.isfinite(x))):
        raise KineticsInputError("e_tot_j and yield_pct must be finite")
    if np.ptp(e) <= 0:
        raise KineticsInputError("all powder points have the same energy; slope undefined")
    X = np.column_stack([np.ones_like(e), e / 1e3])
    res = sm.OLS(x, X).fit()
    idx = ["b_pct", "a_pct_per_kj"]
    params = pd.Series(res.params, index=idx)[["a_pct_per_kj", "b_pct"]]
    stderr = pd.Series(res.bse, index=idx)[["a_pct_per_kj", "b_pct"]]
    return LineFitResult(params=params, stderr=stderr, cov=np.asarray(res.cov_params()),
                         sigma_pct=float(np.sqrt(res.scale)), df_resid=int(res.df_resid),
                         r2=float(res.rsquared), residuals=np.asarray(res.resid),
                         e_tot_kj=e / 1e3, yield_pct=x)


# --------------------------------------------------------------------------------------------
# regime boundaries
# --------------------------------------------------------------------------------------------
@dataclass
class BoundaryResult:
    """Powder/wax and wax/complete boundaries in cumulative energy [J].

    Attributes
    ----------
    method : str - "candidates" (paper: breakpoints between data, least squares of a piecewise
        model), "continuous" (continuous 3-segment hinge, profile least squares on a fine grid)
        or "phase" (from recorded phase labels)
    params : Series - powder_wax_j, wax_complete_j (and for the LS methods the segment
        coefficients)
    ci : DataFrame - index powder_wax_j, wax_complete_j; columns lower, upper [J]
        (bootstrap percentile interval for LS methods, label gap or logistic for "phase")
    boot : ndarray, shape (n_boot, 2) - bootstrap replicates (empty for "phase")
    sse : float - residual sum of squares of the piecewise model (nan for "phase")
    residuals : ndarray, shape (n,) - residuals of the piecewise model [%] (empty for "phase")
    """

    method: str
    params: pd.Series
    ci: pd.DataFrame
    boot: np.ndarray = field(default_factory=lambda: np.empty((0, 2)))
    sse: float = float("nan")
    residuals: np.ndarray = field(default_factory=lambda: np.empty(0))

    @property
    def powder_wax_j(self) -> float:
        return float(self.params["powder_wax_j"])

    @property
    def wax_complete_j(self) -> float:
        return float(self.params["wax_complete_j"])

    @property
    def stderr(self) -> pd.Series:
        if self.boot.shape[0] > 1:
            return pd.Series(self.boot.std(axis=0, ddof=1), index=["powder_wax_j", "wax_complete_j"])
        return pd.Series([np.nan, np.nan], index=["powder_wax_j", "wax_complete_j"])

    def to_frame(self) -> pd.DataFrame:
        se = self.stderr
        rows = []
        for name in ("powder_wax_j", "wax_complete_j"):
            rows.append(dict(method=self.method, boundary=name, value_j=float(self.params[name]),
                             stderr_j=float(se[name]), ci_lo_j=float(self.ci.loc[name, "lower"]),
                             ci_hi_j=float(self.ci.loc[name, "upper"]), n_boot=self.boot.shape[0],
                             sse=self.sse))
        return pd.DataFrame(rows)

    def to_dict(self) -> dict:
        return {"method": self.method, "params": {k: float(v) for k, v in self.params.items()},
                "ci": {k: [float(self.ci.loc[k, "lower"]), float(self.ci.loc[k, "upper"])]
                       for k in self.ci.index},
                "stderr": {k: float(v) for k, v in self.stderr.items()}, "sse": self.sse,
                "boot": self.boot.tolist()}

    @classmethod
    def from_dict(cls, d: dict) -> "BoundaryResult":
        ci = pd.DataFrame({k: {"lower": v[0], "upper": v[1]} for k, v in d["ci"].items()}).T
        boot = np.asarray(d.get("boot", []), dtype=float).reshape(-1, 2)
        return cls(method=d["method"], params=pd.Series(d["params"]), ci=ci, boot=boot,
                   sse=float(d["sse"]))


def _seg_sums(e, x):
    """Prefix sums for O(1) OLS sums of squares of contiguous (sorted) segments."""
    z = np.zeros(1)
    return {k: np.concatenate([z, np.cumsum(v)]) for k, v in
            (("n", np.ones_like(e)), ("e", e), ("x", x), ("ee", e * e), ("ex", e * x),
             ("xx", x * x))}


def _sse_line(S, i, j):
    """SSE of an OLS line through sorted points i..j-1 (vectorised over i, j arrays)."""
    n = S["n"][j] - S["n"][i]
    se, sx = S["e"][j] - S["e"][i], S["x"][j] - S["x"][i]
    see, sex, sxx = S["ee"][j] - S["ee"][i], S["ex"][j] - S["ex"][i], S["xx"][j] - S["xx"][i]
    with np.errstate(invalid="ignore", divide="ignore"):
        cee = see - se * se / n
        cex = sex - se * sx / n
        cxx = sxx - sx * sx / n
        out = cxx - np.where(cee > 1e-12, cex * cex / cee, 0.0)
    return np.maximum(out, 0.0)


def _sse_const(S, i, j):
    n = S["n"][j] - S["n"][i]
    sx, sxx = S["x"][j] - S["x"][i], S["xx"][j] - S["xx"][i]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.maximum(sxx - sx * sx / n, 0.0)


def _boundaries_candidates(e, x, min_points=(3, 3, 2)):
    """Paper's method: breakpoints at the gaps between sorted energies; powder line, wax line,
    complete constant; the pair with the least total SSE wins. Returns (E1, E2, sse, i, j)."""
    order = np.argsort(e, kind="stable")
    e, x = e[order], x[order]
    n = e.size
    S = _seg_sums(e, x)
    gaps = np.flatnonzero(np.diff(e) > 0) + 1        # split index k: points [0,k) | [k, n)
    I, J = np.meshgrid(gaps, gaps, indexing="ij")
    ok = (I >= min_points[0]) & (J - I >= min_points[1]) & (n - J >= min_points[2])
    if not ok.any():
        raise KineticsInputError("too few distinct energies to place two regime boundaries "
                                 f"(need >= {sum(min_points)} points)")
    I, J = I[ok], J[ok]
    sse = _sse_line(S, np.zeros_like(I), I) + _sse_line(S, I, J) + _sse_const(S, J, np.full_like(J, n))
    k = int(np.nanargmin(sse))
    i, j = int(I[k]), int(J[k])
    return 0.5 * (e[i - 1] + e[i]), 0.5 * (e[j - 1] + e[j]), float(sse[k]), (e[i - 1], e[i]), (e[j - 1], e[j])


def _hinge_basis(e, e1, e2):
    """Design of the continuous 3-segment model, batched: e (n,), e1/e2 (G,) -> (G, n, 3)."""
    e = e[None, :]
    e1 = np.asarray(e1)[:, None]
    e2 = np.asarray(e2)[:, None]
    return np.stack([np.ones(np.broadcast_shapes(e.shape, e1.shape)),
                     np.minimum(e, e1), np.clip(e - e1, 0.0, e2 - e1)], axis=-1)


def _hinge_sse(e, x, e1, e2):
    B = _hinge_basis(e, e1, e2)
    BtB = np.einsum("gni,gnj->gij", B, B) + 1e-9 * np.eye(3)
    Btx = np.einsum("gni,n->gi", B, x)
    coef = np.linalg.solve(BtB, Btx[..., None])[..., 0]
    r = x[None, :] - np.einsum("gni,gi->gn", B, coef)
    return (r * r).sum(axis=1), coef


def _boundaries_continuous(e, x, min_points=(3, 2, 2), n_grid=60, n_refine=4):
    """Continuous hinge: X = b + a*min(E,E1) + s*clip(E-E1, 0, E2-E1); profile LS over (E1, E2)."""
    es = np.sort(e)
    n = es.size
    if n < sum(min_points):
        raise KineticsInputError(f"need >= {sum(min_points)} points to place two boundaries, got {n}")
    lo, hi = es[min_points[0] - 1], es[n - min_points[2]]
    if not hi > lo:
        raise KineticsInputError("energies do not spread enough to place two boundaries")
    g1 = np.linspace(lo, hi, n_grid)
    span = hi - lo
    best = None
    for level in range(n_refine + 1):
        E1, E2 = np.meshgrid(g1, g1 if level == 0 else g2, indexing="ij")
        E1, E2 = E1.ravel(), E2.ravel()
        n_below = np.searchsorted(es, E1, side="right")
        n_mid = np.searchsorted(es, E2, side="right") - n_below
        n_above = n - np.searchsorted(es, E2, side="right")
        ok = (E2 > E1) & (n_below >= min_points[0]) & (n_mid >= min_points[1]) & (n_above >= min_points[2])
        if not ok.any():
            if best is None:
                raise KineticsInputError("no admissible pair of boundaries for these energies")
            break
        sse, coef = _hinge_sse(e, x, E1[ok], E2[ok])
        k = int(np.argmin(sse))
        cand = (float(sse[k]), float(E1[ok][k]), float(E2[ok][k]), coef[k])
        if best is None or cand[0] <= best[0]:
            best = cand
        step = span / (n_grid - 1) / (4 ** level)
        g1 = np.linspace(best[1] - 2 * step, best[1] + 2 * step, 17)
        g2 = np.linspace(best[2] - 2 * step, best[2] + 2 * step, 17)
    sse, e1, e2, coef = best
    return e1, e2, sse, coef


def find_boundaries(e_tot_j, yield_pct, method: str = "continuous", n_boot: int = 200,
                    alpha: float = 0.05, random_state=0) -> BoundaryResult:
    """Regime boundaries from yield data by least squares of a piecewise model.

    Parameters
    ----------
    e_tot_j : ndarray, shape (n,) - cumulative energy [J]
    yield_pct : ndarray, shape (n,) - yield [%]
    method : {"continuous", "candidates"}
        "candidates" is the paper's method (breakpoints between data points, powder line + wax
        line + complete constant, least total SSE; each boundary reported at the midpoint of its
        gap). "continuous" fits a continuous powder-line / wax-line / plateau model whose two
        knots are profiled on a fine grid, so a boundary can fall between samples.
    n_boot : int - case-resampling bootstrap replicates for the uncertainty (0: none)
    random_state : int or Generator

    Returns
    -------
    BoundaryResult
    """
    e = np.asarray(e_tot_j, dtype=float)
    x = np.asarray(yield_pct, dtype=float)
    if e.shape != x.shape or e.ndim != 1 or not np.all(np.isfinite(e)) or not np.all(np.isfinite(x)):
        raise KineticsInputError("e_tot_j and yield_pct must be finite 1-d arrays of equal length")

    def one(ee, xx):
        if method == "candidates":
            e1, e2, sse, _, _ = _boundaries_candidates(ee, xx)
            return e1, e2, sse, None
        if method == "continuous":
            return _boundaries_continuous(ee, xx)
        raise KineticsInputError(f"unknown boundary method {method!r}")

    e1, e2, sse, coef = one(e, x)
    params = {"powder_wax_j": e1, "wax_complete_j": e2}
    resid = np.empty(0)
    if coef is not None:
        b, a, s = coef
        params.update(b_pct=b, a_pct_per_j=a, wax_slope_pct_per_j=s,
                      complete_level_pct=b + a * e1 + s * (e2 - e1))
        resid = x - _hinge_basis(e, [e1], [e2])[0] @ coef
    rng = np.random.default_rng(random_state)
    boot = []
    for _ in range(int(n_boot)):
        idx = rng.integers(0, e.size, e.size)
        try:
            b1, b2, _, _ = one(e[idx], x[idx])
        except KineticsInputError:
            continue
        boot.append((b1, b2))
    boot = np.asarray(boot, dtype=float).reshape(-1, 2)
    if boot.shape[0] >= 10:
        q = np.quantile(boot, [alpha / 2, 1 - alpha / 2], axis=0)
        ci = pd.DataFrame({"lower": q[0], "upper": q[1]}, index=["powder_wax_j", "wax_complete_j"])
    else:
        ci = pd.DataFrame({"lower": [np.nan] * 2, "upper": [np.nan] * 2},
                          index=["powder_wax_j", "wax_complete_j"])
    return BoundaryResult(method=method, params=pd.Series(params), ci=ci, boot=boot, sse=sse,
                          residuals=resid)


def _label_boundary(e, later):
    """One boundary from binary labels: gap between the last 'before' and first 'after' sample,
    or, where labels overlap, the 50 % point of a logistic fit (delta-method 95 % interval)."""
    before, after = e[~later], e[later]
    if before.size == 0 or after.size == 0:
        return np.nan, np.nan, np.nan
    if before.max() < after.min():
        return 0.5 * (before.max() + after.min()), before.max(), after.min()
    import statsmodels.api as sm
    ek = e / 1e3
    res = sm.Logit(later.astype(float), sm.add_constant(ek)).fit(disp=0)
    b0, b1 = res.params
    e50 = -b0 / b1
    g = np.array([-1.0 / b1, b0 / b1 ** 2])
    se = float(np.sqrt(g @ np.asarray(res.cov_params()) @ g))
    return e50 * 1e3, (e50 - 1.96 * se) * 1e3, (e50 + 1.96 * se) * 1e3


def boundaries_from_phase(e_tot_j, phase) -> BoundaryResult:
    """Boundaries from recorded phase labels ('powder', 'wax', 'complete').

    The interval of each boundary is the gap between the highest-energy sample of the earlier
    phase and the lowest-energy sample of the later one (estimate: its midpoint); where labels
    overlap in energy a logistic regression gives the 50 % point and its 95 % interval.
    """
    e = np.asarray(e_tot_j, dtype=float)
    ph = np.asarray([str(p).strip().lower() for p in phase])
    known = np.isin(ph, REGIMES)
    if known.sum() < 2:
        raise KineticsInputError("phase column has fewer than 2 labelled samples")
    e, ph = e[known], ph[known]
    pw = _label_boundary(e, ph != "powder")
    wc = _label_boundary(e, ph == "complete")
    params = pd.Series({"powder_wax_j": pw[0], "wax_complete_j": wc[0]})
    ci = pd.DataFrame({"lower": [pw[1], wc[1]], "upper": [pw[2], wc[2]]},
                      index=["powder_wax_j", "wax_complete_j"])
    return BoundaryResult(method="phase", params=params, ci=ci)


# --------------------------------------------------------------------------------------------
# whole fit + prediction
# --------------------------------------------------------------------------------------------
@dataclass
class KineticsFit:
    """Powder line + regime boundaries.

    Attributes
    ----------
    line : LineFitResult - powder-regime line
    boundaries : BoundaryResult - primary (least-squares) boundaries used for regimes
    alternatives : list of BoundaryResult - other boundary estimates (paper method, phase labels)
    powder_selection : str - "phase" (points labelled powder) or "boundary" (E < powder_wax_j)
    complete_band_pct : tuple - 2.5 and 97.5 % quantiles of observed complete-regime yields
    source : str - where the data and energy inputs came from (e.g. SYNTHETIC ...)
    """

    line: LineFitResult
    boundaries: BoundaryResult
    alternatives: list
    powder_selection: str
    complete_band_pct: tuple
    source: str = ""

    @property
    def params(self) -> pd.Series:
        return pd.concat([self.line.params, self.boundaries.params[["powder_wax_j", "wax_complete_j"]]])

    @property
    def stderr(self) -> pd.Series:
        return pd.concat([self.line.stderr, self.boundaries.stderr])

    @property
    def residuals(self) -> np.ndarray:
        return self.line.residuals

    def to_frame(self) -> pd.DataFrame:
        line = self.line.to_frame().rename(columns={"param": "name"})
        line["kind"] = "powder_line"
        bnd = pd.concat([b.to_frame() for b in [self.boundaries] + list(self.alternatives)])
        bnd = bnd.rename(columns={"boundary": "name", "value_j": "value", "stderr_j": "stderr",
                                  "ci_lo_j": "ci_lo", "ci_hi_j": "ci_hi"})
        bnd["kind"] = "boundary_" + bnd["method"]
        return pd.concat([line, bnd], ignore_index=True)

    def to_dict(self) -> dict:
        return {"line": self.line.to_dict(), "boundaries": self.boundaries.to_dict(),
                "alternatives": [b.to_dict() for b in self.alternatives],
                "powder_selection": self.powder_selection,
                "complete_band_pct": list(self.complete_band_pct), "source": self.source}

    @classmethod
    def from_dict(cls, d: dict) -> "KineticsFit":
        return cls(line=LineFitResult.from_dict(d["line"]),
                   boundaries=BoundaryResult.from_dict(d["boundaries"]),
                   alternatives=[BoundaryResult.from_dict(b) for b in d["alternatives"]],
                   powder_selection=d["powder_selection"],
                   complete_band_pct=tuple(d["complete_band_pct"]), source=d.get("source", ""))

    def save(self, path: Path) -> None:
        path = Path(path)
        tmp = path.with_suffix(path.suffix + ".tmp")
        tmp.write_text(json.dumps(self.to_dict(), indent=1))
        tmp.replace(path)

    @classmethod
    def load(cls, path: Path) -> "KineticsFit":
        return cls.from_dict(json.loads(Path(path).read_text()))


def fit_kinetics(e_tot_j, yield_pct, phase=None, method: str = "continuous", n_boot: int = 200,
                 primary: str = "auto", random_state=0, source: str = "") -> KineticsFit:
    """Fit the powder line and the two regime boundaries.

    Parameters
    ----------
    e_tot_j, yield_pct : ndarray, shape (n,) - cumulative energy [J] and yield [%]
    phase : array of str, shape (n,), optional - recorded phase per sample; when given the
        powder line uses the samples labelled 'powder' and phase-label boundaries are computed
    method : {"continuous", "candidates"} - least-squares boundary method (the other one is
        computed too; both are kept)
    n_boot : int - bootstrap replicates for the least-squares boundaries
    primary : {"auto", "ls", "phase"} - which boundaries define the regimes used for prediction:
        "auto" = phase labels when present, else least squares
    """
    e = np.asarray(e_tot_j, dtype=float)
    x = np.asarray(yield_pct, dtype=float)
    other = "candidates" if method == "continuous" else "continuous"
    ls = find_boundaries(e, x, method=method, n_boot=n_boot, random_state=random_state)
    ls_other = find_boundaries(e, x, method=other, n_boot=n_boot, random_state=random_state)
    ph = None
    if phase is not None:
        ph = pd.Series(phase).astype("string").str.strip().str.lower().fillna("").to_numpy(str)
        if not np.isin(ph, REGIMES).any():
            ph = None
    if primary not in ("auto", "ls", "phase"):
        raise KineticsInputError(f"primary must be 'auto', 'ls' or 'phase', got {primary!r}")
    if primary == "phase" and ph is None:
        raise KineticsInputError("primary='phase' needs a phase column with labels")
    found = [ls, ls_other]
    if ph is not None:
        found.append(boundaries_from_phase(e, ph))
    use_phase_bnd = ph is not None and primary in ("auto", "phase")
    main_b = found[-1] if use_phase_bnd else ls
    alts = [b for b in found if b is not main_b]
    if ph is not None:
        powder = ph == "powder"
        complete = ph == "complete"
        selection = "phase"
    else:
        powder = e < main_b.powder_wax_j
        complete = e >= main_b.wax_complete_j
        selection = "boundary"
    line = fit_powder_line(e[powder], x[powder])
    band = (tuple(np.quantile(x[complete], [0.025, 0.975]).tolist()) if complete.any()
            else (np.nan, np.nan))
    return KineticsFit(line=line, boundaries=main_b, alternatives=alts,
                       powder_selection=selection, complete_band_pct=band, source=source)


def regime_of(e_tot_j, fit: KineticsFit) -> np.ndarray:
    """Regime name per energy from the fit's primary boundaries, shape (n,)."""
    e = np.atleast_1d(np.asarray(e_tot_j, dtype=float))
    out = np.full(e.shape, "powder", dtype=object)
    out[e >= fit.boundaries.powder_wax_j] = "wax"
    out[e >= fit.boundaries.wax_complete_j] = "complete"
    return out


def predict_yield_from_energy(fit: KineticsFit, e_tot_j, alpha: float = 0.05) -> pd.DataFrame:
    """Yield, band and regime at given cumulative energies.

    Powder: the line with its confidence (ci_*) and prediction (pi_*) bands, clipped to
    [0, 100] % (the negative intercept is the induction period). Wax: a straight ramp from the
    powder line at E1 to the complete plateau at E2, band from the line's lower
    prediction limit at the powder/wax boundary up to 100 % (the paper: 'broadly estimate the
    range of possible conversions'). Complete: the fitted plateau (or 100 %), band = the
    2.5-97.5 % range of observed complete-regime yields. ``regime_uncertain`` is True where the
    energy lies inside a boundary's interval.

    Returns
    -------
    DataFrame, shape (n, 9): e_tot_j, yield_pct, ci_lo, ci_hi, pi_lo, pi_hi, regime,
    regime_uncertain
    """
    e = np.atleast_1d(np.asarray(e_tot_j, dtype=float))
    cols = yield_bands(fit, e, alpha)
    out = pd.DataFrame({"e_tot_j": e, **cols})
    return out


def yield_bands(fit: KineticsFit, e_tot_j, alpha: float = 0.05) -> dict:
    """numpy core of :func:`predict_yield_from_energy`: dict of arrays, each shape (n,)
    (yield_pct, ci_lo, ci_hi, pi_lo, pi_hi, regime, regime_uncertain)."""
    e = np.atleast_1d(np.asarray(e_tot_j, dtype=float))
    mean, ci_lo, ci_hi, pi_lo, pi_hi = fit.line.bands(e, alpha)
    e1, e2 = fit.boundaries.powder_wax_j, fit.boundaries.wax_complete_j
    reg = np.where(e >= e2, "complete", np.where(e >= e1, "wax", "powder")).astype(object)
    wax = reg == "wax"
    comp = reg == "complete"
    if wax.any() or comp.any():
        y1, _, _, low_at_e1, _ = (float(v[0]) for v in fit.line.bands([e1], alpha))
        # wax: straight ramp from the powder line at E1 to the plateau at E2 (the plateau is
        # the continuous least-squares fit's complete level where available, else 100 %)
        plateau = 100.0
        for b in [fit.boundaries] + list(fit.alternatives):
            if "complete_level_pct" in b.params.index:
                plateau = float(min(b.params["complete_level_pct"], 100.0))
                break
        wax_mean = y1 + (plateau - y1) * (e - e1) / (e2 - e1)
        mean = np.where(wax, wax_mean, mean)
        ci_lo = np.where(wax, low_at_e1, ci_lo)
        pi_lo = np.where(wax, low_at_e1, pi_lo)
        ci_hi = np.where(wax, 100.0, ci_hi)
        pi_hi = np.where(wax, 100.0, pi_hi)
        lo_c = fit.complete_band_pct[0] if np.isfinite(fit.complete_band_pct[0]) else plateau
        mean = np.where(comp, plateau, mean)
        ci_lo = np.where(comp, lo_c, ci_lo)
        pi_lo = np.where(comp, lo_c, pi_lo)
        ci_hi = np.where(comp, 100.0, ci_hi)
        pi_hi = np.where(comp, 100.0, pi_hi)
    unc = np.zeros(e.shape, bool)
    ci = fit.boundaries.ci
    for name in ("powder_wax_j", "wax_complete_j"):
        lo, hi = ci.loc[name, "lower"], ci.loc[name, "upper"]
        if np.isfinite(lo) and np.isfinite(hi):
            unc |= (e >= lo) & (e <= hi)
    clip = lambda v: np.clip(v, 0.0, 100.0)  # noqa: E731
    return {"yield_pct": clip(mean), "ci_lo": clip(ci_lo), "ci_hi": clip(ci_hi),
            "pi_lo": clip(pi_lo), "pi_hi": clip(pi_hi), "regime": reg, "regime_uncertain": unc}


def predict_yield(fit: KineticsFit, e_kin_j: float, f_col_hz: float, time_min,
                  alpha: float = 0.05) -> pd.DataFrame:
    """Yield vs time for a condition given its E_kin and f_col (twin outputs or a surrogate).

    Parameters
    ----------
    e_kin_j : float - mean kinetic energy [J]
    f_col_hz : float - collision frequency [1/s]
    time_min : ndarray, shape (m,) - milling times [min], >= 0 and non-decreasing

    Returns
    -------
    DataFrame, shape (m, 9): time_min plus the columns of :func:`predict_yield_from_energy`
    """
    t = np.atleast_1d(np.asarray(time_min, dtype=float))
    if np.any(~np.isfinite(t)):
        raise KineticsInputError("time_min must be finite")
    if np.any(t < 0):
        raise KineticsInputError(f"time_min must be >= 0, got {t[t < 0][0]}")
    if np.any(np.diff(t) < 0):
        raise KineticsInputError("time_min must be in increasing order")
    e_tot = cumulative_energy_j(e_kin_j, f_col_hz, t * 60.0)
    out = predict_yield_from_energy(fit, e_tot, alpha)
    out.insert(0, "time_min", t)
    return out


# --------------------------------------------------------------------------------------------
# CLI
# --------------------------------------------------------------------------------------------
def _build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m analysis.kinetics",
                                description="Fit yield vs cumulative collision energy (paper Sec. 4) "
                                            "and write tables + Figures 9-11 to results/kinetics/.",
                                epilog="example: python -m analysis.kinetics --twin-table "
                                       "results/twin_tables/all_runs.csv --out results/kinetics")
    p.add_argument("--yields", type=Path, default=None,
                   help="measurement dataset folder with yields.csv (default: the SYNTHETIC "
                        "data/measurements/synthetic_yields_paper)")
    p.add_argument("--twin-table", type=Path, default=None,
                   help="CSV of twin outputs (frequency_hz, ball_diameter_m, v_mean_m_s, f_col_hz); "
                        "default: paper Table 3 measurements")
    p.add_argument("--velocity-assumption", choices=["interp", "as_is"], default="interp",
                   help="without --twin-table: how Table 3 (17.5/20.6 mm) speeds map to 20 mm")
    p.add_argument("--method", choices=["continuous", "candidates"], default="continuous",
                   help="regime-boundary search (default %(default)s)")
    p.add_argument("--n-boot", type=int, default=500,
                   help="case-resampling bootstrap replicates of the boundaries [replicates] "
                        "(0: none; default %(default)s)")
    p.add_argument("--seed", type=int, default=0,
                   help="random seed of the bootstrap [-] (default %(default)s)")
    p.add_argument("--out", type=Path, default=config.KINETICS_DIR,
                   help="output folder (default: results/kinetics)")
    return p


def _inputs(args):
    """The files and folders ``run`` reads: never an output."""
    from analysis import yield_dataset
    return [args.yields if args.yields is not None else yield_dataset.SYNTHETIC_DATASET_DIR,
            args.twin_table]


def run(args) -> Path:
    from analysis import yield_dataset
    from analysis.atomic_dir import check_out_dir, publish_dir, staging_dir

    protected = _inputs(args)
    check_out_dir(args.out, protected)
    ds_path = args.yields if args.yields is not None else yield_dataset.SYNTHETIC_DATASET_DIR
    ds = yield_dataset.load_yield_dataset(ds_path)
    if args.twin_table is not None:
        inputs = load_twin_energy_table(args.twin_table)
    else:
        inputs = table3_energy_inputs(assumption=args.velocity_assumption)
    energy = energy_for_conditions(ds.conditions, inputs)
    data = attach_cumulative_energy(ds.yields, energy)
    label = ("SYNTHETIC yields" if ds.synthetic else f"yields: {ds.name}")
    src = f"{label}; energy: {energy['source'].iloc[0]}"
    phase = data["phase"] if "phase" in data.columns else None
    fit = fit_kinetics(data["e_tot_j"], data["yield_pct"], phase=phase, method=args.method,
                       n_boot=args.n_boot, random_state=args.seed, source=src)
    data["regime_fit"] = regime_of(data["e_tot_j"], fit)

    tmp = staging_dir(args.out, protected)  # makes the parent folder too
    try:
        inputs.to_csv(tmp / "energy_inputs.csv", index=False)
        energy.to_csv(tmp / "energy_per_condition.csv", index=False)
        data.to_csv(tmp / "yields_with_energy.csv", index=False)
        fit.line.to_frame().to_csv(tmp / "powder_line.csv", index=False)
        pd.concat([b.to_frame() for b in [fit.boundaries] + fit.alternatives]).to_csv(
            tmp / "boundaries.csv", index=False)
        fit.save(tmp / "kinetics_fit.json")
        _write_figures(tmp, fit, data, inputs, energy, ds.synthetic, src)
        publish_dir(tmp, args.out, protected)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return args.out


def model_curves(fit, data, energy, n=200) -> dict:
    """condition_id -> (time_min, yield_pct) of the fitted model from 0 to 1.05 x the condition's
    last milling time (figure 10's lines)."""
    e = energy.set_index("condition_id")
    out = {}
    for cid, grp in data.groupby("condition_id", sort=False):
        if cid not in e.index:
            continue
        t = np.linspace(0, grp["time_min"].max() * 1.05, n)
        p = predict_yield(fit, e.loc[cid, "e_kin_j"], e.loc[cid, "f_col_hz"], t)
        out[cid] = (t, np.asarray(p["yield_pct"], float))
    return out


def _write_figures(folder, fit, data, inputs, energy, synthetic, src):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from analysis.plotting import kinetics_plots as kp

    tag = "SYNTHETIC yields - " if synthetic else ""
    fig, ax = plt.subplots(figsize=(6, 4.2))
    kp.plot_ekin_map(inputs, ax=ax)
    ax.set_title("E_kin vs frequency and ball size\n(" + inputs["source"].iloc[0][:70] + ")", fontsize=8)
    fig.tight_layout(); fig.savefig(folder / "fig09_ekin.png", dpi=130); plt.close(fig)

    fig, ax = plt.subplots(figsize=(6, 4.2))
    kp.plot_yield_vs_time(data, curves=model_curves(fit, data, energy), ax=ax)
    ax.set_title(tag + "yield vs milling time (20 mm ball)", fontsize=9)
    fig.tight_layout(); fig.savefig(folder / "fig10_yield_time.png", dpi=130); plt.close(fig)

    fig, ax = plt.subplots(figsize=(6.5, 4.5))
    kp.plot_yield_vs_energy(data, fit, ax=ax)
    ax.set_title(tag + "yield vs cumulative energy, powder line with 95 % bands", fontsize=9)
    fig.tight_layout(); fig.savefig(folder / "fig11_yield_energy.png", dpi=130); plt.close(fig)


def main(argv=None) -> int:
    from analysis.atomic_dir import check_out_dir
    args = _build_parser().parse_args(argv)
    try:
        check_out_dir(args.out, _inputs(args))   # before any work
        out = run(args)
    except (KineticsInputError, ValueError, FileNotFoundError) as exc:  # OutputError: ValueError
        print(f"analysis.kinetics: error: {exc}", file=sys.stderr)
        return 2
    fit = KineticsFit.load(out / "kinetics_fit.json")
    p, se = fit.line.params, fit.line.stderr
    print(f"source: {fit.source}")
    print(f"powder line: a = {p['a_pct_per_kj']:.3f} +- {se['a_pct_per_kj']:.3f} %/kJ (se), "
          f"b = {p['b_pct']:.3f} +- {se['b_pct']:.3f} % (se), r2 = {fit.line.r2:.3f}, n = {fit.line.n}")
    for b in [fit.boundaries] + fit.alternatives:
        print(f"boundaries [{b.method}]: powder/wax {b.powder_wax_j:.0f} J "
              f"[{b.ci.loc['powder_wax_j', 'lower']:.0f}, {b.ci.loc['powder_wax_j', 'upper']:.0f}], "
              f"wax/complete {b.wax_complete_j:.0f} J "
              f"[{b.ci.loc['wax_complete_j', 'lower']:.0f}, {b.ci.loc['wax_complete_j', 'upper']:.0f}]")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
