"""The kinetics model (paper Section 4, eq 4, Table 4): the energy descriptor and the
powder-regime yield line.

The energy descriptor of a run is the cumulative kinetic energy delivered by the ball,

    E_tot(t) = E_kin * f_col * t,     E_kin = 1/2 m v_mean^2,   m = rho * pi d^3 / 6,

and the yield in the powder regime is the straight line X[%] = a * E_tot[kJ] + b (Table 4:
a = 9.49 +- 1.00 %/kJ, b = -3.03 +- 1.70 %), fitted by OLS (statsmodels) with its 95 %
confidence band (of the line) and prediction band (of a new observation). The constants of the
stage (steel density, the yield experiments' ball, the regime names, the paper's Table 4 values)
and its error type live here too; every other kinetics module builds on this one.

References
----------
Anglou et al., ACS Sustainable Chem. Eng. 2024, 12, 9003-9017, Section 4, eq 4, Table 4.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy import stats

STEEL_DENSITY_KG_M3 = 7800.0
#: ball of the paper's yield experiments (one stainless-steel ball, d = 20 mm)
YIELD_BALL_DIAMETER_MM = 20.0
REGIMES = ("powder", "wax", "complete")
#: paper Table 4 values (the published fit; used as truth for synthetic data and for labels)
PAPER_SLOPE_PCT_PER_KJ = 9.49
PAPER_INTERCEPT_PCT = -3.03
PAPER_POWDER_WAX_J = 4593.0
PAPER_WAX_COMPLETE_J = 7126.0


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
