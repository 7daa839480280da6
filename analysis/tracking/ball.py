"""Follow one ball through a high-speed video: video -> track CSV (t_s, x_m, y_m, quality).

As in the seed paper (Sec. 2.5) the ball is followed by OpenCV's MOSSE correlation tracker
(cv2.legacy.TrackerMOSSE_create), initialised by a detector; here the detector is a Hough circle
transform on the grey frame (radius range from the expected ball size). MOSSE gives an integer,
drift-prone box (here on a frame decimated to a ~32 px box of 2.5 ball diameters), so every
frame the centre is refined to sub-pixel accuracy:

* edge points: each row's outermost crossings (left, right) of a grey level half-way between
  background and ball (Otsu threshold), and each column's (top, bottom), linearly interpolated
  between pixels. The default ('band', :class:`BandRim`) reads them on short profiles across
  the expected rim only, every 2nd row / column, all in one gather from precomputed offsets
  (~5x faster than a scan of the whole window, the earlier default 'crossings', which remains
  selectable and serves frames near the image border and re-acquisition; the scale frames read
  every row and column with the window scan's level, hence its very points);
* a circle fitted to those points (algebraic least squares), re-fitted without outliers
  (3 x MAD of the radial residuals) when some point is more than 0.5 px off: a bar or a wall
  hiding part of the rim, or a highlight, does not pull the centre.

The rim fit starts from the constant-velocity prediction of the last two sub-pixel centres (off
by a few px at most, at impacts); MOSSE, updated every ``mosse_every``-th frame (default 4: an
update costs as much as the whole rim fit), supplies the second guess and the check: if the fit
fails around both, or is more than 0.5 radii from the prediction, or its radius is off by
> 15 %, the detector re-acquires the ball (quality 'reacquired') and MOSSE is re-initialised
there; MOSSE is also re-anchored when it fails its PSR test or lies more than 0.3 ball radii from
the refined centre, and every ``reinit_every`` frames to stop template drift. A frame where no
valid circle is found is 'lost' (x, y NaN) - never interpolated; the observation operator treats
such rows as gaps.

Scale: ``m_per_px`` if given, else from the ball diameter as the paper does: the median over
the first frames of the ball's diameter in pixels, measured on the top and bottom arcs only
(motion blur along the jar axis stretches the left/right rims, not the top/bottom).

Output y_m points up (image rows run down): y_m = (height - 1 - y_px) * m_per_px.

The frames come from :mod:`analysis.tracking.video`; with ``jar=True`` :func:`track_video` also
follows the jar (:mod:`analysis.tracking.jar`).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from analysis.tracking.errors import BallNotFoundError, TrackingError, VideoReadError
from analysis.tracking.jar import track_jar_video
from analysis.tracking.video import (declared_fps_from, decode_ahead, fps_mismatch, load_cv2,
                                     open_video, read_sidecar)


#: Rim-point methods of :class:`TrackerSettings` (the first is the default).
RIM_METHODS = ("band", "crossings", "contour")


@dataclass
class TrackerSettings:
    """Tuning of :func:`track_video` (defaults suit a 512x256 high-speed video).

    Attributes
    ----------
    reinit_every : int
        Re-anchor MOSSE on the refined centre every this many frames.
    drift_tol : float
        MOSSE box centre further than this many ball radii from the refined centre -> re-acquire.
    radius_tol : float
        Refined radius off the expected one by more than this fraction -> invalid fit.
    min_points : int
        Fewest inlier rim points for a valid fit.
    max_lost_frac : float
        Above this fraction of lost frames the tracker raises (the track would be useless).
    scale_frames : int
        Frames used for the diameter-in-pixels scale.
    search_margin : float
        Refinement window half size = radius * (1 + search_margin) after a detection.
    track_margin : float
        The same while tracking (the guess is then within a few px).
    rim_step : int
        While tracking, scan every rim_step-th row / column (1 during the scale frames).
    level_every : int
        Recompute the rim grey level (Otsu) every this many frames; in between the last one is
        used (a level error shifts opposite rims symmetrically: the centre does not move).
    rim_method : {'band', 'crossings', 'contour'}
        Rim points while tracking: 'band' (default): sub-pixel crossings on short profiles
        across the expected rim only (:class:`BandRim`; as precise as 'crossings', ~5x
        faster); 'crossings': the same crossings from a scan of every rim_step-th row and column
        of the whole window (the earlier default); 'contour': OpenCV contour pixels (integer
        points, less precise). The scale frames always read every row and column with the
        window's Otsu level ('crossings', or 'band' profiles on all rows and columns: the same
        points).
    rim_span : float
        'band': profiles on rows / columns up to this many radii from the centre.
    mosse_every : int
        Update MOSSE on every this-many-th frame (1: every frame). Between updates the guess
        for the rim fit is the constant-velocity prediction from the last two fits, which is
        within a few px; MOSSE still checks the track and re-anchors as before on the frames it
        runs. A MOSSE update costs as much as the whole 'band' rim fit.
    """

    reinit_every: int = 200
    drift_tol: float = 0.3
    radius_tol: float = 0.15
    min_points: int = 20
    max_lost_frac: float = 0.5
    scale_frames: int = 60
    search_margin: float = 0.45
    track_margin: float = 0.3
    rim_step: int = 2
    level_every: int = 16
    rim_method: str = "band"
    rim_span: float = 0.95
    mosse_every: int = 4


# --------------------------------------------------------------------------------------------
# detection and sub-pixel refinement
# --------------------------------------------------------------------------------------------
def detect_ball(gray: np.ndarray, r_min: float, r_max: float, roi=None):
    """Hough-circle detector. Returns (x_px, y_px, r_px) of the strongest circle or None.

    Parameters
    ----------
    gray : ndarray, shape (H, W), uint8
    r_min, r_max : float
        Radius search range [px].
    roi : (x0, y0, x1, y1), optional
        Search only inside this window.
    """
    cv2 = load_cv2()
    x0 = y0 = 0
    img = gray
    if roi is not None:
        x0, y0, x1, y1 = [int(v) for v in roi]
        x0, y0 = max(x0, 0), max(y0, 0)
        img = gray[y0:y1, x0:x1]
        if img.shape[0] < 2 * r_min or img.shape[1] < 2 * r_min:
            return None
    b = cv2.GaussianBlur(img, (5, 5), 1.5)
    c = cv2.HoughCircles(b, cv2.HOUGH_GRADIENT, dp=1, minDist=max(2 * r_min, 4), param1=60,
                         param2=max(10, int(0.5 * r_min)), minRadius=max(int(r_min), 2),
                         maxRadius=int(math.ceil(r_max)))
    if c is None:
        return None
    for xc, yc, r in c[0]:
        # the ball is brighter than its surroundings: check interior vs ring
        return float(xc) + x0, float(yc) + y0, float(r)
    return None


def _edge_1d(w: np.ndarray, above: np.ndarray, level: float, axis: int):
    """First and last crossings along ``axis`` (1: rows, 0: columns) of a bool mask.

    Returns (line_index, first_pos, last_pos) for lines whose bright run does not touch the
    window border; positions linearly interpolated between the pixels around the crossing.
    """
    a = above if axis == 1 else above.T
    ww = w if axis == 1 else w.T
    n = a.shape[1]
    has = a.any(axis=1)
    idx = np.flatnonzero(has)
    if len(idx) == 0:
        e = np.empty(0)
        return e, e, e
    aa = a[idx]
    first = aa.argmax(axis=1)
    last = n - 1 - aa[:, ::-1].argmax(axis=1)
    ok = (first > 0) & (last < n - 1)
    idx, first, last = idx[ok], first[ok], last[ok]
    rows = ww[idx]
    r_ = np.arange(len(idx))
    i0 = rows[r_, first - 1]
    i1 = rows[r_, first]
    j0 = rows[r_, last]
    j1 = rows[r_, last + 1]
    pf = first - 1 + (level - i0) / np.maximum(i1 - i0, 1e-6)
    pl = last + (j0 - level) / np.maximum(j0 - j1, 1e-6)
    return idx.astype(float), pf, pl


def _crossings(win: np.ndarray, level: float, step: int = 1):
    """Sub-pixel rim points of the bright blob in ``win`` at grey ``level``.

    Every ``step``-th row and column is scanned. Returns xs, ys (window coordinates) and a
    boolean array telling which points come from column scans (top / bottom arcs).
    """
    w = win.astype(np.float32)
    above = w >= level
    if step > 1:
        ri, rf, rl = _edge_1d(w[::step], above[::step], level, 1)
        ci, cf, cl = _edge_1d(w[:, ::step], above[:, ::step], level, 0)
        ri, ci = ri * step, ci * step
    else:
        ri, rf, rl = _edge_1d(w, above, level, 1)
        ci, cf, cl = _edge_1d(w, above, level, 0)
    xs = np.concatenate([rf, rl, ci, ci])
    ys = np.concatenate([ri, ri, cf, cl])
    isc = np.zeros(len(xs), bool)
    isc[2 * len(ri):] = True
    return xs, ys, isc


def _contour_points(win: np.ndarray, level: float):
    """Rim points from cv2.findContours of the thresholded window (pixel centres of the blob's
    boundary pixels, ~0.5 px inside the true rim on every side: the centre is unbiased).
    Contours touching the window border are dropped point-wise. Fast (all in OpenCV)."""
    cv2 = load_cv2()
    _, bw = cv2.threshold(win, level, 255, cv2.THRESH_BINARY)
    cnts, _ = cv2.findContours(bw, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    cnts = [c for c in cnts if len(c) >= 12]
    if not cnts:
        e = np.empty(0)
        return e, e, np.empty(0, bool)
    pts = np.concatenate(cnts).reshape(-1, 2)
    H, W = win.shape
    inside = (pts[:, 0] > 0) & (pts[:, 0] < W - 1) & (pts[:, 1] > 0) & (pts[:, 1] < H - 1)
    pts = pts[inside].astype(np.float64)
    return pts[:, 0], pts[:, 1], np.zeros(len(pts), bool)


def _fit_circle(x: np.ndarray, y: np.ndarray):
    """Algebraic (Kasa) circle fit: returns xc, yc, r."""
    # normal equations of [x y 1] p = x^2 + y^2, centred for conditioning (3x3 solve: fast)
    mx, my = x.mean(), y.mean()
    u, v = x - mx, y - my
    b = u * u + v * v
    suu, svv, suv = u.dot(u), v.dot(v), u.dot(v)
    det = suu * svv - suv * suv
    if not det > 0:
        return float("nan"), float("nan"), float("nan")
    ub, vb = u.dot(b), v.dot(b)
    p0 = (svv * ub - suv * vb) / det
    p1 = (suu * vb - suv * ub) / det
    xc, yc = 0.5 * p0, 0.5 * p1
    r2 = b.mean() + xc * xc + yc * yc
    return xc + mx, yc + my, math.sqrt(r2) if r2 > 0 else float("nan")


def _otsu_level(img: np.ndarray) -> float:
    """Grey level half-way between ball and background: Otsu's threshold of ``img`` + 0.5."""
    cv2 = load_cv2()
    level, _ = cv2.threshold(img, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    return float(level) + 0.5


def window_level(gray: np.ndarray, x: float, y: float, r_exp: float, margin: float) -> float:
    """The rim level :func:`refine_centre` uses by default: Otsu of its window around (x, y)."""
    H, W = gray.shape
    h = int(math.ceil(r_exp * (1 + margin)))
    xg, yg = int(round(x)), int(round(y))
    return _otsu_level(gray[max(yg - h, 0):min(yg + h + 1, H), max(xg - h, 0):min(xg + h + 1, W)])


def refine_centre(gray: np.ndarray, x_guess: float, y_guess: float, r_exp: float,
                  margin: float = 0.45, min_points: int = 20, level: float | None = None,
                  step: int = 1, n_iter: int = 3, method: str = "crossings"):
    """Sub-pixel ball centre near a guess, robust to partial occlusion.

    Parameters
    ----------
    gray : ndarray, shape (H, W)
    x_guess, y_guess : float
        Rough centre [px].
    r_exp : float
        Expected radius [px].
    margin : float
        Window half size = r_exp * (1 + margin).
    level : float, optional
        Grey level of the rim (default: Otsu threshold of the window).
    step : int
        Scan every step-th row / column.
    n_iter : int
        Outlier-rejection rounds (3 x MAD of the radial residuals).
    method : {'crossings', 'contour'}
        Sub-pixel row/column crossings (precise) or OpenCV contour pixels (fast, integer
        points; the fit averages their quantisation).

    Returns
    -------
    (x_px, y_px, r_px, n_inliers, rim_points, level) or None when no valid circle is found;
    rim_points = (xs, ys, is_col) in image coordinates (inliers only).
    """
    cv2 = load_cv2()
    H, W = gray.shape
    h = int(math.ceil(r_exp * (1 + margin)))
    xg, yg = int(round(x_guess)), int(round(y_guess))
    x0, x1 = max(xg - h, 0), min(xg + h + 1, W)
    y0, y1 = max(yg - h, 0), min(yg + h + 1, H)
    if x1 - x0 < 8 or y1 - y0 < 8:
        return None
    win = gray[y0:y1, x0:x1]
    if level is None:
        level = _otsu_level(win)
    if method == "contour":
        xs, ys, isc = _contour_points(win, level)
    else:
        xs, ys, isc = _crossings(win, level, step)
    if len(xs) < min_points:
        return None
    if method == "contour":
        # integer points: one fit, drop points > 1.5 px off the circle (an occluder's straight
        # edge, a wall), refit - no medians (the fast path)
        xc, yc, r = _fit_circle(xs, ys)
        if not np.isfinite(r):
            return None
        keep = np.abs(np.hypot(xs - xc, ys - yc) - r) <= 1.5
        if keep.sum() < min_points:
            return None
        xc, yc, r = _fit_circle(xs[keep], ys[keep])
        if not np.isfinite(r):
            return None
        return (xc + x0, yc + y0, r + 0.5, int(keep.sum()),
                (xs[keep] + x0, ys[keep] + y0, isc[keep]), level)
    keep = np.ones(len(xs), bool)
    for _ in range(n_iter):
        if keep.sum() < min_points:
            return None
        xc, yc, r = _fit_circle(xs[keep], ys[keep])
        if not np.isfinite(r):
            return None
        res = np.hypot(xs - xc, ys - yc) - r
        rk = res[keep]
        med = np.median(rk)
        mad = 1.4826 * np.median(np.abs(rk - med))
        new = np.abs(res - med) <= max(3.0 * mad, 0.5)
        if np.array_equal(new, keep):
            break
        keep = new
    if keep.sum() < min_points:
        return None
    xc, yc, r = _fit_circle(xs[keep], ys[keep])
    if not np.isfinite(r):
        return None
    return (xc + x0, yc + y0, r, int(keep.sum()),
            (xs[keep] + x0, ys[keep] + y0, isc[keep]), level)


class BandRim:
    """Sub-pixel rim points on short profiles across the expected rim (the fast rim fit).

    The ball's centre is known to a few px while tracking (MOSSE or the constant-velocity
    prediction), so there is no need to scan a whole window: every ``step``-th row within
    ``span`` r of the centre gets a horizontal profile across the left and the right rim, every
    ``step``-th column a vertical one across the top and the bottom rim, each 2B+1 px long and
    centred on where the rim of a circle of radius r would be (B = max(8, 0.2 r) px of slack for
    the guess error and motion blur, at most r / 2). All profiles are read with one gather from precomputed
    pixel offsets (no per-frame window copy or allocation of index grids), stored from outside
    to inside; a profile's rim point is its outermost crossing of the grey level, linearly
    interpolated between the two pixels around it - the same point the row / column scan of
    :func:`_crossings` finds, for the pixels near the rim only. The circle is a Kasa fit solved
    from a 4x4 moment matrix; the 3 x MAD outlier refits (an occluder or a wall edge cutting
    profiles) run only when some residual exceeds 0.5 px, the refits' own floor.
    """

    def __init__(self, r: float, width: int, step: int = 2, span: float = 0.95):
        B = min(max(8, int(round(0.2 * r))), max(2, int(0.5 * r)))
        n = 2 * B + 1
        m = int(math.floor(span * r))
        d = np.arange(-m, m + 1, max(1, int(step)))
        c = np.rint(np.sqrt(r * r - d * d)).astype(int)
        e = c + B  # distance from the centre of each profile's outermost sample
        j = np.arange(n)
        outward = e[:, None] - j[None, :]  # distances along the profile, outside -> inside
        offs, ux, uy, ox, oy, isc = [], [], [], [], [], []
        zeros, ones = np.zeros(len(d)), np.ones(len(d))
        for sgn in (1, -1):  # rows: right (+x) and left (-x) rims
            offs.append(d[:, None] * width + sgn * outward)
            ox.append(zeros); oy.append(d); ux.append(sgn * ones); uy.append(zeros)
            isc.append(np.zeros(len(d), bool))
        for sgn in (1, -1):  # columns: bottom (+y) and top (-y) rims
            offs.append(sgn * outward * width + d[:, None])
            ox.append(d); oy.append(zeros); ux.append(zeros); uy.append(sgn * ones)
            isc.append(np.ones(len(d), bool))
        self.r, self.width, self.step, self.n = float(r), int(width), step, n
        self.off = np.ascontiguousarray(np.concatenate(offs), dtype=np.intp)
        self.off_min = int(self.off.min())
        self.off0 = self.off - self.off_min
        self.P = len(self.off)
        self.origin = np.column_stack([np.concatenate(ox), np.concatenate(oy)]).astype(float)
        self.unit = np.column_stack([np.concatenate(ux), np.concatenate(uy)]).astype(float)
        self.e = np.tile(e, 4).astype(float)
        self.isc = np.concatenate(isc)
        self.rowbase = np.arange(self.P, dtype=np.intp) * n
        self.reach = int(max(e.max(), m)) + 1  # farthest sample from the centre [px]
        self.slack = B

    def reach_ok(self, gray, x: float, y: float) -> bool:
        """True if all profiles around (x, y) lie inside the frame."""
        H, W = gray.shape
        xi, yi, R = int(round(x)), int(round(y)), self.reach
        return W == self.width and R <= xi < W - R and R <= yi < H - R

    def _points(self, gray, xi: int, yi: int, level):
        # (P, n) profiles, outside -> inside (offsets shifted to >= 0: a view, no index sum)
        p = gray.reshape(-1)[yi * self.width + xi + self.off_min:].take(self.off0)
        if level is None:
            level = _otsu_level(p)
        above = p >= level
        first = above.argmax(axis=1)  # outermost sample at or above the level
        k = (above[:, -1] > above[:, 0]).nonzero()[0]  # bright inside, dark outside
        i = first[k]
        b = self.rowbase[k] + i
        pf = p.reshape(-1)
        v_in = pf[b]
        # v_in >= level > v_out: the uint8 difference is positive
        dist = (self.e[k] - i) + (v_in - level) / (v_in - pf[b - 1])
        pts = self.origin[k] + self.unit[k] * dist[:, None]  # relative to (xi, yi)
        return pts, k, level

    @staticmethod
    def _fit(pts):
        """Kasa fit in local coordinates: (a, b, r, m) or None; m = [x, y, 1, x^2 + y^2]."""
        m = np.empty((len(pts), 4))
        m[:, :2] = pts
        m[:, 2] = 1.0
        m[:, 3] = (pts * pts).sum(axis=1)
        g = (m.T @ m).tolist()
        (g00, g01, g02, g03), (_, g11, g12, g13), (_, _, g22, g23) = g[0], g[1], g[2]
        # solve the symmetric 3x3 normal equations by Cramer's rule
        c00 = g11 * g22 - g12 * g12
        c01 = g02 * g12 - g01 * g22
        c02 = g01 * g12 - g02 * g11
        det = g00 * c00 + g01 * c01 + g02 * c02
        if not abs(det) > 1e-12 * (abs(g00 * g11 * g22) + 1e-300):
            return None
        c11 = g00 * g22 - g02 * g02
        c12 = g01 * g02 - g00 * g12
        c22 = g00 * g11 - g01 * g01
        p0 = (c00 * g03 + c01 * g13 + c02 * g23) / det
        p1 = (c01 * g03 + c11 * g13 + c12 * g23) / det
        p2 = (c02 * g03 + c12 * g13 + c22 * g23) / det
        a, b = 0.5 * p0, 0.5 * p1
        r2 = p2 + a * a + b * b
        if not r2 > 0:
            return None
        return a, b, math.sqrt(r2), m

    def refine(self, gray, x_guess: float, y_guess: float, level=None, min_points: int = 20,
               n_iter: int = 2, rim: bool = True):
        """Like :func:`refine_centre`: (x_px, y_px, r_px, n_inliers, rim_points, level) or None;
        also None when the profiles would leave the frame (the caller falls back to the window
        scan). rim_points is None unless ``rim``."""
        H, W = gray.shape
        xi, yi = int(round(x_guess)), int(round(y_guess))
        R = self.reach
        if W != self.width or xi < R or yi < R or xi + R >= W or yi + R >= H:
            return None
        if not gray.flags.c_contiguous:
            gray = np.ascontiguousarray(gray)
        for attempt in range(2):
            pts, k, level = self._points(gray, xi, yi, level)
            if len(k) < min_points:
                return None
            fit = self._fit(pts)
            if fit is None:
                return None
            a, b, r, m = fit
            # every point within 0.5 px of the circle, (r - 0.5)^2 <= d^2 <= (r + 0.5)^2, is
            # |d^2 - r^2 - 0.25| <= r, d^2 - r^2 = [x, y, 1, x^2 + y^2] . [-2a, -2b, a^2+b^2-r^2, 1]
            e = m.dot(np.array((-2.0 * a, -2.0 * b, a * a + b * b - r * r, 1.0)))
            keep = None
            for _ in range(n_iter if e.max() > r + 0.25 or e.min() < 0.25 - r else 0):
                q = pts - (a, b)
                res = np.sqrt((q * q).sum(axis=1)) - r
                rk = res if keep is None else res[keep]  # median and MAD of the inliers
                h = len(rk) // 2
                med = np.partition(rk, h)[h]
                mad = 1.4826 * np.partition(np.abs(rk - med), h)[h]
                new = np.abs(res - med) <= max(3.0 * mad, 0.5)
                if keep is not None and np.array_equal(new, keep):
                    break
                keep = new
                nk = int(keep.sum())
                if nk < min_points:
                    return None
                fit = self._fit(pts[keep])
                if fit is None:
                    return None
                a, b, r, _ = fit
            # the profiles are centred on the guess: if it was off by more than a third of the
            # slack, read them again around the fitted centre
            if attempt == 0 and max(abs(a), abs(b)) > self.slack / 3:
                xi, yi = int(round(xi + a)), int(round(yi + b))
                if xi < R or yi < R or xi + R >= W or yi + R >= H:
                    return None
                continue
            break
        if keep is not None:
            pts, k = pts[keep], k[keep]
        return (xi + a, yi + b, r, len(k),
                (pts[:, 0] + xi, pts[:, 1] + yi, self.isc[k]) if rim else None, level)


def _vertical_radius(rim, xc: float, r: float) -> float:
    """Radius from the top/bottom arcs only (immune to horizontal motion blur)."""
    xs, ys, isc = rim
    sel = isc & (np.abs(xs - xc) < 0.6 * r)
    if sel.sum() < 6:
        return float("nan")
    return _fit_circle(xs[sel], ys[sel])[2]


# --------------------------------------------------------------------------------------------
# the tracker
# --------------------------------------------------------------------------------------------
@dataclass
class TrackResult:
    """A tracked video.

    Attributes
    ----------
    track : DataFrame
        t_s, x_m, y_m, quality, x_px, y_px, r_px (NaN where lost).
    m_per_px : float
        Scale used [m/px].
    scale_source : str
        'given' or 'ball_diameter'.
    ball_diameter_px : float
        Measured diameter [px] (median over the scale frames).
    fps : float
    n_frames, n_lost, n_reacquired : int
    wall_s : float
        Tracking time [s].
    """

    track: pd.DataFrame
    m_per_px: float
    scale_source: str
    ball_diameter_px: float
    fps: float
    n_frames: int
    n_lost: int
    n_reacquired: int
    wall_s: float
    params: dict = field(default_factory=dict)

    def to_frame(self) -> pd.DataFrame:
        return pd.DataFrame([{"m_per_px": self.m_per_px, "scale_source": self.scale_source,
                              "ball_diameter_px": self.ball_diameter_px, "fps": self.fps,
                              "n_frames": self.n_frames, "n_lost": self.n_lost,
                              "n_reacquired": self.n_reacquired, "wall_s": self.wall_s}])


#: MOSSE box side in ball radii: 2.5 diameters, so the box holds the whole rim and a ring of
#: background. (A box of 1.2 diameters, the ball filling it, gives a flat correlation peak: MOSSE
#: then failed its PSR test on ~60 % of the frames of the benchmark video.)
MOSSE_BOX_RADII = 5.0


class _ScaledMosse:
    """MOSSE run on a frame shrunk by an integer factor (box ~32 px): it only has to be coarse,
    the rim fit at full resolution gives the sub-pixel centre (at full resolution a 128 px box
    cost ~2 ms/frame)."""

    def __init__(self, gray, xc, yc, r):
        cv2 = load_cv2()
        self.k = max(1, int(round(MOSSE_BOX_RADII * r / 32.0)))
        self.tr = _new_mosse_raw(self._small(gray), self._to_s(xc), self._to_s(yc), r / self.k)

    def _small(self, gray):
        # plain decimation (pixel k*i + k//2): 10x cheaper than INTER_AREA; MOSSE is coarse
        if self.k == 1:
            return gray
        o = self.k // 2
        return np.ascontiguousarray(gray[o::self.k, o::self.k])

    def _to_s(self, v):
        return (v - self.k // 2) / self.k

    def update(self, gray):
        ok, bb = self.tr.update(self._small(gray))
        if not ok:
            return False, None
        k = self.k
        return True, (bb[0] * k + k // 2, bb[1] * k + k // 2, bb[2] * k, bb[3] * k)


def _new_mosse(gray, xc, yc, r):
    return _ScaledMosse(gray, xc, yc, r)


def _new_mosse_raw(gray, xc, yc, r):
    cv2 = load_cv2()
    tr = cv2.legacy.TrackerMOSSE_create()
    # box of an FFT-friendly size (a prime factor like 31 makes MOSSE ~15x slower)
    s = cv2.getOptimalDFTSize(int(round(MOSSE_BOX_RADII * r)))
    tr.init(gray, (int(round(xc - s / 2)), int(round(yc - s / 2)), s, s))
    return tr


def track_frames(frames, fps: float, *, ball_diameter_m: float | None = None,
                 m_per_px: float | None = None, ball_radius_px: float | None = None,
                 settings: TrackerSettings | None = None, source: str = "video") -> TrackResult:
    """Track the ball through an iterable of grey frames.

    Parameters
    ----------
    frames : iterable of ndarray (H, W) uint8
    fps : float
        Frame rate [1/s] (> 0); frame i is at t = i / fps.
    ball_diameter_m : float, optional
        Real ball diameter [m]: gives the scale (with the measured diameter in px) and, with
        m_per_px, the expected radius in px.
    m_per_px : float, optional
        Scale [m/px]; takes precedence over the ball-diameter scale.
    ball_radius_px : float, optional
        Expected radius [px] (else from ball_diameter_m / m_per_px, else found by the detector).
    settings : TrackerSettings
    source : str
        Name for messages.

    Returns
    -------
    TrackResult
    """
    st = TrackerSettings() if settings is None else settings
    if st.rim_method not in RIM_METHODS:
        raise TrackingError(f"{source}: rim_method must be one of {RIM_METHODS}, "
                            f"got {st.rim_method!r}")
    if not (isinstance(st.mosse_every, int) and st.mosse_every >= 1):
        raise TrackingError(f"{source}: mosse_every must be an integer >= 1, "
                            f"got {st.mosse_every!r}")
    if fps is None or not (fps > 0 and math.isfinite(fps)):
        raise TrackingError(f"{source}: fps must be > 0, got {fps}")
    if m_per_px is not None and not m_per_px > 0:
        raise TrackingError(f"{source}: m_per_px must be > 0, got {m_per_px}")
    if ball_diameter_m is not None and not ball_diameter_m > 0:
        raise TrackingError(f"{source}: ball diameter must be > 0, got {ball_diameter_m}")
    if m_per_px is None and ball_diameter_m is None:
        raise TrackingError(f"{source}: give m_per_px or the ball diameter for the scale")
    r_exp = ball_radius_px
    if r_exp is None and m_per_px is not None and ball_diameter_m is not None:
        r_exp = 0.5 * ball_diameter_m / m_per_px
    t_start = time.perf_counter()
    tr = _BallTracker(st, r_exp)
    for gray in frames:
        tr.feed(gray)
    n = tr.n
    if n == 0:
        raise VideoReadError(f"{source}: no decodable frame (empty or corrupt video)")
    qual = np.array(tr.qual)
    if np.all(qual == "lost"):
        raise BallNotFoundError(f"{source}: the ball was never found in {n} frames")
    n_lost = int(np.sum(qual == "lost"))
    if n_lost / n > st.max_lost_frac:
        raise TrackingError(f"{source}: ball lost in {n_lost} of {n} frames "
                            f"(> {100 * st.max_lost_frac:.0f} %); no usable track")
    vr = np.array(tr.vr_list, float)
    rs_px = tr.rs_px
    d_px = 2 * float(np.nanmedian(vr)) if np.isfinite(vr).any() else 2 * float(np.nanmedian(rs_px))
    if m_per_px is not None:
        scale, src = float(m_per_px), "given"
    else:
        scale, src = ball_diameter_m / d_px, "ball_diameter"
    xs_px = np.array(tr.xs_px)
    ys_px = np.array(tr.ys_px)
    t = np.arange(n) / fps
    df = pd.DataFrame({"t_s": t, "x_m": xs_px * scale, "y_m": (tr.H - 1 - ys_px) * scale,
                       "quality": qual, "x_px": xs_px, "y_px": ys_px, "r_px": rs_px})
    wall = time.perf_counter() - t_start
    return TrackResult(df, scale, src, d_px, float(fps), n, n_lost,
                       int(np.sum(qual == "reacquired")), wall,
                       {"r_expected_px": tr.r_exp, **st.__dict__})


class _BallTracker:
    """The tracker's state over the frames fed to it in turn: the ball's pixel track and
    quality per frame, the vertical radii of the scale frames, the MOSSE tracker and the
    constant-velocity prediction from the last two fits."""

    def __init__(self, st: TrackerSettings, r_exp):
        self.st, self.r_exp = st, r_exp
        self.xs_px, self.ys_px, self.rs_px, self.qual = [], [], [], []
        self.vr_list = []
        self.mosse = None
        self.prev = None  # (x, y) of the last valid frame
        self.vel = (0.0, 0.0)
        self.n_since_init = 0
        self.H = self.W = None
        self.n = 0
        self.level = None
        self.band = None  # the 'band' rim geometry, built once the radius and width are known
        self.band_fine = None

    def feed(self, gray):
        """One frame: the ball found (around the prediction, else by the detector) or lost."""
        st = self.st
        self.n += 1
        if self.H is None:
            self.H, self.W = gray.shape
        if self.band is None and st.rim_method == "band" and self.r_exp is not None:
            self.band = BandRim(self.r_exp, self.W, st.rim_step, st.rim_span)
            self.band_fine = BandRim(self.r_exp, self.W, 1, st.rim_span)  # for the scale frames
        res, q = self._acquire(gray) if self.prev is None else self._follow(gray)
        if res is None:
            self._lose()
        else:
            self._keep(gray, res, q)

    def _reset_mosse(self, gray, x, y):
        self.mosse = _new_mosse(gray, x, y, self.r_exp)
        self.n_since_init = 0

    def _acquire(self, gray):
        """(Re)acquire with the detector on the whole frame: (fit or None, quality)."""
        st, H, W = self.st, self.H, self.W
        rmin = 0.7 * self.r_exp if self.r_exp else 6
        rmax = 1.3 * self.r_exp if self.r_exp else min(H, W) / 2
        det = detect_ball(gray, rmin, rmax)
        q, res = "ok", None
        if det is not None:
            if self.r_exp is None:
                self.r_exp = det[2]
            res = refine_centre(gray, det[0], det[1], self.r_exp, st.search_margin,
                                st.min_points)
            if res is not None and abs(res[2] / self.r_exp - 1) > st.radius_tol:
                res = None
            if res is not None:
                q = "reacquired" if self.xs_px else "ok"
                self._reset_mosse(gray, res[0], res[1])
        return res, q

    def _follow(self, gray):
        """The ball near its prediction: the rim fit, else the detector; MOSSE re-anchored
        where it lost or drifted from the fit."""
        st, r_exp, vel = self.st, self.r_exp, self.vel
        px, py = self.prev[0] + vel[0], self.prev[1] + vel[1]
        run_m = self.mosse is not None and self.n % st.mosse_every == 0
        ok_m, bb = self.mosse.update(gray) if run_m else (False, None)
        m_xy = (bb[0] + bb[2] / 2, bb[1] + bb[3] / 2) if ok_m else None
        # rim fit around the constant-velocity prediction (sub-pixel velocity from the last
        # two fits: within a few px even at an impact); then around MOSSE's box if it
        # agrees with the prediction; a fit must lie within 0.5 r of the prediction
        guesses = [(px, py)]
        if m_xy is not None and math.hypot(m_xy[0] - px, m_xy[1] - py) <= \
                st.drift_tol * r_exp + math.hypot(*vel):
            guesses.append(m_xy)
        res = self._rim_fit(gray, guesses, px, py)
        q = "ok"
        if res is None:
            res = self._detect_near(gray, px, py)
            if res is not None:
                q = "reacquired"
                self._reset_mosse(gray, res[0], res[1])
        elif run_m and self.n_since_init >= 25 and (
                m_xy is None or
                math.hypot(m_xy[0] - res[0], m_xy[1] - res[1]) > st.drift_tol * r_exp):
            # MOSSE lost it (low PSR) or drifted but the refinement held: re-anchor MOSSE
            # (at most every 25 frames: an init costs ~9 updates)
            self._reset_mosse(gray, res[0], res[1])
        return res, q

    def _rim_fit(self, gray, guesses, px, py):
        """The first rim fit around ``guesses`` of the right radius within 0.5 r of the
        prediction (px, py), or None."""
        st, r_exp, band = self.st, self.r_exp, self.band
        scale_phase = len(self.vr_list) < st.scale_frames
        use_level = None if (scale_phase or self.level is None
                             or self.n % st.level_every == 0) else self.level
        res = None
        for gx, gy in guesses:
            res = None
            lv = use_level
            if band is not None and scale_phase:
                # every row and column, the level of refine_centre's window: the same rim
                # points as its scan (the diameter, hence the scale, depends on the level)
                res = self.band_fine.refine(gray, gx, gy,
                                            window_level(gray, gx, gy, r_exp, st.track_margin),
                                            st.min_points, n_iter=3)
            elif band is not None:
                res = band.refine(gray, gx, gy, lv, st.min_points, n_iter=2, rim=False)
                if res is None and band.reach_ok(gray, gx, gy):
                    lv = None  # profiles inside the frame but no circle: fresh level
            if res is None:
                res = refine_centre(gray, gx, gy, r_exp, st.track_margin,
                                    st.min_points, level=lv,
                                    step=1 if scale_phase else st.rim_step,
                                    n_iter=3 if scale_phase else 2,
                                    method="crossings" if scale_phase or band is not None
                                    else st.rim_method)
            if res is None and lv is not None:  # lighting changed: fresh level
                res = refine_centre(gray, gx, gy, r_exp, st.search_margin, st.min_points)
            if res is not None and (abs(res[2] / r_exp - 1) > st.radius_tol or
                                    math.hypot(res[0] - px, res[1] - py) > 0.5 * r_exp):
                res = None
            if res is not None:
                break
        return res

    def _detect_near(self, gray, px, py):
        """No valid rim around the prediction nor around MOSSE's box: the detector near the
        prediction, then on the whole frame; its refined fit of the right radius or None."""
        st, r_exp = self.st, self.r_exp
        h = int(3 * r_exp)
        det = detect_ball(gray, 0.8 * r_exp, 1.2 * r_exp, (px - h, py - h, px + h + 1, py + h + 1))
        if det is None:
            det = detect_ball(gray, 0.8 * r_exp, 1.2 * r_exp)
        res = None
        if det is not None:
            res = refine_centre(gray, det[0], det[1], r_exp, st.search_margin, st.min_points)
            if res is not None and abs(res[2] / r_exp - 1) > st.radius_tol:
                res = None
        return res

    def _lose(self):
        """A lost frame: keep predicting for a few frames, then fall back to whole-frame
        detection."""
        self.xs_px.append(np.nan)
        self.ys_px.append(np.nan)
        self.rs_px.append(np.nan)
        self.qual.append("lost")
        lost_run = 0
        for qq in reversed(self.qual):
            if qq != "lost":
                break
            lost_run += 1
        if lost_run > 3:
            self.prev = None

    def _keep(self, gray, res, q):
        """A found frame: its fit recorded, the velocity and the threshold level updated."""
        xc, yc, r = res[0], res[1], res[2]
        self.level = res[5]
        if self.prev is not None and self.qual and self.qual[-1] != "lost":
            self.vel = (xc - self.prev[0], yc - self.prev[1])
        else:
            self.vel = (0.0, 0.0)
        self.prev = (xc, yc)
        self.xs_px.append(xc)
        self.ys_px.append(yc)
        self.rs_px.append(r)
        self.qual.append(q)
        if len(self.vr_list) < self.st.scale_frames:
            self.vr_list.append(_vertical_radius(res[4], xc, r))
        self.n_since_init += 1
        if self.n_since_init >= self.st.reinit_every:
            self._reset_mosse(gray, xc, yc)


def track_video(path, fps: float | None = None, *, ball_diameter_m: float | None = None,
                m_per_px: float | None = None, settings: TrackerSettings | None = None,
                jar: bool = False, jar_band_rows=None, force_fps: bool = False) -> TrackResult:
    """Track the ball in a video file. ``fps`` defaults to a ``<stem>.json`` sidecar's (or a
    ``video.json`` beside the video, as in a measurement dataset), then to the container's
    (OpenCV), and must be > 0. A given ``fps`` more than :data:`FPS_TOLERANCE` away from the
    rate the file declares (:func:`declared_fps`) raises :class:`FpsMismatchError` before any
    frame is tracked, unless ``force_fps`` (then ``params['fps_forced']`` records both rates).
    Scale as in :func:`track_frames`; the sidecar's m_per_px /
    ball_diameter_m are used when both arguments are None; its ball_diameter_px sets the
    expected size. With ``jar`` (a lab-frame video) the jar is followed too (:func:`track_jar`,
    band ``jar_band_rows`` or found): column ``jar_x_m``, which :mod:`analysis.flights` needs
    for the impact observables; ``params['jar']`` holds its band and walls."""
    res = _track_ball_video(path, fps, ball_diameter_m, m_per_px, settings, force_fps)
    if jar:
        x, info = track_jar_video(path, res.m_per_px, band=jar_band_rows)
        if len(x) != len(res.track):
            raise TrackingError("%s: the jar pass read %d frames, the ball pass %d"
                                % (path, len(x), len(res.track)))
        res.track["jar_x_m"] = x
        res.params["jar"] = info
    return res


def _track_ball_video(path, fps, ball_diameter_m, m_per_px, settings,
                      force_fps=False) -> TrackResult:
    path = Path(path)
    side, meta = read_sidecar(path)
    cap = open_video(path)
    given = fps is not None
    if fps is None:
        try:
            fps = declared_fps_from(side, meta, cap)[0]
        except TrackingError:
            cap.release()
            raise
    if not (fps and fps > 0 and math.isfinite(fps)):
        cap.release()
        raise TrackingError(f"{path}: fps must be a finite number > 0 [1/s], got {fps}")
    mismatch = None
    if given:
        try:
            mismatch = fps_mismatch(path, float(fps), *declared_fps_from(side, meta, cap))
        except TrackingError:
            cap.release()
            raise
        if mismatch is not None and not force_fps:
            cap.release()
            raise mismatch
    if m_per_px is None and ball_diameter_m is None:  # explicit arguments win as a pair
        m_per_px = meta.get("m_per_px")
        ball_diameter_m = meta.get("ball_diameter_m")
    r_hint = meta.get("ball_diameter_px")
    try:
        res = track_frames(decode_ahead(cap), float(fps),
                           ball_radius_px=None if r_hint is None else 0.5 * float(r_hint),
                           ball_diameter_m=ball_diameter_m, m_per_px=m_per_px,
                           settings=settings, source=str(path))
    finally:
        cap.release()
    if mismatch is not None:
        res.params["fps_forced"] = {"given_fps": mismatch.given_fps,
                                    "declared_fps": mismatch.declared_fps,
                                    "declared_by": mismatch.declared_by}
    return res
