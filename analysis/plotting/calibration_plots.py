"""Figures of calibration and sensitivity: parity, posterior pairs, Figure-8 grid, Sobol bars.

The ``plot_*`` functions take result tables and ``ax``/``axes`` (created when None) and return
the axes; :func:`write_calibration_figures` and :func:`write_sensitivity_figures` draw the PNG
files the CLIs of analysis.calibrate and analysis.sensitivity publish.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from analysis.plotting.files import pyplot, save_png


def _axes(ax, n=1, figsize=(5, 4)):
    import matplotlib.pyplot as plt
    if ax is not None:
        return ax
    fig, ax = plt.subplots(1, n, figsize=figsize)
    return ax


def plot_parity(comparison, axes=None):
    """Measured vs twin (v_mean and f_col), one point per condition, with the 1:1 line.

    Parameters
    ----------
    comparison : DataFrame - CalibrationResult.comparison (uses the *_twin_* columns when
        present, else the emulator's)
    axes : sequence of 2 Axes, optional

    Returns
    -------
    axes
    """
    axes = _axes(axes, 2, (9, 4.2))
    specs = [("v_mean", "m_s", "mean ball speed [m/s]"), ("f_col", "hz", "collision rate [1/s]")]
    for ax, (q, unit, label) in zip(axes, specs):
        meas = comparison["%s_measured_%s" % (q, unit)]
        twin = "%s_twin_%s" % (q, unit)
        src = "twin (posterior mean)" if twin in comparison else "emulator"
        if twin not in comparison:
            twin = "%s_emulator_%s" % (q, unit)
        sd = comparison.get("%s_twin_sd_%s" % (q, unit))
        d = comparison["ball_diameter_mm"]
        for dia, marker in zip(sorted(d.unique()), "os^v"):
            m = d == dia
            ax.errorbar(meas[m], comparison[twin][m],
                        yerr=None if sd is None else sd[m], fmt=marker, capsize=3,
                        label="%s, d = %.1f mm" % (src, dia))
        if q == "v_mean" and "v_mean_dem_paper_m_s" in comparison:
            ax.plot(meas, comparison["v_mean_dem_paper_m_s"], "x", color="grey",
                    label="paper DEM")
        lim = [min(meas.min(), comparison[twin].min()), max(meas.max(), comparison[twin].max())]
        pad = 0.05 * (lim[1] - lim[0] + 1e-9)
        lim = [lim[0] - pad, lim[1] + pad]
        ax.plot(lim, lim, "k-", lw=0.8)
        ax.set_xlim(lim)
        ax.set_ylim(lim)
        ax.set_xlabel("measured " + label)
        ax.set_ylabel("simulated " + label)
        ax.legend(fontsize=7)
    return axes


def plot_pairs(samples, names, bounds=None, truth=None, axes=None, bins=30):
    """Corner-style pair plot of posterior samples.

    Parameters
    ----------
    samples : array_like (ndarray or DataFrame), shape (n, k)
    names : list of str, length k
    bounds : dict name -> (lo, hi), optional - prior box (axis limits)
    truth : dict name -> value, optional - marked in red
    axes : ndarray of Axes, shape (k, k), optional

    Returns
    -------
    axes : ndarray, shape (k, k)
    """
    samples = np.asarray(samples, float)
    import matplotlib.pyplot as plt
    k = len(names)
    if axes is None:
        fig, axes = plt.subplots(k, k, figsize=(2.2 * k, 2.2 * k))
    axes = np.asarray(axes).reshape(k, k)
    for i in range(k):
        for j in range(k):
            ax = axes[i, j]
            if j > i:
                ax.set_visible(False)
                continue
            if i == j:
                ax.hist(samples[:, i], bins=bins, color="C0", histtype="stepfilled", alpha=0.6)
                q = np.quantile(samples[:, i], [0.025, 0.975])
                for v in q:
                    ax.axvline(v, color="C0", ls="--", lw=0.8)
                ax.set_yticks([])
            else:
                ax.hist2d(samples[:, j], samples[:, i], bins=bins, cmap="Blues")
                if truth is not None:
                    ax.plot(truth[names[j]], truth[names[i]], "r+", ms=10, mew=2)
                if bounds is not None:
                    ax.set_ylim(bounds[names[i]])
            if truth is not None and i == j:
                ax.axvline(truth[names[i]], color="r", lw=1.5)
            if bounds is not None:
                ax.set_xlim(bounds[names[j]])
            if i == k - 1:
                ax.set_xlabel(names[j], fontsize=8)
            else:
                ax.set_xticklabels([])
            if j == 0 and i > 0:
                ax.set_ylabel(names[i], fontsize=8)
            elif j > 0:
                ax.set_yticklabels([])
            ax.tick_params(labelsize=7)
    axes[0, 0].figure.tight_layout()
    return axes


def plot_figure8(grid, target_m_s=2.13, tol_m_s=None, axes=None):
    """The paper's Figure 8: mean +- sd of v_mean over the (C_R, SF, RF) grid.

    One panel per rolling_friction level, x = restitution, one line per static_friction level;
    the measured speed as a red line (and its tolerance band when ``tol_m_s`` is given);
    parameter sets reproducing it are circled.

    Parameters
    ----------
    grid : DataFrame - GridStudy.summary (restitution, static_friction, rolling_friction,
        v_mean_m_s_mean, v_mean_m_s_sd, matches)
    target_m_s : float - measured speed [m/s]
    tol_m_s : float, optional - half width of the "reproduces" band [m/s]

    Returns
    -------
    axes
    """
    levels = sorted(grid["rolling_friction"].unique())
    axes = _axes(axes, len(levels), (4 * len(levels), 3.8))
    axes = np.atleast_1d(axes)
    for ax, rf in zip(axes, levels):
        g = grid[grid["rolling_friction"] == rf]
        for n, (sf, gs) in enumerate(g.groupby("static_friction")):
            gs = gs.sort_values("restitution")
            ax.errorbar(gs["restitution"], gs["v_mean_m_s_mean"], yerr=gs["v_mean_m_s_sd"],
                        marker="os^vD"[n % 5], capsize=3, label="SF = %.2g" % sf)
            if "matches" in gs:
                m = gs["matches"].astype(bool)
                ax.plot(gs["restitution"][m], gs["v_mean_m_s_mean"][m], "o", ms=14,
                        mfc="none", mec="k")
        ax.axhline(target_m_s, color="r", lw=1)
        ax.plot([], [], "r-", label="measured %.2f m/s" % target_m_s)
        if tol_m_s:
            ax.axhspan(target_m_s - tol_m_s, target_m_s + tol_m_s, color="r", alpha=0.1)
        ax.set_title("RF = %.2g" % rf)
        ax.set_xlabel("restitution C_R [-]")
        ax.set_ylabel("v_mean [m/s]")
    axes[0].legend(fontsize=7)
    return axes


def plot_sobol(sobol_frame, ax=None):
    """Bar chart of first-order and total Sobol indices with their confidence intervals.

    Parameters
    ----------
    sobol_frame : DataFrame - SobolResult.to_frame() (index parameter; S1, S1_conf, ST,
        ST_conf)
    """
    ax = _axes(ax)
    x = np.arange(len(sobol_frame))
    ax.bar(x - 0.18, sobol_frame["S1"], 0.36, yerr=sobol_frame["S1_conf"], capsize=3,
           label="first order S1")
    ax.bar(x + 0.18, sobol_frame["ST"], 0.36, yerr=sobol_frame["ST_conf"], capsize=3,
           label="total ST")
    ax.set_xticks(x)
    ax.set_xticklabels(sobol_frame.index, rotation=20)
    ax.set_ylabel("Sobol index")
    ax.legend(fontsize=8)
    return ax


def write_calibration_figures(result, folder):
    """parity.png and posterior_pairs.png of a calibration into ``folder``.

    Parameters
    ----------
    result : CalibrationResult - uses comparison, samples, params (the names) and bounds
    folder : path of an existing folder

    Returns
    -------
    list of Path - the files written
    """
    plt = pyplot()
    folder = Path(folder)
    fig, axes = plt.subplots(1, 2, figsize=(9, 4.2))
    plot_parity(result.comparison, axes=axes)
    fig.tight_layout()
    paths = [save_png(fig, folder / "parity.png", 130)]
    axes = plot_pairs(result.samples, list(result.params.index), bounds=result.bounds)
    paths.append(save_png(axes[0, 0].figure, folder / "posterior_pairs.png", 110))
    return paths


def write_sensitivity_figures(grid, target_m_s, tol_m_s, sobol_frame, folder):
    """figure8.png (:func:`plot_figure8`) and sobol_v_mean.png (:func:`plot_sobol`) into
    ``folder``.

    Parameters
    ----------
    grid : DataFrame - GridStudy.summary
    target_m_s : float - measured speed [m/s]
    tol_m_s : float or None - half width of the "reproduces" band [m/s]
    sobol_frame : DataFrame - SobolResult.to_frame()
    folder : path of an existing folder

    Returns
    -------
    list of Path - the files written
    """
    pyplot()
    folder = Path(folder)
    axes = plot_figure8(grid, target_m_s, tol_m_s)
    axes[0].figure.tight_layout()
    paths = [save_png(axes[0].figure, folder / "figure8.png", 130)]
    ax = plot_sobol(sobol_frame)
    ax.figure.tight_layout()
    paths.append(save_png(ax.figure, folder / "sobol_v_mean.png", 130))
    return paths
