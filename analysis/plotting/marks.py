"""Shared marks for figures: the SYNTHETIC mark."""
from __future__ import annotations

#: the word every figure and page made from synthetic data carries
SYNTHETIC = "SYNTHETIC"


def is_synthetic(dataset=None, synthetic=None) -> bool:
    """The explicit ``synthetic`` flag when given, else what the dataset says about itself
    (``Dataset.synthetic``, i.e. dataset.json ``"synthetic": true``); False without either."""
    if synthetic is not None:
        return bool(synthetic)
    return bool(getattr(dataset, "synthetic", False))


def synthetic_title(title: str, synthetic: bool) -> str:
    """``title`` with a trailing ' [SYNTHETIC data]' when the data are synthetic."""
    if not synthetic or SYNTHETIC in title:
        return title
    return (title + " " if title else "") + "[%s data]" % SYNTHETIC


def mark_synthetic(ax, synthetic: bool = True):
    """A faint diagonal SYNTHETIC watermark across the axes (kept when a caller replaces the
    title). Returns the text artist, or None when the data are not synthetic."""
    if not synthetic:
        return None
    return ax.text(0.5, 0.5, SYNTHETIC, transform=ax.transAxes, ha="center", va="center",
                   rotation=25, fontsize=28, fontweight="bold", color="0.5", alpha=0.22,
                   zorder=10, gid="synthetic-mark")
