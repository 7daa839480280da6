"""Figures of the loop on blind open-world datasets (:mod:`analysis.open_suite`): the fitted
strengths against the hidden truth with their 95 % intervals, and each dataset's chi2/dof
before and after the loop beside the twin's own rerun."""
from __future__ import annotations

import numpy as np

from analysis.plotting.files import pyplot, save_png
from analysis.plotting.marks import synthetic_title

#: one colour per hidden-effect family of the catalog (others: grey)
EFFECT_COLOURS = {"arc_motion": "tab:blue", "jar_compliance": "tab:orange",
                  "viscoelastic_restitution": "tab:green", "powder_layer": "tab:red",
                  "smoothing_window": "tab:purple", "apparent_scale": "tab:brown"}


def strength_points(summ, s_max) -> list:
    """(effect, true, fit, lo, hi) of every found hidden effect in the summary table - the
    interval the summary scored (``<effect>_lo`` / ``_hi``: the profile interval, else
    +- 1.96 se) - each as a fraction of its ``s_max`` (effect -> top of its diagnose range)."""
    out = []
    for _, r in summ.iterrows():
        for k, top in s_max.items():
            fit = r.get("%s_fit" % k)
            if fit is None or not np.isfinite(float(fit)):
                continue
            lo, hi = r.get("%s_lo" % k), r.get("%s_hi" % k)
            if lo is None or not np.isfinite(float(lo)):
                se = float(r["%s_se" % k])
                lo, hi = float(fit) - 1.96 * se, float(fit) + 1.96 * se
            out.append((k, float(r["%s_true" % k]) / top, float(fit) / top, float(lo) / top,
                        float(hi) / top))
    return out


def plot_strengths(summ, s_max, ax, *, synthetic: bool = True):
    """Fitted strength (with its 95 % interval) against the true one, both as fractions of the
    effect's diagnose range; the diagonal is a perfect fit."""
    pts = strength_points(summ, s_max)
    for k, t, f, lo, hi in pts:
        ax.errorbar(t, f, yerr=[[max(f - lo, 0.0)], [max(hi - f, 0.0)]], fmt="o", ms=5,
                    capsize=3, color=EFFECT_COLOURS.get(k, "0.5"))
    for k, c in EFFECT_COLOURS.items():
        if any(p[0] == k for p in pts):
            ax.plot([], [], "o", color=c, label=k)
    top = max([1.0] + [max(t, hi) for _, t, f, lo, hi in pts])
    ax.plot([0, top], [0, top], "k--", lw=0.8)
    ax.set_xlim(0, top)
    ax.set_ylim(min([0.0] + [lo for _, t, f, lo, hi in pts]), top)
    ax.set_xlabel("hidden strength [fraction of the diagnose range]")
    ax.set_ylabel("fitted strength, 95 % interval")
    cov = sum(lo <= t <= hi for _, t, f, lo, hi in pts)
    ax.set_title(synthetic_title("Strengths: %d of %d intervals cover the truth"
                                 % (cov, len(pts)), synthetic), fontsize=9)
    if pts:
        ax.legend(fontsize=7, loc="upper left")
    return ax


def plot_chi2(summ, ax, *, synthetic: bool = True, fits_at: float = 1.5):
    """chi2/dof of each dataset: calibrated without effects, after the loop's last add, and the
    twin rerun at the final point; grouped by how many effects were
    hidden; the line at ``fits_at`` is the suite's 'fits' goal."""
    order = summ.sort_values(["n_hidden", "dataset"]).reset_index(drop=True)
    x = np.arange(len(order))
    marks = (("chi2_dof_calibrated", "calibrated, no effect", "s", "0.6"),
             ("chi2_dof_last", "after the last add", "o", "k"),
             ("chi2_dof_twin_rerun", "twin rerun, final point", "x", "tab:green"))
    for col, lab, m, c in marks:
        if col in order:
            ax.plot(x, order[col].to_numpy(float), m, color=c, ms=5, label=lab, ls="none")
    ax.axhline(fits_at, color="tab:red", lw=0.8, ls="--")
    ax.axhline(1.0, color="0.7", lw=0.6)
    ax.set_yscale("log")
    from matplotlib.ticker import FormatStrFormatter, LogLocator
    ax.yaxis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
    ax.yaxis.set_major_formatter(FormatStrFormatter("%g"))
    ax.yaxis.set_minor_formatter(FormatStrFormatter(""))
    ax.set_xticks(x, ["%s (%d)" % (d, n) for d, n in zip(order["dataset"], order["n_hidden"])],
                  rotation=70, fontsize=6)
    ax.set_ylabel("chi2 / dof")
    ax.set_title(synthetic_title("Fit per dataset (hidden effects in brackets)", synthetic),
                 fontsize=9)
    ax.legend(fontsize=7)
    return ax


def write_open_suite_figure(summ, s_max, path, *, synthetic: bool = True):
    """:func:`plot_strengths` beside :func:`plot_chi2`, written to ``path`` (PNG); returns
    ``path``."""
    plt = pyplot()
    fig, (a, b) = plt.subplots(1, 2, figsize=(12, 4.8),
                               gridspec_kw={"width_ratios": [1, 1.6]})
    plot_strengths(summ, s_max, a, synthetic=synthetic)
    plot_chi2(summ, b, synthetic=synthetic)
    fig.tight_layout()
    return save_png(fig, path, 110)
