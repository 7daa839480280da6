"""Figure of the signature library (analysis.twin_model.library): how much each DEM effect
changes the twin's mean ball speed at every condition."""
from __future__ import annotations

import math

import numpy as np

from analysis.plotting.files import pyplot, save_png


def plot_signatures(top, ax=None):
    """Bar chart: change of v_mean [%] per condition for every DEM effect at its signature
    strength, with the anchor's +-2 se band (of a difference of two runs' means).

    Parameters
    ----------
    top : DataFrame - the library summary at each label's largest strength
        (analysis.twin_model.top_level): label ('none' is the anchor), condition_id, dv_pct,
        v_mean_m_s, v_sd_m_s, n
    """
    if ax is None:
        import matplotlib.pyplot as plt
        _, ax = plt.subplots()
    labels = [c for c in top["label"].unique() if c != "none"]
    cids = list(top.loc[top["label"] == "none", "condition_id"])
    a = top[top["label"] == "none"].set_index("condition_id")
    rel_se = float(np.nanmean(a["v_sd_m_s"] / a["v_mean_m_s"])) / math.sqrt(a["n"].mean())
    w = 0.8 / max(len(labels), 1)
    x = np.arange(len(cids))
    for i, lab in enumerate(labels):
        d = top[top["label"] == lab].set_index("condition_id").loc[cids]
        ax.bar(x + (i - (len(labels) - 1) / 2) * w, d["dv_pct"], w, label=lab)
    band = 2 * 100 * rel_se * math.sqrt(2)
    ax.axhspan(-band, band, color="0.85", zorder=0, label="+-2 se of a difference")
    ax.set_xticks(x, cids, rotation=30, ha="right")
    ax.set_ylabel("change of v_mean [%]")
    ax.set_title("Effect signatures at the calibrated parameters (signature strengths)")
    ax.legend(fontsize=7, ncol=2)
    return ax


def write_signatures_figure(top, path):
    """:func:`plot_signatures` written to ``path`` (PNG); returns ``path``."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(9, 4))
    plot_signatures(top, ax=ax)
    fig.tight_layout()
    return save_png(fig, path, 120)
