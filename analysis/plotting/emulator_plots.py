"""Figures of the emulator check (:mod:`analysis.studies.emulator_check`)."""
from __future__ import annotations

import numpy as np

from analysis.plotting.files import pyplot, save_png


def emulator_check_figure(per_run, path, fake=False):
    """Held-out twin runs against the emulator, one panel per observable: the prediction with
    its 95 % interval of a new run (bars) against the twin's value, and the z histogram."""
    plt = pyplot()
    obs = [] if per_run is None or not len(per_run) else list(dict.fromkeys(per_run.observable))
    n = max(len(obs), 1)
    fig, axes = plt.subplots(2, n, figsize=(2.6 * n, 5.2), squeeze=False)
    for j, o in enumerate(obs):
        d = per_run[per_run.observable == o]
        ax = axes[0, j]
        ax.errorbar(d.twin, d.predicted, yerr=1.96 * d.sd, fmt="o", ms=2.5, lw=0.6,
                    alpha=0.6, color="tab:blue")
        lo = float(np.nanmin([d.twin.min(), d.predicted.min()]))
        hi = float(np.nanmax([d.twin.max(), d.predicted.max()]))
        ax.plot([lo, hi], [lo, hi], "k-", lw=0.8)
        ax.set_title(o, fontsize=8)
        ax.set_xlabel("twin run", fontsize=7)
        if j == 0:
            ax.set_ylabel("emulator (95 % of a new run)", fontsize=7)
        ax.tick_params(labelsize=6)
        cov = float(np.mean(np.abs(d.z) <= 1.96))
        axes[1, j].hist(np.clip(d.z, -6, 6), bins=np.linspace(-6, 6, 25), color="tab:gray")
        axes[1, j].set_title("z: covered %.0f %%, <z^2> %.2f" % (100 * cov, np.mean(d.z ** 2)),
                             fontsize=7)
        axes[1, j].tick_params(labelsize=6)
    fig.suptitle(("FAKE twin - " if fake else "")
                 + "emulator against held-out twin runs", fontsize=9)
    fig.tight_layout()
    return save_png(fig, path, dpi=110)
