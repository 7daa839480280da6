"""Figure files: matplotlib on its file backend (Agg) and PNGs written and closed. The
``write_*`` functions of this package use these; the compute modules never touch matplotlib."""
from __future__ import annotations


def pyplot():
    """``matplotlib.pyplot`` on the Agg backend (files only, no window)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def save_png(fig, path, dpi: int, metadata: dict | None = None):
    """Write ``fig`` to ``path`` as PNG at ``dpi`` [dots per inch] and close it; returns
    ``path``. ``metadata``: PNG text chunks (e.g. {"Title": ..., "Description": ...})."""
    import matplotlib.pyplot as plt
    fig.savefig(path, dpi=dpi, metadata=metadata)
    plt.close(fig)
    return path
