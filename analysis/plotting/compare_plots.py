"""Figures of the comparison / diagnosis loop. Each function takes a result and ``ax=None`` and
returns the axes; nothing here writes files (the CLIs do)."""
from __future__ import annotations

import numpy as np


def _ax(ax):
    if ax is None:
        import matplotlib.pyplot as plt
        _, ax = plt.subplots()
    return ax


def plot_residual_heatmap(comparison, ax=None, z_max: float = 5.0):
    """Condition x observable map of standardised residuals z = (model - measured) / sigma.

    Parameters
    ----------
    comparison : analysis.compare.Comparison
        (yield rows are averaged per condition into one 'yield_pct' column)
    z_max : float
        colour scale is clipped at +-z_max
    """
    ax = _ax(ax)
    t = comparison.table
    order = (t[["condition_id", "label", "ball_diameter_mm", "frequency_hz"]]
             .drop_duplicates("condition_id")
             .sort_values(["ball_diameter_mm", "frequency_hz"]))
    obs = list(dict.fromkeys(t["observable"]))
    z = t.groupby(["condition_id", "observable"])["z"].mean().unstack("observable")
    z = z.reindex(index=order["condition_id"], columns=obs)
    im = ax.imshow(np.clip(z.to_numpy(float), -z_max, z_max), cmap="RdBu_r", vmin=-z_max,
                   vmax=z_max, aspect="auto")
    for i in range(z.shape[0]):
        for j in range(z.shape[1]):
            v = z.iat[i, j]
            if np.isfinite(v):
                ax.text(j, i, "%+.1f" % v, ha="center", va="center", fontsize=8,
                        color="white" if abs(v) > 0.6 * z_max else "black")
    ax.set_xticks(range(len(obs)), obs)
    ax.set_yticks(range(len(order)), order["label"])
    ax.figure.colorbar(im, ax=ax, label="z = (model - measured) / sigma")
    ax.set_title("chi2/dof = %.2f" % comparison.chi2_dof)
    return ax


def plot_phase_folded(comparison, ax=None, condition_id=None, quantity="vx"):
    """Velocity over the jar cycle, measured (points) and model (line), per condition.

    quantity : 'vx' (along the jar axis) or 'speed'
    """
    ax = _ax(ax)
    ph = comparison.phase
    if ph is None:
        ax.text(0.5, 0.5, "no tracks on both sides", ha="center", transform=ax.transAxes)
        return ax
    col = "vx_mean_m_s" if quantity == "vx" else "speed_mean_m_s"
    ids = [condition_id] if condition_id is not None else list(dict.fromkeys(ph["condition_id"]))
    for k, cid in enumerate(ids):
        d = ph.loc[ph["condition_id"] == cid]
        m, p = d.loc[d["side"] == "measured"], d.loc[d["side"] == "model"]
        c = "C%d" % (k % 10)
        ax.plot(p["phase"], p[col], "-", color=c, label="%s model" % d["label"].iat[0])
        ax.plot(m["phase"], m[col], "o", color=c, ms=3, label="measured")
    ax.set_xlabel("phase of the jar cycle [cycles]")
    ax.set_ylabel("%s [m/s]" % ("v_x" if quantity == "vx" else "speed"))
    ax.legend(fontsize=7)
    return ax


def plot_yield_residuals(comparison, ax=None):
    """Yield residual (model - measured, percentage points) against time, per condition,
    with +-1 sigma error bars."""
    ax = _ax(ax)
    t = comparison.table.loc[comparison.table["observable"] == "yield_pct"]
    for k, (cid, d) in enumerate(t.groupby("condition_id", sort=False)):
        ax.errorbar(d["time_min"], d["residual"], yerr=d["sigma"], fmt="o-", ms=3,
                    color="C%d" % (k % 10), label=d["label"].iat[0])
    ax.axhline(0.0, color="k", lw=0.8)
    ax.set_xlabel("milling time [min]")
    ax.set_ylabel("yield residual, model - measured [points]")
    ax.legend(fontsize=7)
    return ax


def plot_chi2_staircase(staircase, ax=None):
    """chi2/dof per stage (baseline, calibrated, with effect) as a staircase of bars.

    staircase : DataFrame with columns stage, chi2_dof (e.g. ``AddEffectResult.staircase``)
    """
    ax = _ax(ax)
    x = np.arange(len(staircase))
    ax.bar(x, staircase["chi2_dof"], color=["C7", "C0", "C2", "C3", "C4"][:len(x)])
    for i, v in enumerate(staircase["chi2_dof"]):
        ax.text(i, v, "%.2f" % v, ha="center", va="bottom", fontsize=8)
    ax.axhline(1.0, color="k", ls="--", lw=0.8)
    ax.set_xticks(x, staircase["stage"], rotation=15)
    ax.set_ylabel("chi2 / dof")
    ax.set_yscale("log")
    return ax


def plot_effect_ranking(diagnosis, ax=None):
    """Bar chart of each candidate's chi2 gain, with the significance threshold
    (Bonferroni-corrected chi2_1 quantile) as a line; non-identifiable candidates hatched."""
    ax = _ax(ax)
    t = diagnosis.table
    x = np.arange(len(t))
    colors = ["C2" if s else "C7" for s in t["significant"]]
    bars = ax.bar(x, np.maximum(t["delta_chi2"], 1e-3), color=colors)
    for b, ident in zip(bars, t["identifiable"]):
        if not ident:
            b.set_hatch("//")
    ax.axhline(diagnosis.threshold_delta_chi2, color="k", ls="--", lw=0.8,
               label="significance threshold")
    ax.set_xticks(x, t["effect"], rotation=20)
    ax.set_ylabel("chi2 gain")
    ax.set_yscale("log")
    ax.legend(fontsize=7)
    return ax
