"""Yield prediction from a kinetics fit: regime, yield and its bands at a cumulative energy,
yield against milling time for a condition's E_kin and f_col, and the fitted curve per condition.
"""
from __future__ import annotations

import numpy as np
import pandas as pd

from analysis.kinetics.fitting import KineticsFit
from analysis.kinetics.model import KineticsInputError, cumulative_energy_j


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
