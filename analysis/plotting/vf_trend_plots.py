"""The figure of :mod:`analysis.studies.vf_trend`: each variant's change of v/f from 22.5 to
30 Hz for both balls with its standard error, beside the paper's EDEM column."""
from __future__ import annotations

import numpy as np

from analysis.plotting.files import pyplot, save_png

BALL_COLOURS = {17.5: "tab:blue", 20.6: "tab:orange"}


def write_vf_trend_figure(trend, path, edem, match_points):
    """Left: change of v/f [%] per variant (rows), both balls, bars +- 1 se; EDEM's changes as
    dashed lines (``edem``: {ball diameter [mm]: change [%]}). Right: the 17.5 mm ball's change
    against the 20.6 mm ball's, EDEM's pair with the +- ``match_points`` box. Returns ``path``."""
    MATCH_POINTS = match_points
    plt = pyplot()
    names = list(dict.fromkeys(trend.loc[trend["runs_done"] > 0, "variant"]))
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(13, 0.32 * len(names) + 2.6),
                                 gridspec_kw={"width_ratios": [1.35, 1]})
    y = np.arange(len(names))[::-1]
    for k, (d, off) in enumerate(((17.5, 0.13), (20.6, -0.13))):
        t = trend[trend["ball_diameter_mm"] == d].set_index("variant").reindex(names)
        c = BALL_COLOURS[d]
        ax.errorbar(t["change_pct"], y + off, xerr=t["se_pct"], fmt="o", color=c, ms=4,
                    capsize=2, label="%.1f mm ball (+- 1 se)" % d)
        ax.axvline(edem[d], color=c, ls="--", lw=1.2,
                   label="EDEM %.1f mm: %+.1f %%" % (d, edem[d]))
    ax.axvline(0, color="0.6", lw=0.8)
    ax.set_yticks(y)
    ax.set_yticklabels(names, fontsize=8)
    ax.set_xlabel("change of v/f from 22.5 to 30 Hz [%]")
    ax.legend(fontsize=7, loc="lower right")
    ax.grid(axis="x", alpha=0.3)
    w = trend.pivot(index="variant", columns="ball_diameter_mm")
    for i, name in enumerate(names):
        if name not in w.index:
            continue
        x, yy = w.loc[name, ("change_pct", 17.5)], w.loc[name, ("change_pct", 20.6)]
        bx.errorbar(x, yy, xerr=w.loc[name, ("se_pct", 17.5)],
                    yerr=w.loc[name, ("se_pct", 20.6)], fmt="o", ms=4, capsize=2,
                    color="k" if name == "default" else "tab:gray")
        if np.isfinite(x) and np.isfinite(yy):
            bx.annotate(str(i + 1), (x, yy), fontsize=7, xytext=(3, 3),
                        textcoords="offset points")
    e17, e20 = edem[17.5], edem[20.6]
    bx.plot([e17], [e20], "r*", ms=12, label="EDEM (%+.1f %%, %+.1f %%)" % (e17, e20))
    bx.add_patch(plt.Rectangle((e17 - MATCH_POINTS, e20 - MATCH_POINTS), 2 * MATCH_POINTS,
                               2 * MATCH_POINTS, fill=False, ec="r", ls=":",
                               label="+- %g points" % MATCH_POINTS))
    bx.axhline(0, color="0.6", lw=0.8)
    bx.axvline(0, color="0.6", lw=0.8)
    bx.set_xlabel("17.5 mm ball: change of v/f [%]")
    bx.set_ylabel("20.6 mm ball: change of v/f [%]")
    bx.set_title("numbers: rows of the left panel, top = 1", fontsize=8)
    bx.legend(fontsize=7, loc="upper left")
    bx.grid(alpha=0.3)
    fig.suptitle("v/f from 22.5 to 30 Hz, one change at a time from the default twin "
                 "(paper contact parameters)", fontsize=10)
    fig.tight_layout()
    return save_png(fig, path, dpi=110)
