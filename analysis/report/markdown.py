"""Markdown building blocks shared by the study pages and the stage pages: number formatting,
tables, the SYNTHETIC banner, and the atomic write of one page file."""
from __future__ import annotations

from pathlib import Path

import numpy as np


def is_number(x):
    """``x`` is a finite number (or a string / numpy value that parses as one)."""
    try:
        return x is not None and np.isfinite(float(x))
    except (TypeError, ValueError):
        return False


def fmt(x, nd=3):
    """A number with ``nd`` decimals, '-' for empty or NaN."""
    return f"{float(x):.{nd}f}" if is_number(x) else "-"


def fmt_signed(x, nd=2):
    return f"{float(x):+.{nd}f}" if is_number(x) else "-"


def md_table(headers, rows):
    """A Markdown table; ``rows`` are sequences of already formatted cells ('|' is escaped)."""
    def cell(c):
        return str(c).replace("|", "\\|").replace("\n", " ")
    lines = ["| " + " | ".join(headers) + " |", "|" + "---|" * len(headers)]
    lines += ["| " + " | ".join(cell(c) for c in r) + " |" for r in rows]
    return "\n".join(lines)


def frame_table_lines(df, cols, fmt="%.4g"):
    """The Markdown table of columns ``cols`` of a DataFrame as a list of lines: floats with
    ``fmt``, everything else with ``str`` (cells are not escaped)."""
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for _, r in df.iterrows():
        lines.append("| " + " | ".join((fmt % r[c]) if isinstance(r[c], (float, np.floating))
                                        else str(r[c]) for c in cols) + " |")
    return lines


def synthetic_banner(what):
    return f"> **SYNTHETIC DATA**: {what}"


def has_tabulate():
    """pandas' ``to_markdown`` needs the optional package tabulate."""
    try:
        import tabulate  # noqa: F401
        return True
    except ImportError:
        return False


def write_atomic(path, text):
    """Write ``text`` to a temporary file beside ``path`` and rename it over ``path``."""
    from analysis.atomic_dir import atomic_file
    path = Path(path)
    with atomic_file(path) as tmp:
        tmp.write_text(text)
    return path
