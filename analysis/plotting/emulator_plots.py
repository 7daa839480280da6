"""Figures of the emulator check (:mod:`analysis.studies.emulator_check`)."""
from __future__ import annotations

import numpy as np

from analysis.plotting.files import pyplot, save_png


def emulator_check_figure(per_run, path, fake=False):
    """Twin runs left out against the model, one panel per observable: the mixture's mean
    against the twin's value (colour: the run's motion mode), and the z = Phi^-1(PIT) histogram
    of the mixture beside that of one GP across the modes."""
    plt = pyplot()
    mix = per_run[per_run.model == "mixture"] if "model" in per_run else per_run
    obs = list(dict.fromkeys(mix.observable)) if len(mix) else []
    n = max(len(obs), 1)
    fig, axes = plt.subplots(2, n, figsize=(2.6 * n, 5.2), squeeze=False)
    colours = dict(zip(sorted(set(mix["mode"])), ("tab:blue", "tab:red", "tab:green",
                                                  "tab:gray")))
    for j, o in enumerate(obs):
        d = mix[mix.observable == o]
        ax = axes[0, j]
        for k, c in colours.items():
            e = d[d["mode"] == k]
            ax.plot(e.twin, e.predicted, "o", ms=2.5, alpha=0.6, color=c, label=k)
        lo = float(np.nanmin([d.twin.min(), d.predicted.min()]))
        hi = float(np.nanmax([d.twin.max(), d.predicted.max()]))
        ax.plot([lo, hi], [lo, hi], "k-", lw=0.8)
        ax.set_title(o, fontsize=8)
        ax.set_xlabel("twin run", fontsize=7)
        if j == 0:
            ax.set_ylabel("mixture mean (left out)", fontsize=7)
            ax.legend(fontsize=6)
        ax.tick_params(labelsize=6)
        bins = np.linspace(-6, 6, 25)
        title = []
        for name, colour in (("mixture", "tab:blue"), ("one GP", "tab:gray")):
            z = per_run[(per_run.get("model", "mixture") == name)
                        & (per_run.observable == o)].z if "model" in per_run else d.z
            if not len(z):
                continue
            axes[1, j].hist(np.clip(z, -6, 6), bins=bins, color=colour, alpha=0.5, label=name)
            title.append("%s %.0f %%" % (name, 100 * np.mean(np.abs(z) <= 1.96)))
        axes[1, j].set_title("covered: " + ", ".join(title), fontsize=6)
        axes[1, j].tick_params(labelsize=6)
        if j == 0:
            axes[1, j].legend(fontsize=6)
            axes[1, j].set_xlabel("z = Phi^-1(PIT)", fontsize=7)
    fig.suptitle(("FAKE twin - " if fake else "")
                 + "the loop's model against twin runs it never saw", fontsize=9)
    fig.tight_layout()
    return save_png(fig, path, dpi=110)
