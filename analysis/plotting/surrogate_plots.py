"""Plots of the surrogate stage (paper Figures 13 and 14). Functions take results, ax=None,
return the axes."""
from __future__ import annotations

import numpy as np
import pandas as pd


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
