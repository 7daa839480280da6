"""Plots of the kinetics stage (paper Figures 9-11). The plot functions take results, ax=None,
return ax; :func:`write_kinetics_figures` draws all three into a folder (the kinetics CLI's)."""
from __future__ import annotations

import numpy as np
import pandas as pd

REGIME_COLOURS = {"powder": "#dbe9f6", "wax": "#fde7c8", "complete": "#dff2d8"}


def _ax(ax):
    if ax is None:
        import matplotlib.pyplot as plt
        _, ax = plt.subplots()
    return ax


def plot_ekin_map(inputs: pd.DataFrame, ax=None):
    """Figure 9: mean kinetic energy E_kin [mJ] vs frequency, one line per ball diameter.

    Parameters
    ----------
    inputs : DataFrame - frequency_hz, ball_diameter_m, e_kin_j (and optional measured flag)
    """
    ax = _ax(ax)
    for d, grp in inputs.groupby("ball_diameter_m"):
        grp = grp.sort_values("frequency_hz")
        measured = bool(grp["measured"].all()) if "measured" in grp else True
        ax.plot(grp["frequency_hz"], grp["e_kin_j"] * 1e3, "o-" if measured else "s--",
                label=f"d = {d * 1e3:.1f} mm" + ("" if measured else " (interpolated)"))
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel("E_kin = 1/2 m v_mean^2 [mJ]")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    return ax


def plot_yield_vs_time(data: pd.DataFrame, curves: dict | None = None, ax=None):
    """Figure 10: yield [%] vs milling time per frequency; with ``curves`` the model curve of
    each condition (line, wax ramp, plateau) is drawn too.

    Parameters
    ----------
    data : DataFrame - condition_id, frequency_hz, time_min, yield_pct
    curves : dict condition_id -> (time_min array, yield_pct array), optional - the model's
        curves, computed by the caller (:func:`analysis.kinetics.prediction.model_curves`)
    """
    ax = _ax(ax)
    for i, (cid, grp) in enumerate(data.groupby("condition_id", sort=False)):
        col = f"C{i}"
        f = grp["frequency_hz"].iloc[0]
        ax.plot(grp["time_min"], grp["yield_pct"], "o", color=col, label=f"{f:g} Hz")
        if curves and cid in curves:
            t, y = curves[cid]
            ax.plot(t, y, "-", color=col, lw=1)
    ax.set_xlabel("milling time [min]")
    ax.set_ylabel("monomer yield X [%]")
    ax.set_ylim(-3, 105)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    return ax


def plot_yield_vs_energy(data: pd.DataFrame, fit, ax=None, alpha: float = 0.05):
    """Figure 11: yield vs cumulative energy with the powder line, its confidence and prediction
    bands, and the regime boundaries as shaded regions.

    Parameters
    ----------
    data : DataFrame - e_tot_j, yield_pct, frequency_hz
    fit : KineticsFit
    """
    ax = _ax(ax)
    e_max = float(data["e_tot_j"].max()) * 1.05
    e1, e2 = fit.boundaries.powder_wax_j, fit.boundaries.wax_complete_j
    ax.axvspan(0, e1 / 1e3, color=REGIME_COLOURS["powder"], zorder=0, label="powder")
    ax.axvspan(e1 / 1e3, e2 / 1e3, color=REGIME_COLOURS["wax"], zorder=0, label="wax")
    ax.axvspan(e2 / 1e3, e_max / 1e3, color=REGIME_COLOURS["complete"], zorder=0, label="complete")
    ci = fit.boundaries.ci
    for name in ("powder_wax_j", "wax_complete_j"):
        lo, hi = ci.loc[name, "lower"], ci.loc[name, "upper"]
        if np.isfinite(lo) and np.isfinite(hi):
            ax.axvspan(lo / 1e3, hi / 1e3, color="0.5", alpha=0.15, zorder=0)
    g = np.linspace(0, e1, 100)
    p = fit.line.predict(g, alpha)
    lv = fit.line.params
    ax.fill_between(g / 1e3, p["pi_lo"], p["pi_hi"], color="C0", alpha=0.15,
                    label=f"{100 * (1 - alpha):.0f} % prediction band")
    ax.fill_between(g / 1e3, p["ci_lo"], p["ci_hi"], color="C0", alpha=0.35,
                    label=f"{100 * (1 - alpha):.0f} % confidence band")
    ax.plot(g / 1e3, p["yield_pct"], "C0-",
            label=f"X = {lv['a_pct_per_kj']:.2f} E - {abs(lv['b_pct']):.2f} (r2 {fit.line.r2:.3f})")
    for i, (f, grp) in enumerate(data.groupby("frequency_hz")):
        ax.plot(grp["e_tot_j"] / 1e3, grp["yield_pct"], "o^sD"[i % 4], color=f"C{i + 1}",
                label=f"{f:g} Hz", mec="k", mew=0.4)
    ax.set_xlim(0, e_max / 1e3)
    ax.set_ylim(-5, 105)
    ax.set_xlabel("cumulative energy E_tot = E_kin f_col t [kJ]")
    ax.set_ylabel("monomer yield X [%]")
    ax.legend(fontsize=7, loc="upper left")
    return ax


def write_kinetics_figures(folder, fit, data: pd.DataFrame, inputs: pd.DataFrame, curves: dict,
                           synthetic: bool) -> None:
    """Figures 9-11 of the kinetics stage as PNG files in ``folder``: fig09_ekin.png,
    fig10_yield_time.png, fig11_yield_energy.png (130 dpi, Agg backend).

    Parameters
    ----------
    folder : Path - existing output folder
    fit : KineticsFit
    data : DataFrame - yields with energy: condition_id, frequency_hz, time_min, yield_pct,
        e_tot_j
    inputs : DataFrame - energy inputs (frequency_hz, ball_diameter_m, e_kin_j, source, ...)
    curves : dict condition_id -> (time_min array, yield_pct array) - the model's curves
        (:func:`analysis.kinetics.prediction.model_curves`)
    synthetic : bool - the yields are SYNTHETIC (the yield figures' titles say so)
    """
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tag = "SYNTHETIC yields - " if synthetic else ""
    fig, ax = plt.subplots(figsize=(6, 4.2))
    plot_ekin_map(inputs, ax=ax)
    ax.set_title("E_kin vs frequency and ball size\n(" + inputs["source"].iloc[0][:70] + ")", fontsize=8)
    fig.tight_layout(); fig.savefig(folder / "fig09_ekin.png", dpi=130); plt.close(fig)

    fig, ax = plt.subplots(figsize=(6, 4.2))
    plot_yield_vs_time(data, curves=curves, ax=ax)
    ax.set_title(tag + "yield vs milling time (20 mm ball)", fontsize=9)
    fig.tight_layout(); fig.savefig(folder / "fig10_yield_time.png", dpi=130); plt.close(fig)

    fig, ax = plt.subplots(figsize=(6.5, 4.5))
    plot_yield_vs_energy(data, fit, ax=ax)
    ax.set_title(tag + "yield vs cumulative energy, powder line with 95 % bands", fontsize=9)
    fig.tight_layout(); fig.savefig(folder / "fig11_yield_energy.png", dpi=130); plt.close(fig)
