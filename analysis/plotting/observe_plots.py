"""Plots of the observation operator (take results, ax=None, return the axes; draw nothing else).

* :func:`plot_velocity_collisions` - the paper's Figure 5: raw and smoothed x-velocity with the
  detected collisions.
* :func:`plot_noise_blur_study` - tracking RMS error and v_mean error against noise / blur.
"""
from __future__ import annotations

import numpy as np


def _axes(ax):
    if ax is None:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        _, ax = plt.subplots(figsize=(7, 3))
    return ax


def plot_velocity_collisions(result, ax=None, t_window_s=None):
    """Raw (grey) and smoothed (red) x-velocity, collisions as black circles (cf. Figure 5).

    Parameters
    ----------
    result : analysis.observe.ObservationResult
    t_window_s : (t0, t1), optional
        Time range to show [s].
    """
    ax = _axes(ax)
    t = result.t_s
    sel = np.ones(len(t), bool) if t_window_s is None else (t >= t_window_s[0]) & (t <= t_window_s[1])
    ax.plot(t[sel], result.vx_raw_m_s[sel], color="0.6", lw=0.8, label="finite difference")
    ax.plot(t[sel], result.vx_m_s[sel], color="tab:red", lw=1.2, label="Savitzky-Golay")
    ct = result.collision_times_s
    if t_window_s is not None:
        ct = ct[(ct >= t_window_s[0]) & (ct <= t_window_s[1])]
    ax.plot(ct, np.zeros_like(ct), "o", mfc="none", mec="k", label="collisions")
    ax.set_xlabel("t [s]")
    ax.set_ylabel("v_x [m/s]")
    ax.legend(loc="upper right", fontsize=8)
    return ax


def plot_noise_blur_study(df, ax=None, x="noise_sigma", y="rms_px"):
    """One line per frequency of ``y`` against ``x`` from the noise/blur study table."""
    ax = _axes(ax)
    for f, g in df.groupby("frequency_hz"):
        g = g.sort_values(x).drop_duplicates(x)
        ax.plot(g[x], g[y], "o-", label=f"{f:g} Hz")
    ax.set_xlabel(x)
    ax.set_ylabel(y)
    ax.legend(fontsize=8)
    return ax
