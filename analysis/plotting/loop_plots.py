"""Figures of the loop (:mod:`analysis.loop`): its chi2/dof staircase and the ranking of the
candidate effects at a diagnosis step. Each ``plot_*`` function takes a result and ``ax=None``
and returns the axes; :func:`write_loop_figures` draws the PNG files of the loop's folder."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from analysis.plotting.files import pyplot, save_png
from analysis.plotting.marks import is_synthetic, mark_synthetic, synthetic_title


def _ax(ax):
    if ax is None:
        import matplotlib.pyplot as plt
        _, ax = plt.subplots()
    return ax


def _name_and_synthetic(dataset, dataset_name, synthetic):
    name = dataset_name if dataset_name is not None else getattr(dataset, "name", "") or ""
    return name, is_synthetic(dataset, synthetic)


#: colours of the loop staircase's bar kinds (analysis.report.loop_words.stage_kind)
STAGE_COLOURS = {"model": "C0", "real twin": "C3", "FAKE twin": "C1"}


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
    kinds = [stage_kind(s, fake) for s in st["stage"]]
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


def write_loop_figures(staircase, first_diagnosis, folder, dataset, *, fake: bool = False,
                       quoted=None, threshold_scale: float = 1.0) -> list:
    """The loop's figures into ``folder``: staircase.png (every stage's chi2/dof,
    :func:`plot_loop_staircase`) and, when a diagnosis ran, ranking.png (its first step's
    ranking with the threshold that step applied, :func:`plot_effect_ranking`).

    Parameters
    ----------
    staircase : DataFrame - stage, chi2, dof, chi2_dof (``LoopResult.staircase``)
    first_diagnosis : analysis.diagnose.Diagnosis or None
    folder : path of an existing folder
    dataset : analysis.measurements.Dataset - names the ranking, marks a synthetic dataset
    fake : the loop ran on the FAKE twin: FAKE in both titles, a watermark and the PNG's
        Title / Description text chunks
    quoted : {role: row} of the staircase rows the verdict quotes (default
        :func:`analysis.report.loop_words.quoted_stages`)
    threshold_scale : the bootstrap's scale of the first step's threshold

    Returns
    -------
    list of str - the names of the files written
    """
    from analysis.report.loop_words import FAKE_WORDS
    plt = pyplot()
    folder = Path(folder)
    synth = bool(getattr(dataset, "synthetic", False))
    name = getattr(dataset, "name", "") or ""
    fig, ax = plt.subplots(figsize=loop_staircase_figsize(staircase))
    plot_loop_staircase(staircase, ax=ax, quoted=quoted, synthetic=synth, fake=fake,
                        title="chi2/dof staircase of the loop on %s" % name if name else None)
    fig.tight_layout()
    meta = {"Title": ax.get_title()}
    if fake:
        meta["Description"] = FAKE_WORDS
    save_png(fig, folder / "staircase.png", 120, meta)
    names = ["staircase.png"]
    if first_diagnosis is not None:
        fig, ax = plt.subplots(figsize=ranking_figsize(first_diagnosis))
        plot_effect_ranking(first_diagnosis, ax=ax, dataset=dataset, fake=fake, step=1,
                            threshold_scale=threshold_scale)
        fig.tight_layout()
        meta = {"Title": ax.get_title()}
        if fake:
            meta["Description"] = FAKE_WORDS
        save_png(fig, folder / "ranking.png", 120, meta)
        names.append("ranking.png")
    return names
