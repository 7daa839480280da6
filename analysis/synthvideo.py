"""Synthetic high-speed video of the ball (and the analytic 1-D bounce model that drives it).

Two pieces, both pure compute plus a CLI:

* :class:`BounceTrack` / :func:`bounce_track` - an ANALYTIC 1-D MODEL (not the twin): a ball moving
  at constant speed between the two end caps of a jar whose centre moves as x_jar = A sin(2 pi f t);
  at each end impact the ball's velocity relative to the wall is reversed and scaled by the
  restitution e (v' = (1 + e) v_wall - e v). Gravity, friction, spin and the jar's radial room are
  ignored. It is exact between events (piecewise linear in time), so it gives the true mean speed
  and the true collision times that the observation operator must recover.
* :func:`render_video` - draws a trajectory (a :class:`BounceTrack`, any object with ``position(t)``
  / ``jar_position(t)``, or a twin recording) as a camera would see it: the ball as a shaded disc
  with a highlight, the jar's outline moving with jar_x_m, motion blur from the exposure time
  (sub-frame positions averaged), sensor noise, lighting flicker and an opaque bar that hides part
  of the image. Writes a standard video file (OpenCV VideoWriter) plus a ground-truth CSV
  (t_s, x_px, y_px, x_m, y_m, jar_x_m, jar_x_px) and a ``video.json`` sidecar (fps, m_per_px,
  ball_diameter_px, ...).

Codec: the default is raw 8-bit grey (FourCC ``GREY``) in Matroska (.mkv): lossless and the fastest
to decode here (~8000 frames/s at 512x256); ``FFV1`` (.mkv) is lossless and ~5x smaller but decodes
at ~800 frames/s. AVI containers are refused: OpenCV's AVI muxer here clamps the frame rate to 600/s
and loses frames at 2134 fps (tested).

Pixel convention: pixel centres at integer coordinates (OpenCV's), x to the right along the jar
axis, image rows downward; world y (= z_m, up) maps to rows as y_px = cy - y_m / m_per_px.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

#: Camera frame rate of the seed paper (Chronos 1.4).
CAMERA_FPS = 2134.0
#: Defaults of the analytic bounce model (the brief's 20.6 mm ball in the 25 mL jar).
BOUNCE_DEFAULTS = dict(amplitude_m=0.0135, inner_length_m=0.042, ball_diameter_m=0.0206,
                       restitution=0.11)


class BounceModelError(ValueError):
    """Impossible parameters of the analytic bounce model."""


# --------------------------------------------------------------------------------------------
# analytic 1-D bounce model
# --------------------------------------------------------------------------------------------
@dataclass
class BounceTrack:
    """Piecewise-linear ball motion of the analytic 1-D bounce model (lab frame).

    Segment k runs from t_events_s[k] to t_events_s[k+1]; it is free flight (stuck_side 0: x linear
    in t) or a stick (stuck_side +-1: the ball rides on that end cap, x = x_jar +- (L - d)/2).

    Attributes
    ----------
    frequency_hz, amplitude_m, inner_length_m, ball_diameter_m, restitution : float
        Model parameters (SI).
    t_events_s : ndarray, shape (k,)
        Impact times (the first entry is the start of the returned record, not an impact).
    x_events_m : ndarray, shape (k,)
        Ball centre (lab x) at those times.
    v_after_m_s : ndarray, shape (k,)
        Ball velocity (lab) just after each event.
    t0_s, t1_s : float
        The record the track was built for.
    y_m : float
        Constant camera-plane height of the ball (the model is 1-D).
    """

    frequency_hz: float
    amplitude_m: float
    inner_length_m: float
    ball_diameter_m: float
    restitution: float
    t_events_s: np.ndarray
    x_events_m: np.ndarray
    v_after_m_s: np.ndarray
    t0_s: float
    t1_s: float
    y_m: float = 0.0
    stuck_side: np.ndarray | None = None
    is_impact: np.ndarray | None = None

    def __post_init__(self):
        n = len(self.t_events_s)
        if self.stuck_side is None:
            self.stuck_side = np.zeros(n, int)
        if self.is_impact is None:
            self.is_impact = np.r_[False, np.ones(n - 1, bool)]

    @property
    def half_gap_m(self) -> float:
        return 0.5 * (self.inner_length_m - self.ball_diameter_m)

    @property
    def omega(self) -> float:
        return 2.0 * math.pi * self.frequency_hz

    def jar_position(self, t):
        """Jar displacement x_jar = A sin(2 pi f t) [m], same shape as t [s]."""
        return self.amplitude_m * np.sin(self.omega * np.asarray(t, float))

    def jar_velocity(self, t):
        """Jar velocity [m/s]."""
        return self.amplitude_m * self.omega * np.cos(self.omega * np.asarray(t, float))

    def _seg(self, t):
        t = np.asarray(t, float)
        k = np.searchsorted(self.t_events_s, t, side="right") - 1
        return t, np.clip(k, 0, len(self.t_events_s) - 1)

    def position(self, t):
        """Ball centre (x_m, y_m) in the lab frame at times t [s]; arrays shaped like t."""
        t, k = self._seg(t)
        s = self.stuck_side[k]
        x = np.where(s == 0, self.x_events_m[k] + self.v_after_m_s[k] * (t - self.t_events_s[k]),
                     self.jar_position(t) + s * self.half_gap_m)
        return x, np.full_like(x, self.y_m)

    def velocity(self, t):
        """Ball velocity (lab) [m/s] at times t."""
        t, k = self._seg(t)
        return np.where(self.stuck_side[k] == 0, self.v_after_m_s[k], self.jar_velocity(t))

    def impact_times(self, t0=None, t1=None) -> np.ndarray:
        """End-cap impact times inside [t0, t1] [s] (releases from a stick are not impacts)."""
        t0 = self.t0_s if t0 is None else t0
        t1 = self.t1_s if t1 is None else t1
        te = self.t_events_s[self.is_impact]
        return te[(te >= t0) & (te <= t1)]

    def true_mean_speed(self, t0=None, t1=None, frame: str = "lab", n: int = 200001) -> float:
        """Time-averaged |v| over [t0, t1] [m/s]; exact in the lab frame, fine quadrature in the jar."""
        t0 = self.t0_s if t0 is None else t0
        t1 = self.t1_s if t1 is None else t1
        if frame not in ("lab", "jar"):
            raise ValueError(f"frame must be 'lab' or 'jar', got {frame!r}")
        te = self.t_events_s
        edges = np.unique(np.concatenate([[t0], te[(te > t0) & (te < t1)], [t1]]))
        total = 0.0
        for a, b in zip(edges[:-1], edges[1:]):
            k = np.searchsorted(te, 0.5 * (a + b), side="right") - 1
            if frame == "lab" and self.stuck_side[k] == 0:
                total += abs(self.v_after_m_s[k]) * (b - a)
                continue
            if frame == "jar" and self.stuck_side[k] != 0:
                continue  # riding on the wall: no speed relative to the jar
            tt = np.linspace(a, b, 801)
            vv = self.velocity(tt) - (self.jar_velocity(tt) if frame == "jar" else 0.0)
            total += float(np.trapezoid(np.abs(vv), tt))
        return total / (t1 - t0)

    def reversal_times(self, t0=None, t1=None, frame: str = "lab", n: int = 400001) -> np.ndarray:
        """Times where the ball's x-velocity changes sign [s] - what the paper counts as collisions.

        In the lab frame an impact need not reverse the ball (the wall can catch the receding ball
        a second time), so this can be fewer than :meth:`impact_times`.
        """
        t0 = self.t0_s if t0 is None else t0
        t1 = self.t1_s if t1 is None else t1
        t = np.linspace(t0, t1, n)
        v = self.velocity(t) - (self.jar_velocity(t) if frame == "jar" else 0.0)
        sg = np.sign(v)
        nz = sg != 0
        t, sg = t[nz], sg[nz]
        k = np.flatnonzero(sg[1:] != sg[:-1])
        return 0.5 * (t[k] + t[k + 1])

    def sample(self, fps: float, t0=None, t1=None, frame: str = "lab") -> pd.DataFrame:
        """Track sampled at the camera rate: columns t_s, x_m, y_m, jar_x_m (x lab or jar frame)."""
        t0 = self.t0_s if t0 is None else t0
        t1 = self.t1_s if t1 is None else t1
        n = int(math.floor((t1 - t0) * fps + 1e-9)) + 1
        t = t0 + np.arange(n) / fps
        x, y = self.position(t)
        xj = self.jar_position(t)
        if frame == "jar":
            x = x - xj
        elif frame != "lab":
            raise ValueError(f"frame must be 'lab' or 'jar', got {frame!r}")
        return pd.DataFrame({"t_s": t, "x_m": x, "y_m": y, "jar_x_m": xj})


def _check_bounce_params(frequency_hz, duration_s, amplitude_m, inner_length_m, ball_diameter_m,
                         restitution):
    f, A, L, d, e = (float(frequency_hz), float(amplitude_m), float(inner_length_m),
                     float(ball_diameter_m), float(restitution))
    if not (f > 0 and math.isfinite(f)):
        raise BounceModelError(f"frequency_hz must be > 0, got {frequency_hz}")
    if not duration_s > 0:
        raise BounceModelError(f"duration_s must be > 0, got {duration_s}")
    if not (0 < e <= 1):
        raise BounceModelError(f"restitution must lie in (0, 1], got {restitution}")
    if not (A >= 0 and d > 0 and L > d):
        raise BounceModelError(f"need amplitude >= 0 and inner_length > ball_diameter > 0, "
                               f"got A={A}, L={L}, d={d}")
    return f, A, L, d, e


def periodic_orbit(frequency_hz: float, *, amplitude_m: float = 0.0135,
                   inner_length_m: float = 0.042, ball_diameter_m: float = 0.0206,
                   restitution: float = 0.11) -> tuple[float, float]:
    """Symmetric end-to-end orbit of the 1-D bounce model (two end impacts per jar cycle).

    The ball hits the +x end cap at jar phase theta (wall velocity A w cos(theta) < 0, i.e. the
    wall moving towards the ball), flies back at constant speed V and hits the -x end cap half a
    cycle later. Impact law: V = (1 + e) / (1 - e) * A w |cos(theta)|; flight: V T/2 equals the gap
    L - d plus the jar's displacement 2 A sin(theta), i.e.
    ``(1 + e)/(1 - e) pi A |cos(theta)| = (L - d) + 2 A sin(theta)``, one root in (pi/2, pi).

    Returns
    -------
    theta_rad : float
        Jar phase (omega t mod 2 pi) of the impacts on the +x end.
    speed_m_s : float
        Ball speed V between impacts (lab frame).
    """
    f, A, L, d, e = _check_bounce_params(frequency_hz, 1.0, amplitude_m, inner_length_m,
                                         ball_diameter_m, restitution)
    from scipy.optimize import brentq
    k = (1 + e) / (1 - e)
    g = L - d

    def F(th):
        return -k * math.pi * A * math.cos(th) - 2 * A * math.sin(th) - g

    lo, hi = math.pi / 2, math.pi
    if A == 0 or F(lo) * F(hi) > 0:
        raise BounceModelError(f"no end-to-end orbit for A={A} m, gap={g} m, e={e}: the stroke "
                               f"is too short for the ball to cross the jar in half a cycle")
    th = brentq(F, lo, hi, xtol=1e-15)
    return th, k * A * 2 * math.pi * f * abs(math.cos(th))


def bounce_track(frequency_hz: float, duration_s: float, *, amplitude_m: float = 0.0135,
                 inner_length_m: float = 0.042, ball_diameter_m: float = 0.0206,
                 restitution: float = 0.11, mode: str = "integrate", settle_cycles: int = 60,
                 phase_s: float = 0.0, y_m: float = 0.0) -> BounceTrack:
    """A record of the analytic 1-D bounce model.

    ``mode='integrate'`` (default) runs the event-driven dynamics with sticking: a chatter whose
    relative speed has died out becomes a stick, and the ball rides on the end cap until the
    wall's acceleration turns away from it (sin(w t) = 0), leaving at the wall's speed. For the
    paper's e = 0.11 the settled motion at 22.5-30 Hz is: impact, stick, release at the jar's
    peak speed A w, flight to the other end (see results/observe/frame_of_reference.md).
    ``mode='periodic'`` builds the symmetric end-to-end orbit of :func:`periodic_orbit`
    exactly (two end impacts per cycle, the motion the paper filmed). ``mode='integrate'`` runs the
    event-driven dynamics from the jar centre for ``settle_cycles`` and keeps the last
    ``duration_s``; with small e that orbit need not be the periodic one (the ball can chatter
    against one end - a real feature of the model, see DESIGN.md on motion modes).

    The ball starts on the jar's axis centre moving at A*omega and is run for ``settle_cycles`` jar
    cycles (transients decay by a factor ~e per impact), then ``duration_s`` are kept. Times are
    shifted so the record starts at t = phase_s (jar phase keeps x_jar = A sin(2 pi f t)).

    Parameters
    ----------
    frequency_hz : float
        Jar frequency f [Hz] (> 0).
    duration_s : float
        Length of the returned record [s] (> 0).
    amplitude_m, inner_length_m, ball_diameter_m : float
        Half stroke A, inner length of the jar along x, ball diameter [m].
    restitution : float
        Coefficient of restitution e in (0, 1].
    settle_cycles : int
        Jar cycles simulated before the record starts.
    phase_s : float
        Start time of the record [s] (the model's clock runs through the settling time).
    y_m : float
        Constant camera-plane height of the ball [m].

    Returns
    -------
    BounceTrack
    """
    f, A, L, d, e = _check_bounce_params(frequency_hz, duration_s, amplitude_m, inner_length_m,
                                         ball_diameter_m, restitution)
    if mode == "periodic":
        th, V = periodic_orbit(f, amplitude_m=A, inner_length_m=L, ball_diameter_m=d,
                               restitution=e)
        w = 2 * math.pi * f
        h = 0.5 * (L - d)
        T = 1.0 / f
        t_plus0 = th / w  # impacts on the +x end at t_plus0 + n T; on the -x end half a cycle on
        n0 = math.floor((phase_s - t_plus0) / T) - 1
        n1 = math.ceil((phase_s + duration_s - t_plus0) / T) + 1
        ts, xs, vs = [], [], []
        for n in range(n0, n1 + 1):
            tp = t_plus0 + n * T
            ts += [tp, tp + T / 2]
            xs += [A * math.sin(w * tp) + h, A * math.sin(w * (tp + T / 2)) - h]
            vs += [-V, V]
        ts, xs, vs = np.array(ts), np.array(xs), np.array(vs)
        k0 = np.searchsorted(ts, phase_s, side="right") - 1
        x0 = xs[k0] + vs[k0] * (phase_s - ts[k0])
        return BounceTrack(f, A, L, d, e, np.concatenate([[phase_s], ts[k0 + 1:]]),
                           np.concatenate([[x0], xs[k0 + 1:]]),
                           np.concatenate([[vs[k0]], vs[k0 + 1:]]),
                           float(phase_s), float(phase_s + duration_s), float(y_m))
    if mode != "integrate":
        raise BounceModelError(f"mode must be 'periodic' or 'integrate', got {mode!r}")
    w = 2 * math.pi * f
    h = 0.5 * (L - d)  # ball-centre travel room either side of the jar centre
    T = 1.0 / f
    from scipy.optimize import brentq

    def xj(t):
        return A * math.sin(w * t)

    def vj(t):
        return A * w * math.cos(w * t)

    t_settle = settle_cycles / f
    t_end = phase_s + duration_s
    # run the clock from phase_s - t_settle (whole cycles before), so the jar phase is unchanged
    t = phase_s - t_settle
    x = xj(t)
    v = 1.5 * A * w if A > 0 else 0.1  # not equal to the jar speed, so it leaves the centre
    ts, xs, vs, kinds, imp = [t], [x], [v], [0], [False]
    dt_scan = T / 400.0
    u_stick = 1e-4 * max(A * w, 1e-3)  # relative speed below which a chatter is a stick
    n_guard = 0
    while t < t_end:
        n_guard += 1
        if n_guard > 2_000_000:
            raise BounceModelError("bounce model did not advance")

        def gap(tt, x=x, v=v, t=t):  # room to the nearer end cap; > 0 while inside
            return h - abs((x + v * (tt - t)) - xj(tt))

        ta, ga = t, gap(t)
        tc = None
        while ta < t_end + 2 * dt_scan:
            tb = ta + dt_scan
            gb = gap(tb)
            if gb <= 0:
                tc = brentq(gap, ta, tb, xtol=1e-15, rtol=1e-15) if ga > 0 else tb
                break
            ta, ga = tb, gb
        if tc is None:
            break
        xc = x + v * (tc - t)
        side = 1.0 if xc - xj(tc) > 0 else -1.0  # +1: the +x end cap
        vw = vj(tc)
        u = v - vw
        vn = vw - e * u
        ts.append(tc)
        xs.append(xc)
        imp.append(True)
        pushing = side * (-A * w * w * math.sin(w * tc)) < 0  # wall accelerates into the ball
        if e * abs(u) < u_stick and pushing:
            # chatter converged: the ball rides on the wall until the wall's acceleration turns
            # away from it (sin(w t) = 0), then leaves with the wall's velocity
            vs.append(vw)
            kinds.append(int(side))
            n_rel = math.floor(w * tc / math.pi) + 1  # next zero of sin(w t)
            t_rel = n_rel * math.pi / w
            t, x, v = t_rel, xj(t_rel) + side * h, vj(t_rel)
            ts.append(t)
            xs.append(x)
            vs.append(v)
            kinds.append(0)
            imp.append(False)
        else:
            vs.append(vn)
            kinds.append(0)
            t, x, v = tc, xc, vn
    ts, xs, vs = np.array(ts), np.array(xs), np.array(vs)
    kinds, imp = np.array(kinds, int), np.array(imp, bool)
    k0 = np.searchsorted(ts, phase_s, side="right") - 1
    if kinds[k0] == 0:
        x0, v0 = xs[k0] + vs[k0] * (phase_s - ts[k0]), vs[k0]
    else:
        x0, v0 = xj(phase_s) + kinds[k0] * h, vj(phase_s)
    return BounceTrack(f, A, L, d, e, np.concatenate([[phase_s], ts[k0 + 1:]]),
                       np.concatenate([[x0], xs[k0 + 1:]]), np.concatenate([[v0], vs[k0 + 1:]]),
                       float(phase_s), float(phase_s + duration_s), float(y_m),
                       stuck_side=np.concatenate([[kinds[k0]], kinds[k0 + 1:]]),
                       is_impact=np.concatenate([[False], imp[k0 + 1:]]))


# --------------------------------------------------------------------------------------------
# rendering
# --------------------------------------------------------------------------------------------
class VideoWriteError(RuntimeError):
    """OpenCV could not write the requested video."""


@dataclass
class Camera:
    """How the synthetic camera sees the scene.

    Attributes
    ----------
    fps : float
        Frame rate [1/s].
    width_px, height_px : int
        Image size.
    m_per_px : float
        Scale [m/px] (default 0.2 mm/px: the 20.6 mm ball is 103 px across).
    exposure_s : float
        Exposure time [s] (motion blur); frame time = middle of the exposure.
    noise_sigma : float
        Sensor noise, standard deviation in grey levels (0-255).
    flicker : float
        Relative amplitude of lighting flicker (mains 100 Hz plus 1/3 of it random per frame).
    occluder : bool
        Draw an opaque dark bar over part of the image.
    occluder_x_px, occluder_width_px, occluder_top_frac : float
        Bar position, width, and the fraction of the image height it covers from the top.
    background, ball_level, wall_level, occluder_level : float
        Grey levels; the ball's limb is at background + 0.7 (ball_level - background).
    jar_inner_diameter_m, jar_wall_px : float
        Jar outline drawn as dark lines just outside the inner volume.
    """

    fps: float = CAMERA_FPS
    width_px: int = 512
    height_px: int = 256
    m_per_px: float = 2.0e-4
    exposure_s: float = 100e-6
    noise_sigma: float = 2.0
    flicker: float = 0.03
    occluder: bool = True
    occluder_x_px: float = 400.0
    occluder_width_px: float = 12.0
    occluder_top_frac: float = 0.6
    background: float = 70.0
    ball_level: float = 210.0
    wall_level: float = 25.0
    occluder_level: float = 12.0
    jar_inner_diameter_m: float = 0.0275
    jar_wall_px: float = 3.0

    def to_px(self, x_m, y_m):
        """World camera-plane (x right, y up) [m] -> pixel (x_px, y_px), image centre = origin."""
        cx = (self.width_px - 1) / 2.0
        cy = (self.height_px - 1) / 2.0
        return cx + np.asarray(x_m) / self.m_per_px, cy - np.asarray(y_m) / self.m_per_px


def _disc_coverage(xx, yy, xc, yc, r):
    """Anti-aliased coverage (0..1) of a disc of radius r [px] on pixel centres xx, yy."""
    d = np.sqrt((xx - xc) ** 2 + (yy - yc) ** 2)
    return np.clip(r + 0.5 - d, 0.0, 1.0), d


def render_frames(positions, jar_x_m, cam: Camera, ball_diameter_m: float,
                  jar_inner_length_m: float, rng=None, t_s=None, frame: str = "lab"):
    """Render frames (generator of uint8 arrays, shape (height_px, width_px)).

    Parameters
    ----------
    positions : callable
        ``positions(t) -> (x_m, y_m)`` lab-frame ball centre for an array of times [s].
    jar_x_m : callable
        ``jar_x_m(t)`` jar displacement [m].
    cam : Camera
    ball_diameter_m, jar_inner_length_m : float
    rng : numpy.random.Generator
    t_s : ndarray, shape (n,)
        Frame times (middle of exposure) [s].
    frame : {'lab', 'jar'}
        'jar': the camera rides on the jar (ball drawn at x - jar_x, jar static).
    """
    rng = np.random.default_rng(0) if rng is None else rng
    H, W = cam.height_px, cam.width_px
    r_px = 0.5 * ball_diameter_m / cam.m_per_px
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
    bg = np.full((H, W), cam.background, np.float32)
    C = cam.ball_level - cam.background
    for t in np.asarray(t_s, float):
        # sub-exposure sample times: enough that the ball moves <= 0.25 px between them
        v_est = 3.0  # m/s, an upper bound used only to pick the sub-sample count
        blur_px = v_est * cam.exposure_s / cam.m_per_px
        n_sub = max(1, int(math.ceil(blur_px / 0.25)))
        ts = t + (np.arange(n_sub) + 0.5) / n_sub * cam.exposure_s - 0.5 * cam.exposure_s \
            if cam.exposure_s > 0 else np.array([t])
        xb, yb = positions(ts)
        xb = np.asarray(xb, float)
        yb = np.asarray(yb, float)
        xj_mid = float(jar_x_m(np.array([t]))[0])
        if frame == "jar":
            xb = xb - jar_x_m(ts)
            xj_draw = 0.0
        else:
            xj_draw = xj_mid
        img = bg.copy()
        # jar outline (dark walls just outside the inner volume), at mid-exposure
        jx0, jy0 = cam.to_px(xj_draw - jar_inner_length_m / 2, cam.jar_inner_diameter_m / 2)
        jx1, jy1 = cam.to_px(xj_draw + jar_inner_length_m / 2, -cam.jar_inner_diameter_m / 2)
        wpx = cam.jar_wall_px
        walls = np.zeros((H, W), np.float32)
        inner_y = (yy >= jy0 - 0.5) & (yy <= jy1 + 0.5)
        inner_x = (xx >= jx0 - 0.5) & (xx <= jx1 + 0.5)
        # end caps: coverage of the bands [jx0 - wpx, jx0] and [jx1, jx1 + wpx]
        left = np.clip(np.minimum(xx + 0.5 - (jx0 - wpx), jx0 - (xx - 0.5)), 0, 1)
        right = np.clip(np.minimum(xx + 0.5 - jx1, jx1 + wpx - (xx - 0.5)), 0, 1)
        top = np.clip(np.minimum(yy + 0.5 - (jy0 - wpx), jy0 - (yy - 0.5)), 0, 1)
        bot = np.clip(np.minimum(yy + 0.5 - jy1, jy1 + wpx - (yy - 0.5)), 0, 1)
        walls = np.maximum(np.maximum(left, right) * (inner_y | (top > 0) | (bot > 0)),
                           np.maximum(top, bot) * (inner_x | (left > 0) | (right > 0)))
        img += walls * (cam.wall_level - cam.background)
        # ball: shaded disc with a highlight, averaged over the exposure
        xp, yp = cam.to_px(xb, yb)
        x0 = int(max(0, math.floor(xp.min() - r_px - 2)))
        x1 = int(min(W, math.ceil(xp.max() + r_px + 3)))
        y0 = int(max(0, math.floor(yp.min() - r_px - 2)))
        y1 = int(min(H, math.ceil(yp.max() + r_px + 3)))
        if x1 > x0 and y1 > y0:
            sx, sy = xx[y0:y1, x0:x1], yy[y0:y1, x0:x1]
            acc = np.zeros_like(sx)
            for xc, yc in zip(xp, yp):
                cov, d = _disc_coverage(sx, sy, xc, yc, r_px)
                rr = np.clip(d / r_px, 0, 1)
                shade = 0.7 + 0.3 * np.sqrt(1 - rr ** 2)
                hl = 0.25 * np.exp(-((sx - xc + 0.35 * r_px) ** 2 + (sy - yc + 0.35 * r_px) ** 2)
                                   / (2 * (0.15 * r_px) ** 2))
                ball = cam.background + C * (shade + hl)
                base = img[y0:y1, x0:x1]
                acc += cov * ball + (1 - cov) * base
            img[y0:y1, x0:x1] = acc / len(xp)
        if cam.occluder:
            ox0 = cam.occluder_x_px
            ox1 = ox0 + cam.occluder_width_px
            ocov = np.clip(np.minimum(xx + 0.5 - ox0, ox1 - (xx - 0.5)), 0, 1)
            ocov *= np.clip(cam.occluder_top_frac * H - (yy - 0.5), 0, 1)
            img = img * (1 - ocov) + ocov * cam.occluder_level
        gain = 1.0 + cam.flicker * (math.sin(2 * math.pi * 100.0 * t) + rng.normal(0, 1 / 3))
        img = img * gain
        if cam.noise_sigma > 0:
            img = img + rng.normal(0.0, cam.noise_sigma, img.shape).astype(np.float32)
        yield np.clip(np.rint(img), 0, 255).astype(np.uint8)


def _fourcc_for(path: Path, codec: str | None) -> tuple[str, int]:
    import cv2
    ext = path.suffix.lower()
    if ext == ".avi":
        raise VideoWriteError(f"{path}: AVI is refused (OpenCV's AVI muxer here clamps the rate to "
                              f"600/s and drops frames at 2134 fps); use .mkv")
    codec = codec or ("GREY" if ext == ".mkv" else None)
    if codec is None:
        raise VideoWriteError(f"{path}: unknown video extension {ext!r}; use .mkv")
    return codec, cv2.VideoWriter_fourcc(*codec.ljust(4)[:4])


def write_video(path, frames, fps: float, size: tuple[int, int], codec: str | None = None) -> int:
    """Write grey uint8 frames to ``path`` via cv2.VideoWriter (temp file, then rename).

    Returns the number of frames written.
    """
    import cv2
    path = Path(path)
    if not fps > 0:
        raise VideoWriteError(f"fps must be > 0, got {fps}")
    codec, fourcc = _fourcc_for(path, codec)
    tmp = path.with_name(f".tmp-{path.stem}-{os.getpid()}{path.suffix}")
    w = cv2.VideoWriter(str(tmp), fourcc, float(fps), size, False)
    if not w.isOpened():
        raise VideoWriteError(f"{path}: OpenCV cannot write codec {codec!r}")
    n = 0
    try:
        for f in frames:
            w.write(f)
            n += 1
    finally:
        w.release()
    if n == 0:
        tmp.unlink(missing_ok=True)
        raise VideoWriteError(f"{path}: no frames to write")
    os.replace(tmp, path)
    return n


def _trajectory_source(source, frame_defaults: dict):
    """positions(t), jar(t), t-range, ball diameter, jar length from a BounceTrack or recording."""
    if isinstance(source, BounceTrack):
        return (source.position, source.jar_position, source.t0_s, source.t1_s,
                source.ball_diameter_m, source.inner_length_m)
    from analysis.observe import load_recording
    rec = load_recording(source)
    tr = rec.trajectory
    t = tr["t_s"].to_numpy(float)
    x = tr["x_m"].to_numpy(float)
    z = tr["z_m"].to_numpy(float)
    jx = tr["jar_x_m"].to_numpy(float)
    z0 = float(np.median(z)) if frame_defaults.get("center_z", True) else 0.0
    cfg = rec.meta.get("config", {})
    d = float(cfg.get("ball_diameter_m", BOUNCE_DEFAULTS["ball_diameter_m"]))
    L = float(rec.meta.get("jar", {}).get("inner_length_m", BOUNCE_DEFAULTS["inner_length_m"]))
    return ((lambda tt: (np.interp(tt, t, x), np.interp(tt, t, z) - z0)),
            (lambda tt: np.interp(tt, t, jx)), float(t[0]), float(t[-1]), d, L)


def render_video(source, out_path, cam: Camera | None = None, *, t0_s=None, duration_s=None,
                 frame: str = "lab", seed: int = 0, codec: str | None = None) -> pd.DataFrame:
    """Synthetic video of a trajectory plus its ground truth.

    Parameters
    ----------
    source : BounceTrack or recording folder / object
        The motion to film (recordings: x_m and z_m - median z, jar_x_m).
    out_path : path
        Video file (.mkv). Beside it: ``<stem>_truth.csv`` and ``<stem>.json`` (the sidecar:
        fps, m_per_px, ball_diameter_px, ball_diameter_m, width/height, exposure, frame).
    cam : Camera
    t0_s, duration_s : float, optional
        Part of the trajectory to film (default: all of it).
    frame : {'lab', 'jar'}
        Lab camera on a tripod, or a camera riding on the jar.
    seed : int
        Noise and flicker seed.

    Returns
    -------
    DataFrame
        Ground truth: t_s, x_px, y_px, x_m, y_m, jar_x_m, jar_x_px (x_m in the filmed frame).
    """
    cam = Camera() if cam is None else cam
    if not cam.fps > 0:
        raise VideoWriteError(f"fps must be > 0, got {cam.fps}")
    if frame not in ("lab", "jar"):
        raise ValueError(f"frame must be 'lab' or 'jar', got {frame!r}")
    pos, jar, ta, tb, d, L = _trajectory_source(source, {})
    t0 = ta if t0_s is None else float(t0_s)
    t1 = tb if duration_s is None else t0 + float(duration_s)
    n = int(math.floor((t1 - t0) * cam.fps + 1e-9)) + 1
    t = t0 + np.arange(n) / cam.fps
    # keep the whole exposure inside the trajectory
    t = t[(t - cam.exposure_s / 2 >= ta - 1e-12) & (t + cam.exposure_s / 2 <= tb + 1e-12)]
    if len(t) == 0:
        raise ValueError("nothing to film: empty time range")
    rng = np.random.default_rng(seed)
    frames = render_frames(pos, jar, cam, d, L, rng=rng, t_s=t, frame=frame)
    out_path = Path(out_path)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    write_video(out_path, frames, cam.fps, (cam.width_px, cam.height_px), codec)
    x, y = pos(t)
    jx = jar(t)
    if frame == "jar":
        x = x - jx
    xp, yp = cam.to_px(x, y)
    truth = pd.DataFrame({"t_s": t, "x_px": xp, "y_px": yp, "x_m": x, "y_m": y, "jar_x_m": jx,
                          "jar_x_px": cam.to_px(jx if frame == "lab" else 0 * jx, 0 * jx)[0]})
    truth.to_csv(out_path.with_name(out_path.stem + "_truth.csv"), index=False)
    side = {"fps": cam.fps, "m_per_px": cam.m_per_px, "ball_diameter_m": d,
            "ball_diameter_px": d / cam.m_per_px, "width_px": cam.width_px,
            "height_px": cam.height_px, "exposure_s": cam.exposure_s,
            "noise_sigma": cam.noise_sigma, "flicker": cam.flicker, "occluder": cam.occluder,
            "frame": frame, "seed": seed}
    out_path.with_name(out_path.stem + ".json").write_text(json.dumps(side, indent=1))
    return truth


# --------------------------------------------------------------------------------------------
# noise / blur study: how tracking and v_mean errors grow
# --------------------------------------------------------------------------------------------
def film_and_measure(track: BounceTrack, cam: Camera, workdir, seed: int = 0) -> dict:
    """Render ``track``, track the video, apply the observation operator; compare with truth.

    The scale is measured from the ball's diameter in pixels (as the paper does); the v_mean
    error with the true scale is reported too, so the two error sources separate.
    """
    from analysis.tracking import track_video
    from analysis.observe import observe_track
    workdir = Path(workdir)
    vid = workdir / f"study_{seed}.mkv"
    truth = render_video(track, vid, cam, seed=seed)
    res = track_video(vid, cam.fps, ball_diameter_m=track.ball_diameter_m)
    tk = res.track
    err = np.hypot(tk.x_px - truth.x_px, tk.y_px - truth.y_px).to_numpy()
    ok = np.isfinite(err)
    t0, t1 = float(truth.t_s.iloc[0]), float(truth.t_s.iloc[-1])
    v_true = track.true_mean_speed(t0, t1)
    f_true = len(track.reversal_times(t0, t1)) / (t1 - t0)
    o = observe_track(tk.t_s, tk.x_m, tk.y_m, fps=cam.fps, frequency_hz=track.frequency_hz,
                      quality=tk.quality)
    o_plain = observe_track(tk.t_s, tk.x_m, tk.y_m, fps=cam.fps,
                            frequency_hz=track.frequency_hz, quality=tk.quality,
                            kink_correction=False)
    k_true = cam.m_per_px / res.m_per_px  # rescale to the true m_per_px
    for p in (vid, vid.with_name(vid.stem + "_truth.csv"), vid.with_name(vid.stem + ".json")):
        p.unlink(missing_ok=True)
    return {"frequency_hz": track.frequency_hz, "noise_sigma": cam.noise_sigma,
            "exposure_us": cam.exposure_s * 1e6,
            "blur_px": v_true * cam.exposure_s / cam.m_per_px,
            "occluder": cam.occluder, "flicker": cam.flicker, "n_frames": res.n_frames,
            "rms_px": float(np.sqrt(np.mean(err[ok] ** 2))), "max_px": float(np.max(err[ok])),
            "n_lost": res.n_lost, "n_reacquired": res.n_reacquired,
            "scale_err_pct": 100 * (res.m_per_px / cam.m_per_px - 1),
            "v_true_m_s": v_true, "v_obs_m_s": o.v_mean_m_s,
            "v_err_pct": 100 * (o.v_mean_m_s / v_true - 1),
            "v_err_true_scale_pct": 100 * (o.v_mean_m_s * k_true / v_true - 1),
            "v_err_plain_pct": 100 * (o_plain.v_mean_m_s / v_true - 1),
            "v_err_raw_fd_pct": 100 * (o.v_mean_raw_m_s / v_true - 1),
            "f_col_true_hz": f_true, "f_col_obs_hz": o.f_col_hz,
            "f_col_err_hz": o.f_col_hz - f_true, "track_fps": res.n_frames / res.wall_s}


def noise_blur_study(out_csv=None, frequencies=(22.5, 30.0), duration_s: float = 0.5,
                     noise_levels=(0.0, 2.0, 5.0, 10.0, 20.0),
                     exposures_us=(0.0, 100.0, 200.0, 400.0), seed: int = 0,
                     verbose: bool = True) -> pd.DataFrame:
    """Tracking and v_mean errors against sensor noise (at 100 us exposure) and motion blur (at
    noise 2 grey levels), with flicker and the occluding bar on, 512x256 px, 2134 fps.
    Writes ``out_csv`` (default results/observe/noise_blur_study.csv) atomically."""
    from analysis import config
    out_csv = Path(out_csv) if out_csv else config.OBSERVE_DIR / "noise_blur_study.csv"
    rows = []
    with tempfile.TemporaryDirectory() as td:
        for f in frequencies:
            tr = bounce_track(f, duration_s)
            cases = [(s, 100.0) for s in noise_levels] + \
                [(2.0, e) for e in exposures_us if e != 100.0]
            for i, (s, e) in enumerate(cases):
                cam = Camera(noise_sigma=s, exposure_s=e * 1e-6)
                row = film_and_measure(tr, cam, td, seed=seed + i)
                rows.append(row)
                if verbose:
                    print(f"f={f:5.1f} Hz noise={s:5.1f} exp={e:5.0f} us: rms {row['rms_px']:.3f}"
                          f" px, v err {row['v_err_pct']:+.3f} %, f_col err "
                          f"{row['f_col_err_hz']:+.2f} /s", file=sys.stderr)
    df = pd.DataFrame(rows)
    from analysis.atomic_dir import atomic_file
    with atomic_file(out_csv) as tmp:
        df.to_csv(tmp, index=False, float_format="%.6g")
    return df


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m analysis.synthvideo",
                                description="Synthetic high-speed video of the 1-D bounce model "
                                            "(or a twin recording), or the noise/blur study.",
                                epilog="example: python -m analysis.synthvideo --out film.mkv "
                                       "--frequency-hz 30 --duration-s 0.3")
    p.add_argument("--out", help="video file (.mkv) to write")
    p.add_argument("--recording", help="film a twin recording folder instead of the bounce model")
    p.add_argument("--frequency-hz", type=float, default=30.0,
                   help="jar frequency of the bounce model [Hz] (default %(default)s)")
    p.add_argument("--duration-s", type=float, default=0.3,
                   help="length of the bounce model's video [s] (default %(default)s)")
    p.add_argument("--fps", type=float, default=CAMERA_FPS,
                   help="camera frame rate [frames/s] (default %(default)s)")
    p.add_argument("--exposure-us", type=float, default=100.0,
                   help="exposure time per frame, sets the motion blur [us] "
                        "(default %(default)s)")
    p.add_argument("--noise", type=float, default=2.0,
                   help="sensor noise sigma [grey levels] (default %(default)s)")
    p.add_argument("--no-occluder", action="store_true")
    p.add_argument("--frame", choices=("lab", "jar"), default="lab")
    p.add_argument("--seed", type=int, default=0,
                   help="random seed of the noise and flicker [-] (default %(default)s)")
    p.add_argument("--noise-study", action="store_true",
                   help="run the noise/blur study -> results/observe/noise_blur_study.csv")
    a = p.parse_args(argv)
    try:
        if a.noise_study:
            df = noise_blur_study(a.out, seed=a.seed)
            with pd.option_context("display.width", 200, "display.max_columns", 30):
                print(df.round(4).to_string(index=False))
            return 0
        if not a.out:
            p.error("--out is required")
        cam = Camera(fps=a.fps, exposure_s=a.exposure_us * 1e-6, noise_sigma=a.noise,
                     occluder=not a.no_occluder)
        src = a.recording or bounce_track(a.frequency_hz, a.duration_s)
        truth = render_video(src, a.out, cam, frame=a.frame, seed=a.seed)
    except (ValueError, RuntimeError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"{a.out}: {len(truth)} frames, truth in {Path(a.out).stem}_truth.csv")
    return 0


if __name__ == "__main__":
    sys.exit(main())
