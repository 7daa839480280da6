"""Plots of the surrogate stage (paper Figures 13 and 14). The ``plot_*`` functions take
results, ax=None, return the axes; :func:`write_surrogate_figures` and
:func:`write_yield_parity_figure` draw the PNG files analysis.surrogate and analysis.predict
publish."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from analysis.plotting.files import pyplot, save_png


def _ax(ax):
    if ax is None:
        import matplotlib.pyplot as plt
        _, ax = plt.subplots()
    return ax


def plot_parity(predictions: pd.DataFrame, output: str, ax=None, title: str | None = None):
    """Figure 13: predicted vs true for one output, train and test splits.

    Parameters
    ----------
    predictions : DataFrame - split, <output>, <output>_pred
    output : str - "v_mean_m_s" or "f_col_hz"
    """
    ax = _ax(ax)
    for split, mk in (("train", "o"), ("test", "s")):
        p = predictions[predictions["split"] == split]
        ax.plot(p[output], p[output + "_pred"], mk, ms=4, label=split, alpha=0.8)
    lo = float(np.nanmin(predictions[[output, output + "_pred"]].to_numpy()))
    hi = float(np.nanmax(predictions[[output, output + "_pred"]].to_numpy()))
    ax.plot([lo, hi], [lo, hi], "k-", lw=0.8)
    ax.set_xlabel(f"twin {output}")
    ax.set_ylabel(f"surrogate {output}")
    if title:
        ax.set_title(title, fontsize=8)
    ax.legend(fontsize=7)
    return ax


def plot_learning_curve(lc: pd.DataFrame, output: str, ax=None):
    """Mean absolute % error on the test split vs number of training design points (mean +- sd over
    repeats), one line per surrogate kind."""
    ax = _ax(ax)
    d = lc[lc["output"] == output]
    for kind, g in d.groupby("kind"):
        s = g.groupby("n_train")["mape_pct"].agg(["mean", "std"])
        ax.errorbar(s.index, s["mean"], yerr=s["std"], marker="o", capsize=3, label=kind.upper())
    ax.set_yscale("log")
    ax.set_xlabel("training design points (each a replicate mean)")
    ax.set_ylabel(f"test MAPE {output} [%]")
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3, which="both")
    return ax


def plot_yield_parity(table: pd.DataFrame, ax=None, reference: str = "yield_twin_pct",
                      kinds=None, *, reference_label: str | None = None,
                      synthetic: bool = False):
    """Figure 14: yields from surrogate outputs vs a reference (twin-output yields or measured).

    Parameters
    ----------
    table : DataFrame - with columns ``reference`` and yield_<kind>_pct
    reference_label : str or None - x-axis label (default: the reference column's name)
    synthetic : bool - the reference yields are synthetic: SYNTHETIC watermark
    """
    ax = _ax(ax)
    kinds = kinds or [c[len("yield_"):-len("_pct")] for c in table.columns
                      if c.startswith("yield_") and c.endswith("_pct") and c != reference]
    for i, k in enumerate(kinds):
        col = f"yield_{k}_pct"
        if col == reference or col not in table:
            continue
        ax.plot(table[reference], table[col], "os^D"[i % 4], ms=4, label=k.upper().replace("_", " "))
    ax.plot([0, 100], [0, 100], "k-", lw=0.8)
    ax.set_xlabel(reference_label if reference_label is not None
                  else reference.replace("_", " "))
    ax.set_ylabel("surrogate-based yield [%]")
    ax.legend(fontsize=7)
    if synthetic:
        from analysis.plotting.marks import mark_synthetic
        mark_synthetic(ax)
    return ax


def write_surrogate_figures(folder, predictions: dict, learning_curve, source: str,
                            outputs=("v_mean_m_s", "f_col_hz")) -> list:
    """fig13_parity.png (:func:`plot_parity`, one column per surrogate kind, one row per
    output) and, with a learning curve, fig_learning_curve.png (:func:`plot_learning_curve`)
    into ``folder``.

    Parameters
    ----------
    folder : path of an existing folder
    predictions : dict kind -> DataFrame - each kind's predictions (split, <output>,
        <output>_pred)
    learning_curve : DataFrame or None - output, kind, n_train, mape_pct
    source : str - where the training data came from (the title; 'SYNTHETIC' in it marks
        the figures)
    outputs : the surrogate's outputs, one row of panels each

    Returns
    -------
    list of Path - the files written
    """
    plt = pyplot()
    folder = Path(folder)
    kinds = list(predictions)
    tag = "SYNTHETIC - " if "SYNTHETIC" in source else ""
    fig, axes = plt.subplots(2, len(kinds), figsize=(3.4 * len(kinds), 6.4), squeeze=False)
    for i, k in enumerate(kinds):
        for j, o in enumerate(outputs):
            plot_parity(predictions[k], o, ax=axes[j, i], title=f"{k.upper()} {o}")
    fig.suptitle(tag + "parity: " + source[:80], fontsize=8)
    fig.tight_layout()
    paths = [save_png(fig, folder / "fig13_parity.png", 120)]
    if learning_curve is not None:
        fig, axes = plt.subplots(1, 2, figsize=(8, 3.4))
        for j, o in enumerate(outputs):
            plot_learning_curve(learning_curve, o, ax=axes[j])
        fig.suptitle(tag + "learning curve", fontsize=9)
        fig.tight_layout()
        paths.append(save_png(fig, folder / "fig_learning_curve.png", 120))
    return paths


def write_yield_parity_figure(table: pd.DataFrame, path, surrogate_kinds, *,
                              twin_source: str, surrogate_source: str,
                              synthetic: bool = False):
    """Figure 14 written to ``path`` (PNG): surrogate-based yields against the twin-output
    yields (left) and every predicted yield against the measured - or SYNTHETIC - yields
    (right), both by :func:`plot_yield_parity`.

    Parameters
    ----------
    table : DataFrame - yield_twin_pct, yield_measured_pct, yield_<kind>_pct
        (analysis.predict.compare_yield_sources)
    surrogate_kinds : list of str - the surrogates compared (e.g. ['lr', 'rf', 'gp'])
    twin_source, surrogate_source : str - where the twin outputs and the surrogate came from
        (the title)
    synthetic : bool - the reference yields are synthetic: SYNTHETIC labels and watermark

    Returns
    -------
    path
    """
    plt = pyplot()
    kinds = list(surrogate_kinds)
    fig, axes = plt.subplots(1, 2, figsize=(8, 3.8))
    plot_yield_parity(table, ax=axes[0], reference="yield_twin_pct", kinds=kinds)
    axes[0].set_title("surrogate-MC vs twin-MC yield", fontsize=8)
    plot_yield_parity(table, ax=axes[1], reference="yield_measured_pct",
                      kinds=["twin"] + kinds,
                      reference_label=("SYNTHETIC yield [%] (stands in for measured)"
                                       if synthetic else "measured yield [%]"),
                      synthetic=synthetic)
    axes[1].set_title("SYNTHETIC yields vs predicted yield" if synthetic
                      else "measured vs predicted yield", fontsize=8)
    fig.suptitle(("SYNTHETIC yields; " if synthetic else "") + "twin outputs: "
                 + twin_source[:60] + "; surrogate: " + surrogate_source[:40], fontsize=7)
    fig.tight_layout()
    return save_png(fig, path, 120)
