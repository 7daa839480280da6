"""Figure of analysis.demo: the twin's mean ball speed at the paper's 8 conditions beside the
measured speeds and the paper's DEM (Table 3)."""
from __future__ import annotations

from analysis.plotting.files import pyplot, save_png


def plot_demo(table, ax=None):
    """v_mean over frequency: measured, the paper's DEM and this twin (mean +- sd).

    Parameters
    ----------
    table : DataFrame - the demo's comparison table (ball_diameter_mm, frequency_hz,
        v_mean_measured_m_s, v_mean_dem_paper_m_s, v_mean_twin_observed_m_s,
        v_mean_twin_sd_m_s)
    ax : Axes, optional - the current axes when None
    """
    import matplotlib.pyplot as plt
    if ax is None:
        ax = plt.gca()
    colors = {17.5: "tab:green", 20.6: "tab:blue"}
    for d, g in table.groupby("ball_diameter_mm"):
        g = g.sort_values("frequency_hz")
        c = colors.get(d, "k")
        ax.plot(g["frequency_hz"], g["v_mean_measured_m_s"], "s", color=c, ms=7,
                label="measured, %.1f mm" % d)
        ax.plot(g["frequency_hz"], g["v_mean_dem_paper_m_s"], "^", color=c, mfc="none",
                label="paper DEM (EDEM), %.1f mm" % d)
        ax.errorbar(g["frequency_hz"], g["v_mean_twin_observed_m_s"], yerr=g["v_mean_twin_sd_m_s"],
                    fmt="o-", color=c, alpha=0.8, capsize=3, label="this twin, %.1f mm" % d)
    ax.set_xlabel("frequency f [Hz]")
    ax.set_ylabel("mean ball speed v_mean [m/s]")
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    return ax


def write_demo_figure(table, path):
    """:func:`plot_demo` titled 'MM400 twin vs Table 3 (paper contact parameters)', written to
    ``path`` (PNG); returns ``path``."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6, 4.2))
    plot_demo(table, ax)
    ax.set_title("MM400 twin vs Table 3 (paper contact parameters)")
    fig.tight_layout()
    return save_png(fig, path, 120)
