"""Figures of the hidden-effect suite and demo: the confusion matrix (what diagnose reports
against what was hidden) and the demo's overview (residual map before, chi2/dof staircase).
The ``plot_*`` functions take results and ``ax=None`` and return the axes; the ``write_*``
functions draw the PNG files analysis.hidden_suite and analysis.hidden_demo publish."""
from __future__ import annotations

from analysis.plotting.compare_plots import (heatmap_figsize, plot_chi2_staircase,
                                             plot_residual_heatmap)
from analysis.plotting.files import pyplot, save_png
from analysis.plotting.marks import synthetic_title


def _ax(ax):
    if ax is None:
        import matplotlib.pyplot as plt
        _, ax = plt.subplots()
    return ax


def plot_confusion(confusion, ax=None, *, synthetic: bool = True):
    """Share of each hidden effect's datasets (rows) by what diagnose reported (columns), as a
    blue map with the percentages written in the non-empty cells.

    Parameters
    ----------
    confusion : DataFrame - index hidden effect, columns reported effect ('nothing' last),
        values the fraction of the row's datasets [-] (analysis.hidden_suite.confusion_matrix)
    synthetic : bool - the datasets are synthetic: SYNTHETIC title suffix
    """
    ax = _ax(ax)
    truths, said = list(confusion.index), list(confusion.columns)
    m = confusion.to_numpy(float)
    ax.imshow(m, cmap="Blues", vmin=0, vmax=1)
    ax.set_xticks(range(len(said)), said, rotation=40, ha="right", fontsize=7)
    ax.set_yticks(range(len(truths)), truths, fontsize=7)
    for i in range(len(truths)):
        for j in range(len(said)):
            if m[i, j] > 0:
                ax.text(j, i, "%.0f%%" % (100 * m[i, j]), ha="center", va="center", fontsize=7)
    ax.set_xlabel("reported by diagnose")
    ax.set_ylabel("hidden in the data")
    ax.set_title(synthetic_title("Hidden-effect suite: what diagnose reports", synthetic))
    return ax


def write_confusion_figure(confusion, path, *, synthetic: bool = True):
    """:func:`plot_confusion` written to ``path`` (PNG); returns ``path``."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(8, 5))
    plot_confusion(confusion, ax=ax, synthetic=synthetic)
    fig.tight_layout()
    return save_png(fig, path, 120)


def write_overview_figure(comparison, staircase, dataset, path):
    """The hidden-effect demo's overview written to ``path`` (PNG): the residual map of the
    calibrated twin without effects (left) beside the chi2/dof staircase (right).

    Parameters
    ----------
    comparison : analysis.compare.Comparison - the calibrated twin, no effect
    staircase : DataFrame - stage, chi2_dof
    dataset : Dataset - the title's name and whether the data are synthetic

    Returns
    -------
    path
    """
    plt = pyplot()
    w, h = heatmap_figsize(comparison)
    fig, axes = plt.subplots(1, 2, figsize=(w + 5.0, max(h, 4.0)),
                             gridspec_kw={"width_ratios": [w, 5.0]})
    plot_residual_heatmap(comparison, ax=axes[0], dataset=dataset,
                          title="before: calibrated twin, no effect")
    plot_chi2_staircase(staircase, ax=axes[1], title="chi2/dof by stage",
                        synthetic=dataset.synthetic)
    fig.tight_layout()
    return save_png(fig, path, 110)
