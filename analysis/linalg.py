"""Linear algebra the fits ask ~10^5 times, without the per-call checks of the general
functions: the same LAPACK calls, so the same bits."""
from __future__ import annotations

import numpy as np
from scipy.linalg import get_lapack_funcs

_TRTRS = get_lapack_funcs(("trtrs",), (np.empty((1, 1)),))[0]


def solve_lower(L, b):
    """L^-1 b for a lower-triangular float64 L and a float64 b of one or more columns: the
    LAPACK call ``scipy.linalg.solve_triangular(L, b, lower=True)`` makes (trtrs; a C-ordered
    L as its transpose's upper system), without its validation."""
    if b.size == 0:
        return np.empty_like(b)
    if L.flags.f_contiguous:
        x, info = _TRTRS(L, b, lower=1, trans=0)
    else:
        x, info = _TRTRS(L.T, b, lower=0, trans=1)
    if info != 0:
        raise np.linalg.LinAlgError("triangular solve failed (LAPACK info %d)" % info)
    return x
