"""Figures of the comparison / diagnosis loop. Each ``plot_*`` function takes a result and
``ax=None`` and returns the axes; :func:`write_compare_figures` draws the PNG files of
analysis.compare's report."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from analysis.plotting.files import pyplot, save_png
from analysis.plotting.marks import (condition_label, fits_horizontally, is_synthetic,
                                     mark_synthetic, short_observable, synthetic_title)


def _ax(ax):
    if ax is None:
        import matplotlib.pyplot as plt
        _, ax = plt.subplots()
    return ax


def _name_and_synthetic(dataset, dataset_name, synthetic):
    name = dataset_name if dataset_name is not None else getattr(dataset, "name", "") or ""
    return name, is_synthetic(dataset, synthetic)


def heatmap_figsize(comparison, extra_width: float = 0.0):
    """(width, height) in inches for :func:`plot_residual_heatmap`: wide enough for the row
    labels, the colour bar and 0.6 in per observable column, tall enough for the rows and
    upright column labels."""
    t = comparison.table
    n_cols = t["observable"].nunique()
    n_rows = t["condition_id"].nunique()
    return (max(5.5, 3.4 + 0.6 * n_cols) + extra_width, 1.9 + 0.35 * n_rows)


def plot_residual_heatmap(comparison, ax=None, z_max: float = 5.0, *, dataset=None,
                          dataset_name: str | None = None, synthetic: bool | None = None,
                          title: str | None = None):
    """Condition x observable map of standardised residuals z = (model - measured) / sigma.

    Parameters
    ----------
    comparison : analysis.compare.Comparison
        (yield rows are averaged per condition into one 'yield_pct' column)
    z_max : float
        colour scale is clipped at +-z_max
    dataset : Dataset or None
        supplies the title's name and whether the data are synthetic (``Dataset.synthetic``)
    dataset_name, synthetic : override what ``dataset`` says
    title : str or None
        replaces the default title '<name>: chi2/dof = ...'; synthetic data still get the
        SYNTHETIC mark (title suffix and watermark)

    Rows carry short condition labels ('17.5 mm / 25 Hz'), columns short observable names,
    written upright when they would not fit side by side; size the figure with
    :func:`heatmap_figsize`.
    """
    ax = _ax(ax)
    name, synth = _name_and_synthetic(dataset, dataset_name, synthetic)
    t = comparison.table
    order = (t[["condition_id", "ball_diameter_mm", "frequency_hz"]]
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
    xlabels = [short_observable(o) for o in obs]
    fs = 9
    if fits_horizontally(ax, xlabels, fs):
        ax.set_xticks(range(len(obs)), xlabels, fontsize=fs)
    else:
        ax.set_xticks(range(len(obs)), xlabels, fontsize=fs, rotation=90)
    ax.set_yticks(range(len(order)), [condition_label(f, d) for f, d in
                                      zip(order["frequency_hz"], order["ball_diameter_mm"])],
                  fontsize=fs)
    ax.set_ylabel("ball / frequency")
    ax.figure.colorbar(im, ax=ax, label="z = (model - %s) / sigma"
                       % ("synthetic data" if synth else "measured"))
    if title is None:
        title = ("%s: " % name if name else "") + "chi2/dof = %.2f" % comparison.chi2_dof
    ax.set_title(synthetic_title(title, synth), fontsize=10)
    mark_synthetic(ax, synth)
    return ax


def plot_phase_folded(comparison, ax=None, condition_id=None, quantity="vx", *,
                      synthetic: bool = False):
    """Velocity over the jar cycle, measured (points) and model (line), per condition.

    quantity : 'vx' (along the jar axis) or 'speed'
    synthetic : bool - the 'measured' side is synthetic data: SYNTHETIC title and watermark
    """
    ax = _ax(ax)
    if synthetic:
        ax.set_title(synthetic_title("velocity over the jar cycle", True), fontsize=10)
        mark_synthetic(ax)
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
        ax.plot(m["phase"], m[col], "o", color=c, ms=3,
                label="synthetic data" if synthetic else "measured")
    ax.set_xlabel("phase of the jar cycle [cycles]")
    ax.set_ylabel("%s [m/s]" % ("v_x" if quantity == "vx" else "speed"))
    ax.legend(fontsize=7)
    return ax


def plot_yield_residuals(comparison, ax=None, *, synthetic: bool = False):
    """Yield residual (model - measured, percentage points) against time, per condition,
    with +-1 sigma error bars; ``synthetic``: SYNTHETIC title and watermark."""
    ax = _ax(ax)
    if synthetic:
        ax.set_title(synthetic_title("yield residuals", True), fontsize=10)
        mark_synthetic(ax)
    t = comparison.table.loc[comparison.table["observable"] == "yield_pct"]
    for k, (cid, d) in enumerate(t.groupby("condition_id", sort=False)):
        ax.errorbar(d["time_min"], d["residual"], yerr=d["sigma"], fmt="o-", ms=3,
                    color="C%d" % (k % 10), label=d["label"].iat[0])
    ax.axhline(0.0, color="k", lw=0.8)
    ax.set_xlabel("milling time [min]")
    ax.set_ylabel("yield residual, model - %s [points]"
                  % ("synthetic data" if synthetic else "measured"))
    ax.legend(fontsize=7)
    return ax


def plot_chi2_staircase(staircase, ax=None, *, title: str | None = None,
                        synthetic: bool = False):
    """chi2/dof per stage (baseline, calibrated, with effect) as a staircase of bars.

    staircase : DataFrame with columns stage, chi2_dof (e.g. ``AddEffectResult.staircase``)
    title : str or None; synthetic : bool - add the SYNTHETIC mark (title suffix, watermark)
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
    if title is not None or synthetic:
        ax.set_title(synthetic_title(title or "", synthetic), fontsize=10)
    mark_synthetic(ax, synthetic)
    return ax


#: legend words of the ranking's marks
RANKING_WORDS = {"significant": "significant (identifiable, Bonferroni p < alpha, BIC gain > 0)",
                 "not significant": "not significant",
                 "not identifiable": "not identifiable (hatched: footprint or SNR too small)",
                 "at the bound": "strength at the bound of its range",
                 "threshold": "significance threshold: chi2 gain %.3g (Bonferroni, alpha %g)"}


def plot_effect_ranking(diagnosis, ax=None, *, dataset=None, dataset_name: str | None = None,
                        synthetic: bool | None = None, title: str | None = None):
    """Each candidate's chi2 gain as a horizontal bar (rank 1 on top, linear axis, value
    written at the bar), the significance threshold (Bonferroni-corrected chi2_1 quantile) as
    a labelled line; significant bars green, others grey, non-identifiable ones hatched, a
    triangle where the fitted strength sits on its bound; a legend names every mark used.

    dataset : Dataset or None - the title's name and whether it is synthetic
    dataset_name, synthetic : override what ``dataset`` says
    title : str or None - replaces the default 'Which effect is missing? <name>'
    """
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch
    from matplotlib.transforms import blended_transform_factory

    ax = _ax(ax)
    name, synth = _name_and_synthetic(dataset, dataset_name, synthetic)
    t = diagnosis.table
    n = len(t)
    y = np.arange(n)
    gain = np.nan_to_num(t["delta_chi2"].to_numpy(float), nan=0.0)
    sig = t["significant"].astype(bool).to_numpy()
    ident = t["identifiable"].astype(bool).to_numpy()
    bound = (t["strength_at_bound"].astype(bool).to_numpy() if "strength_at_bound" in t
             else np.zeros(n, bool))
    thr = float(diagnosis.threshold_delta_chi2)
    bars = ax.barh(y, gain, color=["C2" if s else "C7" for s in sig], edgecolor="k",
                   linewidth=0.4, height=0.7)
    for b, ok in zip(bars, ident):
        if not ok:
            b.set_hatch("///")
    hi = max(float(gain.max()) if n else 0.0, thr, 1e-9)
    for i in range(n):
        words = "%.3g" % gain[i] + ("" if ident[i] else "  not identifiable")
        ax.text(gain[i] + (0.03 if bound[i] else 0.012) * hi, i, words, va="center",
                ha="left", fontsize=7,
                bbox=dict(facecolor="white", edgecolor="none", alpha=0.7, pad=0.5))
    if bound.any():
        ax.plot(gain[bound], y[bound], ">", color="k", ms=5, zorder=5)
    ax.axvline(thr, color="C3", ls="--", lw=1.0)
    ax.text(thr, 1.0, " threshold %.3g" % thr, color="C3", fontsize=7, ha="left", va="top",
            transform=blended_transform_factory(ax.transData, ax.transAxes))
    ax.set_xlim(0.0, 1.3 * hi)
    ax.set_yticks(y, t["effect"], fontsize=8)
    ax.set_ylim(n - 0.5, -0.5 - (0.9 if n else 0.0))     # rank 1 on top, room for the label
    ax.set_xlabel("chi2 gain when the effect is added (base refitted)")
    handles = []
    if sig.any():
        handles.append(Patch(facecolor="C2", edgecolor="k", label=RANKING_WORDS["significant"]))
    if (~sig).any():
        handles.append(Patch(facecolor="C7", edgecolor="k",
                             label=RANKING_WORDS["not significant"]))
    if (~ident).any():
        handles.append(Patch(facecolor="white", edgecolor="k", hatch="///",
                             label=RANKING_WORDS["not identifiable"]))
    if bound.any():
        handles.append(Line2D([], [], ls="", marker=">", color="k",
                              label=RANKING_WORDS["at the bound"]))
    handles.append(Line2D([], [], color="C3", ls="--",
                          label=RANKING_WORDS["threshold"] % (thr, diagnosis.alpha)))
    # below the axes, clear of the tick labels and the axis label whatever the axes height
    ax.legend(handles=handles, fontsize=7, loc="upper center", bbox_to_anchor=(0.5, 0.0),
              borderaxespad=4.6, ncol=1, frameon=False)
    if title is None:
        title = "Which effect is missing?" + (" %s" % name if name else "")
    ax.set_title(synthetic_title(title, synth), fontsize=10)
    mark_synthetic(ax, synth)
    return ax


def ranking_figsize(diagnosis):
    """(width, height) in inches for :func:`plot_effect_ranking`: 0.25 in per candidate plus
    the title, axis label and legend."""
    return (7.0, 2.4 + 0.25 * len(diagnosis.table))


def write_compare_figures(comparison, dataset, folder) -> list:
    """The figures of a comparison's report into ``folder``: heatmap.png
    (:func:`plot_residual_heatmap`), phase.png when both sides have tracks
    (:func:`plot_phase_folded`), yields.png when yields are compared
    (:func:`plot_yield_residuals`).

    Parameters
    ----------
    comparison : analysis.compare.Comparison
    dataset : Dataset - the title's name and whether the data are synthetic
    folder : path of an existing folder

    Returns
    -------
    list of str - the names of the files written, in that order
    """
    plt = pyplot()
    folder = Path(folder)
    names = []
    fig, ax = plt.subplots(figsize=heatmap_figsize(comparison))
    plot_residual_heatmap(comparison, ax=ax, dataset=dataset)
    fig.tight_layout()
    save_png(fig, folder / "heatmap.png", 120)
    names.append("heatmap.png")
    if comparison.phase is not None:
        fig, ax = plt.subplots(figsize=(6, 4))
        plot_phase_folded(comparison, ax=ax, synthetic=dataset.synthetic)
        fig.tight_layout()
        save_png(fig, folder / "phase.png", 120)
        names.append("phase.png")
    if (comparison.table["observable"] == "yield_pct").any():
        fig, ax = plt.subplots(figsize=(6, 4))
        plot_yield_residuals(comparison, ax=ax, synthetic=dataset.synthetic)
        fig.tight_layout()
        save_png(fig, folder / "yields.png", 120)
        names.append("yields.png")
    return names
