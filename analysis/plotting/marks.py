"""Shared marks for figures: the SYNTHETIC mark, short condition and observable labels, and
whether column labels fit side by side."""
from __future__ import annotations

import textwrap

#: the word every figure and page made from synthetic data carries
SYNTHETIC = "SYNTHETIC"

#: short axis labels of the compared observables (units sit in the colour bar or the table)
SHORT_OBSERVABLES = {"v_mean_m_s": "v_mean", "f_col_hz": "f_col", "yield_pct": "yield",
                     "e_app": "e_app", "v_in_m_s": "v_in", "impact_phase_rad": "impact phase",
                     "jar_amplitude_m": "jar amplitude", "vy_rms_m_s": "vy_rms"}


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


def condition_label(frequency_hz, ball_diameter_mm) -> str:
    """Short condition label, e.g. '17.5 mm / 25 Hz'."""
    return "%g mm / %g Hz" % (float(ball_diameter_mm), float(frequency_hz))


def short_observable(name: str, width: int = 12) -> str:
    """Short label of an observable; an unknown long name is wrapped onto lines of ``width``."""
    s = SHORT_OBSERVABLES.get(name, name)
    if len(s) <= width:
        return s
    return "\n".join(textwrap.wrap(s.replace("_", " "), width)) or s


def fits_horizontally(ax, labels, fontsize: float, share: float = 0.8) -> bool:
    """Whether ``labels`` written horizontally fit side by side under ``ax``'s columns.

    An estimate at drawing time (average glyph width 0.62 em); ``share`` is the part of the
    axes width left after a colour bar and layout changes."""
    n = max(len(labels), 1)
    fig = ax.figure
    col_in = ax.get_position().width * fig.get_figwidth() * share / n
    longest = max((max(len(line) for line in str(s).split("\n")) for s in labels), default=0)
    return longest * 0.62 * fontsize / 72.0 < 0.85 * col_in

