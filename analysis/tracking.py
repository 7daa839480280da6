"""Follow one ball through a high-speed video: video -> track CSV (t_s, x_m, y_m, quality).

As in the seed paper (Sec. 2.5) the ball is followed by OpenCV's MOSSE correlation tracker
(cv2.legacy.TrackerMOSSE_create), initialised by a detector; here the detector is a Hough circle
transform on the grey frame (radius range from the expected ball size). MOSSE gives an integer,
drift-prone box, so every frame its centre is refined to sub-pixel accuracy:

* edge points: in a window around the box, each row's first and last crossing of a grey level
  half-way between background and ball (Otsu threshold of the window), and each column's top and
  bottom crossing, linearly interpolated between pixels;
* a circle fitted to those points (algebraic least squares), twice re-fitted without outliers
  (3 x MAD of the radial residuals): a bar or a wall hiding part of the rim, or a highlight,
  does not pull the centre.

The refined fit is also the check on MOSSE: if MOSSE fails (low PSR), or its box lies more than
0.3 ball radii from the refined centre, or the refined radius is off by > 15 %, the detector
re-acquires the ball (quality 'reacquired') and MOSSE is re-initialised there. MOSSE is also
re-anchored on the refined centre every ``reinit_every`` frames to stop template drift. A frame
where neither gives a valid circle is 'lost' (x, y NaN) - never interpolated; the observation
operator treats such rows as gaps.

Scale: ``m_per_px`` if given, else from the ball diameter as the paper does: the median over
the first frames of the ball's diameter in pixels, measured on the top and bottom arcs only
(motion blur along the jar axis stretches the left/right rims, not the top/bottom).

Output y_m points up (image rows run down): y_m = (height - 1 - y_px) * m_per_px.
"""
from __future__ import annotations

import argparse
import math
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd


class TrackingError(ValueError):
    """Bad video or a ball that cannot be followed (message names the file)."""


class VideoReadError(TrackingError):
    """The video cannot be opened or holds no decodable frame."""


class BallNotFoundError(TrackingError):
    """The detector never found the ball."""


def _cv2():
    import cv2
    return cv2


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
    rim_method : {'crossings', 'contour'}
        Rim points while tracking: sub-pixel crossings (precise, default) or OpenCV contours
        (fast); the scale frames always use crossings.
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
    rim_method: str = "crossings"


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
    cv2 = _cv2()
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
    cv2 = _cv2()
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
    cv2 = _cv2()
    H, W = gray.shape
    h = int(math.ceil(r_exp * (1 + margin)))
    xg, yg = int(round(x_guess)), int(round(y_guess))
    x0, x1 = max(xg - h, 0), min(xg + h + 1, W)
    y0, y1 = max(yg - h, 0), min(yg + h + 1, H)
    if x1 - x0 < 8 or y1 - y0 < 8:
        return None
    win = gray[y0:y1, x0:x1]
    if level is None:
        level, _ = cv2.threshold(win, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
        level = float(level) + 0.5
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


def _vertical_radius(rim, xc: float, r: float) -> float:
    """Radius from the top/bottom arcs only (immune to horizontal motion blur)."""
    xs, ys, isc = rim
    sel = isc & (np.abs(xs - xc) < 0.6 * r)
    if sel.sum() < 6:
        return float("nan")
    return _fit_circle(xs[sel], ys[sel])[2]


# --------------------------------------------------------------------------------------------
# video reading
# --------------------------------------------------------------------------------------------
def open_video(path):
    """Open a video for grey frames; raises VideoReadError for missing / unreadable files."""
    cv2 = _cv2()
    try:
        cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)
    except AttributeError:  # pragma: no cover - older OpenCV
        pass
    path = Path(path)
    if not path.is_file():
        raise VideoReadError(f"{path}: no such video file")
    if path.stat().st_size == 0:
        raise VideoReadError(f"{path}: empty file")
    cap = cv2.VideoCapture(str(path), cv2.CAP_FFMPEG, [cv2.CAP_PROP_CONVERT_RGB, 0])
    if not cap.isOpened():
        cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        raise VideoReadError(f"{path}: OpenCV cannot open it (unreadable or corrupt video)")
    return cap


def iter_gray(cap):
    """Yield grey uint8 frames from an open capture."""
    cv2 = _cv2()
    while True:
        ok, f = cap.read()
        if not ok or f is None:
            return
        if f.ndim == 3:
            f = cv2.cvtColor(f, cv2.COLOR_BGR2GRAY)
        elif f.dtype != np.uint8:
            f = cv2.convertScaleAbs(f)
        yield f


def read_frames(path) -> list[np.ndarray]:
    """All grey frames of a video (for benchmarks and small tests)."""
    cap = open_video(path)
    try:
        frames = list(iter_gray(cap))
    finally:
        cap.release()
    if not frames:
        raise VideoReadError(f"{path}: no decodable frame (empty or corrupt video)")
    return frames


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


class _ScaledMosse:
    """MOSSE run on a frame shrunk by an integer factor (box ~32 px): it only has to be coarse,
    the rim fit at full resolution gives the sub-pixel centre; a 128 px box costs ~2 ms/frame."""

    def __init__(self, gray, xc, yc, r):
        cv2 = _cv2()
        self.k = max(1, int(round(2.4 * r / 32.0)))
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
    cv2 = _cv2()
    tr = cv2.legacy.TrackerMOSSE_create()
    # box of an FFT-friendly size (a prime factor like 31 makes MOSSE ~15x slower)
    s = cv2.getOptimalDFTSize(int(round(2.4 * r)))
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
    xs_px, ys_px, rs_px, qual = [], [], [], []
    vr_list = []
    mosse = None
    prev = None  # (x, y) of the last valid frame
    vel = (0.0, 0.0)
    n_since_init = 0
    H = W = None
    n = 0
    level = None
    for gray in frames:
        n += 1
        if H is None:
            H, W = gray.shape
        q = "ok"
        res = None
        if prev is None:
            # (re)acquire with the detector on the whole frame
            rmin = 0.7 * r_exp if r_exp else 6
            rmax = 1.3 * r_exp if r_exp else min(H, W) / 2
            det = detect_ball(gray, rmin, rmax)
            if det is not None:
                if r_exp is None:
                    r_exp = det[2]
                res = refine_centre(gray, det[0], det[1], r_exp, st.search_margin, st.min_points)
                if res is not None and abs(res[2] / r_exp - 1) > st.radius_tol:
                    res = None
                if res is not None:
                    q = "reacquired" if xs_px else "ok"
                    mosse = _new_mosse(gray, res[0], res[1], r_exp)
                    n_since_init = 0
        else:
            px, py = prev[0] + vel[0], prev[1] + vel[1]
            ok_m, bb = mosse.update(gray) if mosse is not None else (False, None)
            guess = (px, py)
            if ok_m:
                mx, my = bb[0] + bb[2] / 2, bb[1] + bb[3] / 2
                if math.hypot(mx - px, my - py) <= st.drift_tol * r_exp + math.hypot(*vel):
                    guess = (mx, my)
            scale_phase = len(vr_list) < st.scale_frames
            use_level = None if (scale_phase or level is None or n % st.level_every == 0) \
                else level
            res = refine_centre(gray, guess[0], guess[1], r_exp, st.track_margin, st.min_points,
                                level=use_level, step=1 if scale_phase else st.rim_step,
                                n_iter=3 if scale_phase else 2,
                                method="crossings" if scale_phase else st.rim_method)
            if res is None and use_level is not None:  # lighting changed: fresh level
                res = refine_centre(gray, guess[0], guess[1], r_exp, st.search_margin,
                                    st.min_points)
            if res is not None and (abs(res[2] / r_exp - 1) > st.radius_tol or
                                    math.hypot(res[0] - px, res[1] - py) > 0.5 * r_exp):
                res = None
            if res is None:
                # MOSSE failed or drifted and the prediction found no rim: detector near the
                # prediction, then on the whole frame
                h = int(3 * r_exp)
                det = detect_ball(gray, 0.8 * r_exp, 1.2 * r_exp,
                                  (px - h, py - h, px + h + 1, py + h + 1))
                if det is None:
                    det = detect_ball(gray, 0.8 * r_exp, 1.2 * r_exp)
                if det is not None:
                    res = refine_centre(gray, det[0], det[1], r_exp, st.search_margin,
                                        st.min_points)
                    if res is not None and abs(res[2] / r_exp - 1) > st.radius_tol:
                        res = None
                if res is not None:
                    q = "reacquired"
                    mosse = _new_mosse(gray, res[0], res[1], r_exp)
                    n_since_init = 0
            elif (ok_m is False or guess == (px, py)) and n_since_init >= 25:
                # MOSSE lost it (low PSR) or drifted but the refinement held: re-anchor MOSSE
                # (at most every 25 frames: an init costs ~50 updates)
                mosse = _new_mosse(gray, res[0], res[1], r_exp)
                n_since_init = 0
        if res is None:
            xs_px.append(np.nan)
            ys_px.append(np.nan)
            rs_px.append(np.nan)
            qual.append("lost")
            if prev is not None and len(qual) >= 2 and qual[-2] == "lost":
                pass
            # keep predicting for a few frames, then fall back to whole-frame detection
            lost_run = 0
            for qq in reversed(qual):
                if qq != "lost":
                    break
                lost_run += 1
            if lost_run > 3:
                prev = None
            continue
        xc, yc, r = res[0], res[1], res[2]
        level = res[5]
        if prev is not None and qual and qual[-1] != "lost":
            vel = (xc - prev[0], yc - prev[1])
        else:
            vel = (0.0, 0.0)
        prev = (xc, yc)
        xs_px.append(xc)
        ys_px.append(yc)
        rs_px.append(r)
        qual.append(q)
        if len(vr_list) < st.scale_frames:
            vr_list.append(_vertical_radius(res[4], xc, r))
        n_since_init += 1
        if n_since_init >= st.reinit_every:
            mosse = _new_mosse(gray, xc, yc, r_exp)
            n_since_init = 0
    if n == 0:
        raise VideoReadError(f"{source}: no decodable frame (empty or corrupt video)")
    qual = np.array(qual)
    if np.all(qual == "lost"):
        raise BallNotFoundError(f"{source}: the ball was never found in {n} frames")
    n_lost = int(np.sum(qual == "lost"))
    if n_lost / n > st.max_lost_frac:
        raise TrackingError(f"{source}: ball lost in {n_lost} of {n} frames "
                            f"(> {100 * st.max_lost_frac:.0f} %); no usable track")
    vr = np.array(vr_list, float)
    d_px = 2 * float(np.nanmedian(vr)) if np.isfinite(vr).any() else 2 * float(np.nanmedian(rs_px))
    if m_per_px is not None:
        scale, src = float(m_per_px), "given"
    else:
        scale, src = ball_diameter_m / d_px, "ball_diameter"
    xs_px = np.array(xs_px)
    ys_px = np.array(ys_px)
    t = np.arange(n) / fps
    df = pd.DataFrame({"t_s": t, "x_m": xs_px * scale, "y_m": (H - 1 - ys_px) * scale,
                       "quality": qual, "x_px": xs_px, "y_px": ys_px, "r_px": rs_px})
    wall = time.perf_counter() - t_start
    return TrackResult(df, scale, src, d_px, float(fps), n, n_lost,
                       int(np.sum(qual == "reacquired")), wall,
                       {"r_expected_px": r_exp, **st.__dict__})


def track_video(path, fps: float | None = None, *, ball_diameter_m: float | None = None,
                m_per_px: float | None = None, settings: TrackerSettings | None = None
                ) -> TrackResult:
    """Track the ball in a video file. ``fps`` defaults to a ``<stem>.json`` sidecar's (or a
    ``video.json`` beside the video, as in a measurement dataset), then to the container's
    (OpenCV), and must be > 0. Scale as in :func:`track_frames`; the sidecar's m_per_px /
    ball_diameter_m are used when both arguments are None; its ball_diameter_px sets the
    expected size."""
    import json
    path = Path(path)
    side = path.with_name(path.stem + ".json")
    if not side.is_file():  # a measurement dataset's videos/video.json (DESIGN.md)
        side = path.with_name("video.json")
    meta = {}
    if side.is_file():
        try:
            meta = json.loads(side.read_text())
        except json.JSONDecodeError as exc:
            raise TrackingError(f"{side}: not valid JSON ({exc})") from None
    cap = open_video(path)
    if fps is None:
        fps = meta.get("fps") or cap.get(_cv2().CAP_PROP_FPS)
    if not (fps and fps > 0):
        cap.release()
        raise TrackingError(f"{path}: fps must be > 0, got {fps}")
    if m_per_px is None and ball_diameter_m is None:  # explicit arguments win as a pair
        m_per_px = meta.get("m_per_px")
        ball_diameter_m = meta.get("ball_diameter_m")
    r_hint = meta.get("ball_diameter_px")
    try:
        return track_frames(_threaded(iter_gray(cap)), float(fps),
                            ball_radius_px=None if r_hint is None else 0.5 * float(r_hint),
                            ball_diameter_m=ball_diameter_m, m_per_px=m_per_px,
                            settings=settings, source=str(path))
    finally:
        cap.release()


def _threaded(gen, depth: int = 64):
    """Decode in a background thread (OpenCV releases the GIL) while the caller tracks."""
    import queue
    import threading
    q: queue.Queue = queue.Queue(maxsize=depth)
    end = object()
    stop = threading.Event()

    def work():
        try:
            for f in gen:
                while not stop.is_set():
                    try:
                        q.put(f, timeout=0.1)
                        break
                    except queue.Full:
                        continue
                if stop.is_set():
                    return
        finally:
            try:
                q.put(end, timeout=1.0)
            except queue.Full:  # the consumer has gone
                pass

    th = threading.Thread(target=work, daemon=True)
    th.start()
    try:
        while True:
            f = q.get()
            if f is end:
                return
            yield f
    finally:
        stop.set()
        th.join(timeout=5)


def write_track(track: pd.DataFrame, out) -> Path:
    """Write a track CSV atomically (temp file, then rename)."""
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".tmp-{out.name}-{os.getpid()}")
    track.to_csv(tmp, index=False)
    os.replace(tmp, out)
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m analysis.tracking",
                                description="Track one ball in a high-speed video -> track CSV "
                                            "(t_s, x_m, y_m, quality, x_px, y_px, r_px).")
    p.add_argument("video")
    p.add_argument("--fps", type=float, default=None, help="frame rate (default: sidecar/video)")
    p.add_argument("--ball-diameter-mm", type=float, default=None,
                   help="real ball diameter; the scale comes from its size in pixels")
    p.add_argument("--m-per-px", type=float, default=None, help="scale, overrides the ball size")
    p.add_argument("--out", required=True, help="track CSV to write")
    a = p.parse_args(argv)
    try:
        res = track_video(a.video, a.fps,
                          ball_diameter_m=None if a.ball_diameter_mm is None
                          else a.ball_diameter_mm * 1e-3, m_per_px=a.m_per_px)
        write_track(res.track, a.out)
    except (TrackingError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"{a.out}: {res.n_frames} frames, {res.n_lost} lost, {res.n_reacquired} reacquired, "
          f"scale {res.m_per_px * 1e3:.5f} mm/px ({res.scale_source}, ball "
          f"{res.ball_diameter_px:.2f} px), {res.n_frames / res.wall_s:.0f} frames/s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
