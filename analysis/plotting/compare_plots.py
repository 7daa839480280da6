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
    """chi2/dof per stage (baseline, calibrated, with effect) as a staircase of bars (linear
    axis from 0; the loop's longer staircase: :func:`plot_loop_staircase`).

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
    ax.set_yscale("linear")
    top = np.nanmax(np.asarray(staircase["chi2_dof"], float)) if len(x) else 1.0
    ax.set_ylim(0.0, 1.15 * max(top if np.isfinite(top) else 1.0, 1.0))
    if title is not None or synthetic:
        ax.set_title(synthetic_title(title or "", synthetic), fontsize=10)
    mark_synthetic(ax, synthetic)
    return ax


#: colours of the loop staircase's bar kinds (analysis.report.loop_words.stage_kind)
STAGE_COLOURS = {"model": "C0", "real twin": "C3"}


def loop_staircase_figsize(staircase):
    """(width, height) in inches for :func:`plot_loop_staircase`: 0.42 in per stage plus the
    title, axis label and the legend below."""
    return (8.0, 3.0 + 0.42 * len(staircase))


def plot_loop_staircase(staircase, ax=None, *, quoted=None, synthetic: bool = False,
                        fake: bool = False, title: str | None = None):
    """The loop's chi2/dof staircase, one horizontal bar per stage in the loop's order (top
    to bottom) on a linear axis from 0, each labelled with its stage and what it is (model,
    model on the twin's reruns, real twin: colour and label), its chi2/dof and dof written at
    the bar; the stages the verdict quotes (``quoted``: {role: row},
    :func:`analysis.report.loop_words.quoted_stages`) in bold with a '* verdict' mark; a bar
    far beyond the others is cut at the axis' end and says so; chi2/dof = 1 as a line.

    staircase : DataFrame with stage, chi2_dof, dof (``LoopResult.staircase``)
    synthetic, fake : the SYNTHETIC / FAKE marks (title suffix, watermark)
    """
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch
    from analysis.report.loop_words import KIND_WORDS, quoted_stages, stage_kind

    ax = _ax(ax)
    st = staircase.reset_index(drop=True)
    n = len(st)
    y = np.arange(n)
    v = np.asarray(st["chi2_dof"], float)
    shown = np.where(np.isfinite(v), v, 0.0)
    dof = (np.asarray(st["dof"], float) if "dof" in st else np.full(n, np.nan))
    kinds = [stage_kind(s) for s in st["stage"]]
    if quoted is None:
        quoted = quoted_stages(st) if "stage" in st else {}
    qrows = {int(i): role for role, i in quoted.items()}
    # a bar more than 3x the rest is cut at the axis' end so the rest stays readable
    order = np.sort(shown)[::-1]
    rest = order[1] if n > 1 else order[0] if n else 1.0
    hi = max(float(order[0]) if n else 1.0, 1.0)
    cut = n > 2 and order[0] > 3.0 * max(rest, 1.0)
    xmax = 1.8 * max(rest, 1.0) if cut else 1.5 * hi
    drawn = np.minimum(shown, 1.2 * max(rest, 1.0)) if cut else shown
    bars = ax.barh(y, drawn, color=[STAGE_COLOURS[k] for k in kinds], edgecolor="k",
                   linewidth=[2.0 if i in qrows else 0.4 for i in range(n)], height=0.7)
    for i in range(n):
        words = ("%.2f" % v[i]) if np.isfinite(v[i]) else "untestable"
        if np.isfinite(dof[i]):
            words += "  (dof %d)" % int(dof[i])
        if cut and shown[i] > drawn[i]:
            words += ", bar cut"
            bars[i].set_hatch("//")
        if i in qrows:
            words += "   * verdict"
        ax.text(drawn[i] + 0.01 * xmax, i, words, va="center", ha="left", fontsize=7,
                fontweight="bold" if i in qrows else "normal",
                bbox=dict(facecolor="white", edgecolor="none", alpha=0.7, pad=0.5))
    ax.axvline(1.0, color="k", ls="--", lw=0.8)
    ax.set_xscale("linear")
    ax.set_yscale("linear")
    ax.set_xlim(0.0, xmax)
    labels = ["%s  [%s]" % (s, k) for s, k in zip(st["stage"], kinds)]
    ax.set_yticks(y, labels, fontsize=7)
    for i, tl in enumerate(ax.get_yticklabels()):
        tl.set_color(STAGE_COLOURS[kinds[i]] if kinds[i] != "model" else "k")
        if i in qrows:
            tl.set_fontweight("bold")
    ax.set_ylim(n - 0.5, -0.5)
    ax.set_xlabel("chi2 / dof")
    handles = [Patch(facecolor=STAGE_COLOURS[k], edgecolor="k", label=KIND_WORDS[k])
               for k in STAGE_COLOURS if k in kinds]
    if qrows:
        handles.append(Patch(facecolor="white", edgecolor="k", linewidth=2.0,
                             label="* verdict: the chi2/dof the verdict quotes"))
    if cut:
        handles.append(Patch(facecolor="white", edgecolor="k", hatch="//",
                             label="bar cut at the axis' end (its value is written)"))
    handles.append(Line2D([], [], color="k", ls="--", lw=0.8,
                          label="chi2/dof = 1: a fit as good as the stated sigmas"))
    ax.legend(handles=handles, fontsize=7, loc="upper center", bbox_to_anchor=(0.5, 0.0),
              borderaxespad=4.4, ncol=1, frameon=False)
    title = title if title is not None else "chi2/dof staircase of the loop"
    marks = fake_title(synthetic_title("", synthetic)) if fake else synthetic_title("",
                                                                                    synthetic)
    ax.set_title(title + ("\n" + marks if marks else ""), fontsize=10)
    mark_synthetic(ax, synthetic)
    mark_fake(ax, fake)
    return ax


#: legend words of the ranking's marks
RANKING_WORDS = {"significant": "significant (identifiable, Bonferroni p < alpha, BIC gain > 0)",
                 "not significant": "not significant",
                 "not identifiable": "not identifiable (hatched: footprint or SNR too small)",
                 "at the bound": "strength at the bound of its range",
                 "threshold": "significance threshold applied to every candidate: chi2 gain "
                              "%.3g (Bonferroni, alpha %g)",
                 "threshold scaled": "significance threshold applied to every candidate: chi2 "
                                     "gain %.3g = %.3g (Bonferroni, alpha %g) x %.2f "
                                     "(bootstrap)",
                 "needed": "gain this candidate needed (its F-test at the misfit it leaves, "
                           "or BIC), where above the line"}


def plot_effect_ranking(diagnosis, ax=None, *, dataset=None, dataset_name: str | None = None,
                        synthetic: bool | None = None, title: str | None = None,
                        threshold_scale: float = 1.0, fake: bool = False,
                        step: int | None = None):
    """Each candidate's chi2 gain as a horizontal bar (rank 1 on top, linear axis, value
    written at the bar), the significance threshold as applied (the Bonferroni-corrected
    chi2_1 quantile times the bootstrap's ``threshold_scale``,
    :func:`analysis.report.loop_words.applied_threshold`) as a labelled line, and a tick where
    a candidate needed more (its F-test at the misfit it leaves:
    :func:`analysis.report.loop_words.needed_gains`); significant bars green, others grey,
    non-identifiable ones hatched, a triangle where the fitted strength sits on its bound; a
    legend names every mark used.

    dataset : Dataset or None - the title's name and whether it is synthetic
    dataset_name, synthetic : override what ``dataset`` says
    title : str or None - replaces the default 'Which effect is missing? <name>'
    threshold_scale : the bootstrap's scale of the nominal threshold at this step (1: none)
    fake : the runs were made by the FAKE twin: FAKE in the title and a watermark
    step : the diagnosis step drawn (named in the title)
    """
    from analysis.report.loop_words import applied_threshold, needed_gains
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
    thr_nominal = float(diagnosis.threshold_delta_chi2)
    scale = float(threshold_scale) if np.isfinite(threshold_scale) else 1.0
    thr = applied_threshold(diagnosis, scale)
    need = needed_gains(diagnosis, scale).reindex(t["effect"]).to_numpy(float)
    above = np.isfinite(need) & (need > thr * (1 + 1e-9))
    bars = ax.barh(y, gain, color=["C2" if s else "C7" for s in sig], edgecolor="k",
                   linewidth=0.4, height=0.7)
    for b, ok in zip(bars, ident):
        if not ok:
            b.set_hatch("///")
    hi = max(float(gain.max()) if n else 0.0, thr,
             float(np.max(need[above])) if above.any() else 0.0, 1e-9)
    for i in range(n):
        words = "%.3g" % gain[i] + ("" if ident[i] else "  not identifiable")
        at = gain[i]
        if above[i] and gain[i] - 0.01 * hi <= need[i] <= gain[i] + 0.35 * hi:
            at = need[i]                # clear of the tick just beyond the bar
        ax.text(at + (0.03 if bound[i] else 0.012) * hi, i, words, va="center",
                ha="left", fontsize=7,
                bbox=dict(facecolor="white", edgecolor="none", alpha=0.7, pad=0.5))
    if bound.any():
        ax.plot(gain[bound], y[bound], ">", color="k", ms=5, zorder=5)
    if above.any():
        ax.plot(need[above], y[above], "|", color="C3", ms=14, mew=2.0, zorder=6,
                gid="needed-gain")
    ax.axvline(thr, color="C3", ls="--", lw=1.0, gid="applied-threshold")
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
    if above.any():
        handles.append(Line2D([], [], ls="", marker="|", ms=10, mew=2.0, color="C3",
                              label=RANKING_WORDS["needed"]))
    if abs(scale - 1.0) > 1e-12:
        words = RANKING_WORDS["threshold scaled"] % (thr, thr_nominal, diagnosis.alpha, scale)
    else:
        words = RANKING_WORDS["threshold"] % (thr, diagnosis.alpha)
    handles.append(Line2D([], [], color="C3", ls="--", label=words))
    # below the axes, clear of the tick labels and the axis label whatever the axes height
    ax.legend(handles=handles, fontsize=7, loc="upper center", bbox_to_anchor=(0.5, 0.0),
              borderaxespad=4.6, ncol=1, frameon=False)
    if title is None:
        title = "Which effect is missing?" + (" %s" % name if name else "")
        if step is not None:
            title += " (step %d)" % step
    title = synthetic_title(title, synth)
    if fake:
        title = fake_title(title)
    ax.set_title(title, fontsize=10)
    mark_synthetic(ax, synth)
    mark_fake(ax, fake)
    return ax


def fake_title(title: str) -> str:
    """``title`` with a trailing ' [FAKE twin]' (a figure made from FAKE-twin runs)."""
    from analysis.report.loop_words import FAKE
    return title if FAKE in title else (title + " " if title else "") + "[%s twin]" % FAKE


def mark_fake(ax, fake: bool = True):
    """A diagonal FAKE watermark across the axes (runs made by the FAKE analytic twin); the
    text artist, or None."""
    if not fake:
        return None
    from analysis.report.loop_words import FAKE
    return ax.text(0.5, 0.3, FAKE + " twin", transform=ax.transAxes, ha="center",
                   va="center", rotation=25, fontsize=26, fontweight="bold", color="C3",
                   alpha=0.2, zorder=10, gid="fake-mark")


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
