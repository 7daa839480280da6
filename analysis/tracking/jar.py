"""Follow the jar through a lab-frame video by its two end walls -> ``jar_x_m``.

In a band of rows just inside the jar's bottom wall (found as the darker of the frame's two
darkest rows, or given) the mean grey profile shows the two end walls as dark dips; each is
followed by its darkness-weighted centroid (sub-pixel: 0.02 px rms on the synthetic films), the
jar's x is their mean, written as ``jar_x_m`` (zero-mean), which :mod:`analysis.flights` needs
for the impact observables (``python -m analysis.tracking VIDEO --jar``).
"""
from __future__ import annotations

import numpy as np

from analysis.tracking.errors import JarNotFoundError
from analysis.tracking.video import iter_gray, open_video


def jar_band(gray: np.ndarray, inset_frac: float = 0.12):
    """(row0, row1) of a band just inside the jar's bottom wall, where its two end walls cross
    and the ball, flying near the jar's axis, seldom comes: the jar's top and bottom walls are
    the two darkest rows of the frame (their lines span the whole jar; an occluder or the ball
    darkens only part of a row)."""
    g = np.asarray(gray, float)
    dark = np.median(g) - g.mean(axis=1)
    rows = np.argsort(dark)[::-1]
    top = int(rows[0])
    far = [r for r in rows[1:] if abs(int(r) - top) > 0.1 * g.shape[0]]
    if not far:
        raise JarNotFoundError("no two dark horizontal jar walls in the first frame")
    a, b = sorted((top, int(far[0])))
    h = b - a
    r1 = b - 3
    r0 = max(a + 1, int(round(b - inset_frac * h)))
    if r1 - r0 < 2:
        raise JarNotFoundError("the jar is too small in the frame (%d px between its walls)" % h)
    return r0, r1


def _dip_centroid(p: np.ndarray, c: float, half: int, level: float, width: int = 4):
    """Sub-pixel centre of a dark dip of profile ``p`` near column ``c``: its darkest column
    within ``half`` px of ``c``, then the darkness-weighted (level - p, >= 0) centroid of the
    columns within ``width`` px of that (the whole dip with its anti-aliased edges)."""
    i0, i1 = max(0, int(round(c)) - half), min(len(p), int(round(c)) + half + 1)
    if i1 <= i0:
        return np.nan
    m = i0 + int(np.argmin(p[i0:i1]))
    j0, j1 = max(0, m - width), min(len(p), m + width + 1)
    d = np.maximum(level - p[j0:j1], 0.0)
    if d.sum() <= 0:
        return np.nan
    return float(j0 + np.sum(d * np.arange(len(d))) / np.sum(d))


def track_jar(frames, m_per_px: float, band=None, max_step_px: float = 12.0):
    """Jar displacement along x per frame [m], from its two end walls.

    In a band of rows (default :func:`jar_band` of the first frame) each frame's mean grey over
    the band is a profile with two dark dips, the end walls; each is followed by its
    darkness-weighted centroid (sub-pixel), the jar's position is their mean. Returns
    (jar_x_m, info): displacement relative to the record's mean (the twin's jar_x_m is zero-mean
    too), NaN where a wall was lost; info holds the band, the walls' first columns and the
    length between them [px]."""
    it = iter(frames)
    try:
        first = np.asarray(next(it), float)
    except StopIteration:
        raise JarNotFoundError("no frame") from None
    if first.ndim == 3:
        first = first.mean(axis=2)
    r0, r1 = band if band is not None else jar_band(first)
    if not (0 <= r0 < r1 <= first.shape[0]):
        raise JarNotFoundError("jar band rows %s outside the frame (height %d)"
                               % ((r0, r1), first.shape[0]))
    p = first[r0:r1].mean(axis=0)
    level = float(np.median(p))
    dark = level - p
    order = np.argsort(dark)[::-1]
    c1 = int(order[0])
    rest = [int(i) for i in order[1:] if abs(int(i) - c1) > 0.1 * len(p)]
    if not rest or dark[rest[0]] < 0.3 * dark[c1]:
        raise JarNotFoundError("rows %d-%d: not two dark jar end walls" % (r0, r1))
    caps = sorted((c1, rest[0]))
    half = int(max(4, max_step_px))
    pos = [[_dip_centroid(p, c, half, level) for c in caps]]
    for g in it:
        g = np.asarray(g, float)
        if g.ndim == 3:
            g = g.mean(axis=2)
        q = g[r0:r1].mean(axis=0)
        lv = float(np.median(q))
        prev = pos[-1]
        cur = []
        for k, c in enumerate(prev):
            guess = c if np.isfinite(c) else next((x[k] for x in reversed(pos)
                                                   if np.isfinite(x[k])), caps[k])
            cur.append(_dip_centroid(q, guess, half, lv))
        pos.append(cur)
    P = np.array(pos, float)
    x_px = P.mean(axis=1)
    length = P[:, 1] - P[:, 0]
    bad = ~np.isfinite(length) | (np.abs(length - np.nanmedian(length)) > 2.0)
    x_px[bad] = np.nan
    x_m = (x_px - np.nanmean(x_px)) * m_per_px
    return x_m, {"band_rows": (int(r0), int(r1)), "wall_px": caps,
                 "length_px": float(np.nanmedian(length)), "n_lost": int(bad.sum())}


def track_jar_video(path, m_per_px: float, band=None):
    """:func:`track_jar` on a video file."""
    cap = open_video(path)
    try:
        return track_jar(iter_gray(cap), m_per_px, band=band)
    finally:
        cap.release()
