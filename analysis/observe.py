"""Observation operator: a ball track (from video or from the twin) -> v_mean, E_kin, f_col.

ONE operator for both sides (seed paper, Sec. 2.5 and 3.1.1, eqs 1-3, Figure 5):

1. the camera-plane track (t, x, y; x along the jar axis) sampled at the camera rate;
2. velocity by finite differences between consecutive frames (eqs 1-2), v = sqrt(vx^2 + vy^2)
   (eq 3, 2-D: the camera does not see depth);
3. Savitzky-Golay smoothing of the velocity (scipy.signal.savgol_filter);
4. collisions = sign changes of the smoothed x-velocity, with a dead band (hysteresis): the sign
   state flips only when the velocity crosses the OPPOSITE threshold, so noise near zero makes no
   false collisions;
5. v_mean = time average of the speed over the record, E_kin = 1/2 m v_mean^2,
   f_col = the inverse mean interval between collisions (``yade_scripts/twin_modes.collision_rate``,
   the scene's own rule): not quantised by the record length, with its standard error.

The same function serves a tracked video (:func:`observe_track`, :func:`observe_track_file`) and a
twin recording (:func:`observe_recording`: trajectory.csv sampled at the camera rate and projected on
the camera plane: camera x = x_m, camera y = z_m). Frames: ``lab`` (a camera on a tripod) or ``jar``
(a camera riding on the jar: x - jar_x_m).

Smoothing window rule
---------------------
With f the jar frequency and two end impacts per cycle, the time between impacts is fps / (2 f)
frames (35.6 frames at 2134 fps and 30 Hz). The window is the largest odd number of frames not
above a QUARTER of that (7 frames at 30 Hz, 11 at 22.5 Hz), at least polyorder + 3: the smoother
then never spans two impacts, and each flight holds >= 4 windows. If f is not given it is taken
from the spectrum of x (dominant frequency).

Impacts are sharp (contact ~0.1 ms < one frame). A smoother run across an impact rounds the
reversal and lowers mean |v| by ~ window / (4 * frames between impacts) - several per cent - and
even the raw difference across the impact frame cuts the corner (-0.5 frame per impact: -1.4 % at
30 Hz, 2134 fps). Hence, by default (``kink_correction=True``): at each detected collision a local
test decides between a smooth turn (velocity linear through the reversal, e.g. a sinusoid) and a
kink (a jump between similar speeds of opposite sign); at a kink the three frame-differences around it are dropped, the velocity is
smoothed on each side separately, and the speed is interpolated across the dropped frames (the
time integral of the speed is a trapezoid over the kept samples). ``kink_correction=False`` is
the paper's plain recipe (smoothing straight through), kept to measure its bias.

Gaps
----
Rows with NaN position or quality ``lost`` are gaps. Velocity is never differentiated across a
gap; the track is split into runs. A gap shorter than a quarter of the inter-impact time is
bridged for collision counting (at most one reversal fits in it; the sign before and after tells);
longer gaps end a run, and their time is excluded from the duration. The gap fraction is reported;
above ``max_gap_fraction`` (default 0.2) :class:`TrackGapError` is raised.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.signal import savgol_filter, savgol_coeffs

from analysis import config
from yade_scripts.twin_modes import collision_rate

#: Seed paper's camera (Chronos 1.4) frame rate [1/s] (declared with the run config)
CAMERA_FPS = config.twin_config.CAMERA_FPS
#: Steel density used when only a ball diameter is known [kg/m3] (Table 2).
STEEL_DENSITY_KG_M3 = 7800.0
TRACK_COLUMNS = ("t_s", "x_m", "y_m")
#: the recording's columns this module reads (a subset of the schema declared once in
#: yade_scripts/twin_config.py; tests/test_twin_runner.py checks it is one)
TRAJECTORY_COLUMNS = ("t_s", "x_m", "y_m", "z_m", "vx_m_s", "vy_m_s", "vz_m_s", "jar_x_m",
                      "jar_vx_m_s")
IMPACT_COLUMNS = ("event_id", "t_start_s", "t_end_s", "where")
#: Plausible measured collision frequency as a multiple of 2 f (two end impacts per jar cycle):
#: a result outside [low, high] x 2 f is flagged (``f_col_suspect``) and the CLI warns; it is
#: not an error (a ball sliding or stuck at one end can be real), but usually means a wrong
#: frequency or frame rate, or a track that misses reversals.
F_COL_PLAUSIBLE_RATIO = (0.5, 1.5)


class ObserveError(ValueError):
    """Bad input to the observation operator (names the file / row / column where known)."""


class TrackGapError(ObserveError):
    """The track has too many lost frames to give trustworthy figures."""


# --------------------------------------------------------------------------------------------
# result object
# --------------------------------------------------------------------------------------------
@dataclass
class ObservationResult:
    """What the operator measured from one track.

    Attributes
    ----------
    v_mean_m_s : float
        Time-averaged camera-plane speed (eq 3 in 2-D) [m/s].
    v_mean_raw_m_s : float
        Mean of |raw finite-difference velocity| (no smoothing, no kink handling) [m/s].
    e_kin_j : float
        1/2 m v_mean^2 [J] (NaN when the mass is unknown).
    f_col_hz : float
        Collision rate: the inverse mean interval between collisions within unbroken stretches
        of the track (n / observed time when fewer than 2 intervals are seen) [1/s].
    f_col_se_hz : float
        Its standard error (renewal process: rate * sd(intervals) / (mean * sqrt(n))) [1/s].
    n_collisions : int
    collision_times_s : ndarray, shape (n_collisions,)
    t_s : ndarray, shape (m,)
        Times of the velocity samples (midpoints of consecutive frames) [s].
    vx_m_s, vy_m_s : ndarray, shape (m,)
        Smoothed velocity (NaN at gaps and at dropped kink frames) [m/s].
    vx_raw_m_s, vy_raw_m_s : ndarray, shape (m,)
        Finite differences (eqs 1-2) [m/s].
    duration_s : float
        Observed time (gaps longer than the bridge limit excluded) [s].
    gap_fraction : float
        Fraction of frames lost.
    n_kinks : int
        Collisions treated as sharp kinks.
    count_duration_s : float
        Time base of f_col: duration_s plus bridged short gaps [s].
    params : dict
        fps, frequency_hz, window_frames, polyorder, deadband_m_s, noise_px-equivalent [m],
        frame, kink_correction, mass_kg, ...
    f_col_ratio_2f : float
        f_col_hz / (2 frequency_hz) [-] (the jar frequency given or estimated).
    f_col_suspect : bool
        f_col_ratio_2f outside :data:`F_COL_PLAUSIBLE_RATIO` (see :meth:`f_col_warning`).
    """

    v_mean_m_s: float
    v_mean_raw_m_s: float
    e_kin_j: float
    f_col_hz: float
    f_col_se_hz: float
    n_collisions: int
    collision_times_s: np.ndarray
    t_s: np.ndarray
    vx_m_s: np.ndarray
    vy_m_s: np.ndarray
    vx_raw_m_s: np.ndarray
    vy_raw_m_s: np.ndarray
    duration_s: float
    gap_fraction: float
    n_kinks: int
    count_duration_s: float
    params: dict = field(default_factory=dict)
    f_col_ratio_2f: float = float("nan")
    f_col_suspect: bool = False

    def f_col_warning(self) -> str | None:
        """One sentence when f_col is far from 2 f (``f_col_suspect``), else None."""
        if not self.f_col_suspect:
            return None
        f = self.params.get("frequency_hz", float("nan"))
        lo, hi = F_COL_PLAUSIBLE_RATIO
        return (f"measured f_col {self.f_col_hz:.4g} /s is {self.f_col_ratio_2f:.2f} x 2f "
                f"(f = {f:g} Hz, 2f = {2 * f:g} /s; plausible {lo:g}-{hi:g} x 2f): check the "
                "jar frequency, the frame rate and the track's lost frames")

    def to_frame(self) -> pd.DataFrame:
        """One-row summary: the figures, the f_col plausibility flag and the parameters used."""
        row = {"v_mean_m_s": self.v_mean_m_s, "v_mean_raw_m_s": self.v_mean_raw_m_s,
               "e_kin_j": self.e_kin_j, "f_col_hz": self.f_col_hz,
               "f_col_se_hz": self.f_col_se_hz, "n_collisions": self.n_collisions,
               "duration_s": self.duration_s, "gap_fraction": self.gap_fraction,
               "n_kinks": self.n_kinks, "f_col_ratio_2f": self.f_col_ratio_2f,
               "f_col_suspect": self.f_col_suspect}
        row.update({f"param_{k}": v for k, v in self.params.items()})
        return pd.DataFrame([row])

    def samples_frame(self) -> pd.DataFrame:
        """Velocity samples: t_s, vx_raw_m_s, vy_raw_m_s, vx_m_s, vy_m_s, speed_m_s."""
        return pd.DataFrame({"t_s": self.t_s, "vx_raw_m_s": self.vx_raw_m_s,
                             "vy_raw_m_s": self.vy_raw_m_s, "vx_m_s": self.vx_m_s,
                             "vy_m_s": self.vy_m_s,
                             "speed_m_s": np.hypot(self.vx_m_s, self.vy_m_s)})


# --------------------------------------------------------------------------------------------
# parameters from fps and f
# --------------------------------------------------------------------------------------------
def window_frames(fps: float, frequency_hz: float, polyorder: int = 2) -> int:
    """Savitzky-Golay window [frames]: largest odd <= fps / (2 f) / 4, at least polyorder + 3.

    Parameters
    ----------
    fps : float
        Camera frame rate [1/s].
    frequency_hz : float
        Jar frequency f [Hz]; the impacts come every fps / (2 f) frames.
    polyorder : int
        Savitzky-Golay polynomial order.
    """
    if not fps > 0:
        raise ObserveError(f"fps must be > 0, got {fps}")
    if not frequency_hz > 0:
        raise ObserveError(f"frequency_hz must be > 0, got {frequency_hz}")
    n_half = fps / (2.0 * frequency_hz)
    w = int(math.floor(n_half / 4.0))
    if w % 2 == 0:
        w -= 1
    return max(w, polyorder + 3 if (polyorder + 3) % 2 else polyorder + 4)


def estimate_frequency(t_s: np.ndarray, x_m: np.ndarray) -> float:
    """Dominant frequency of x(t) [Hz] (periodogram peak, mean removed); NaN rows ignored."""
    ok = np.isfinite(x_m)
    t, x = t_s[ok], x_m[ok]
    if len(t) < 16:
        raise ObserveError("too few valid samples to estimate the jar frequency")
    dt = np.median(np.diff(t))
    tu = np.arange(t[0], t[-1], dt)
    xu = np.interp(tu, t, x)
    xu = xu - xu.mean()
    n = 1 << int(math.ceil(math.log2(len(xu) * 8)))
    p = np.abs(np.fft.rfft(xu * np.hanning(len(xu)), n)) ** 2
    fr = np.fft.rfftfreq(n, dt)
    p[0] = 0
    return float(fr[np.argmax(p)])


def _noise_sigma(x: np.ndarray) -> float:
    """Position noise [same unit as x] from the MAD of third differences (sqrt(20) sigma)."""
    d3 = np.diff(x, 3)
    d3 = d3[np.isfinite(d3)]
    if len(d3) < 5:
        return 0.0
    return float(1.4826 * np.median(np.abs(d3 - np.median(d3))) / math.sqrt(20.0))


def _runs(valid: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) index pairs of consecutive True."""
    v = np.concatenate([[False], valid, [False]]).astype(np.int8)
    d = np.diff(v)
    return list(zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1)))


def _hysteresis_states(v: np.ndarray, db: float) -> np.ndarray:
    """Sign state (+1/-1, 0 before the first exit from the dead band) after each sample."""
    st = np.zeros(len(v), np.int8)
    s = 0
    for i, vi in enumerate(v):
        if vi > db:
            s = 1
        elif vi < -db:
            s = -1
        st[i] = s
    return st


def _smooth(v: np.ndarray, w: int, p: int) -> np.ndarray:
    n = len(v)
    if n == 0:
        return v.copy()
    ww = min(w, n if n % 2 else n - 1)
    if ww <= p:
        return np.full(n, np.mean(v)) if n else v.copy()
    return savgol_filter(v, ww, p, mode="interp")


# --------------------------------------------------------------------------------------------
# the operator
# --------------------------------------------------------------------------------------------
def observe_track(t_s, x_m, y_m, *, fps: float | None = None, frequency_hz: float | None = None,
                  quality=None, mass_kg: float | None = None, window: int | None = None,
                  polyorder: int = 2, deadband_m_s: float | None = None, n_sigma: float = 6.0,
                  deadband_floor_m_s: float = 0.02, kink_correction: bool = True,
                  max_gap_fraction: float = 0.2, frame: str = "lab", jar_x_m=None,
                  source: str = "track") -> ObservationResult:
    """Apply the observation operator to a camera-plane track.

    Parameters
    ----------
    t_s : array_like, shape (n,)
        Frame times [s], increasing, uniform (1 / fps) apart.
    x_m, y_m : array_like, shape (n,)
        Ball centre in the camera plane [m]; x along the jar axis. NaN marks a lost frame.
    fps : float, optional
        Camera rate [1/s]; default 1 / median frame spacing. Must agree with t_s (1 %).
    frequency_hz : float, optional
        Jar frequency [Hz] for the window rule; default from the spectrum of x.
    quality : array_like of str, shape (n,), optional
        'ok' / 'reacquired' / 'lost' per frame; 'lost' rows are gaps.
    mass_kg : float, optional
        Ball mass for E_kin (NaN E_kin without it).
    window : int, optional
        Savitzky-Golay window [frames] (odd); default :func:`window_frames`.
    polyorder : int
        Savitzky-Golay order.
    deadband_m_s : float, optional
        Hysteresis half-width on the smoothed vx; default max(n_sigma * noise of the smoothed
        velocity, deadband_floor_m_s), the noise estimated from the track itself.
    kink_correction : bool
        Handle sharp impacts (see module notes); False reproduces the plain recipe.
    max_gap_fraction : float
        Above this fraction of lost frames, :class:`TrackGapError`.
    frame : {'lab', 'jar'}
        'jar' subtracts ``jar_x_m`` from x (a camera riding on the jar).
    jar_x_m : array_like, shape (n,), optional
        Jar displacement [m], needed for frame='jar'.
    source : str
        Name used in error messages.

    Returns
    -------
    ObservationResult
    """
    t, x, y = _track_arrays(t_s, x_m, y_m, frame, jar_x_m, source)
    fps = _checked_fps(t, fps, source)
    valid, gap_fraction = _valid_frames(x, y, quality, max_gap_fraction, source)
    if frequency_hz is None:
        frequency_hz = estimate_frequency(t, np.where(valid, x, np.nan))
    frequency_hz = float(frequency_hz)
    if not frequency_hz > 0:
        raise ObserveError(f"{source}: frequency_hz must be > 0, got {frequency_hz}")
    n_half = fps / (2 * frequency_hz)
    if n_half < 8:
        raise ObserveError(f"{source}: {fps} frames/s gives only {n_half:.1f} frames between "
                           f"impacts at {frequency_hz} Hz; need >= 8")
    w = window_frames(fps, frequency_hz, polyorder) if window is None else int(window)
    if w % 2 == 0 or w <= polyorder:
        raise ObserveError(f"window must be odd and > polyorder, got {w}")
    bridge = int(math.floor(n_half / 4))  # longest gap [frames] bridged for counting

    # --- noise and dead band ----------------------------------------------------------------
    sig_x = np.nanmedian([_noise_sigma(x[a:b]) for a, b in _runs(valid) if b - a > 10] or [0.0])
    c = savgol_coeffs(w, polyorder)
    k = np.convolve(c, [1.0, -1.0])
    sig_vs = sig_x * fps * float(np.sqrt(np.sum(k ** 2)))
    db = max(n_sigma * sig_vs, deadband_floor_m_s) if deadband_m_s is None else float(deadband_m_s)
    if db < 0:
        raise ObserveError(f"deadband_m_s must be >= 0, got {db}")

    sw = _Sweep(t, x, y, valid, fps, w, polyorder, db, bridge,
                sig_vraw=sig_x * fps * math.sqrt(2.0), kink_correction=kink_correction)
    if not sw.runs or sw.duration <= 0:
        raise TrackGapError(f"{source}: no stretch of consecutive frames long enough to measure")
    n_valid_fd = int(np.sum(np.isfinite(sw.vxr)))
    v_mean = sw.integral / sw.duration
    # raw mean over the same time base as the smoothed one
    v_mean_raw = sw.integral_raw / (n_valid_fd / fps)
    ct = np.array(sorted(sw.coll_times))
    f_col, f_col_se = collision_rate(sw.coll_times, sw.duration + sw.count_extra,
                                     sw.coll_segments)
    e_kin = 0.5 * mass_kg * v_mean ** 2 if mass_kg is not None else float("nan")
    params = {"fps": fps, "frequency_hz": frequency_hz, "window_frames": w,
              "polyorder": polyorder, "deadband_m_s": db, "noise_sigma_m": sig_x,
              "frame": frame, "kink_correction": bool(kink_correction),
              "mass_kg": float("nan") if mass_kg is None else float(mass_kg),
              "bridge_frames": bridge, "max_gap_fraction": max_gap_fraction}
    ratio = f_col / (2.0 * frequency_hz)
    return ObservationResult(float(v_mean), float(v_mean_raw), float(e_kin), float(f_col),
                             float(f_col_se), len(ct), ct, sw.tm, sw.vxs, sw.vys, sw.vxr,
                             sw.vyr, float(sw.duration), float(gap_fraction), sw.n_kinks,
                             float(sw.duration + sw.count_extra), params,
                             f_col_ratio_2f=float(ratio),
                             f_col_suspect=bool(not (F_COL_PLAUSIBLE_RATIO[0] <= ratio
                                                     <= F_COL_PLAUSIBLE_RATIO[1])))


def _track_arrays(t_s, x_m, y_m, frame, jar_x_m, source):
    """(t, x, y) as float arrays of one length, x in the asked frame; at least 8 rows."""
    t = np.asarray(t_s, float)
    x = np.asarray(x_m, float).copy()
    y = np.asarray(y_m, float).copy()
    n = len(t)
    if not (len(x) == n and len(y) == n):
        raise ObserveError(f"{source}: t_s, x_m, y_m differ in length ({n}, {len(x)}, {len(y)})")
    if frame not in ("lab", "jar"):
        raise ObserveError(f"{source}: frame must be 'lab' or 'jar', got {frame!r}")
    if frame == "jar":
        if jar_x_m is None:
            raise ObserveError(f"{source}: frame='jar' needs jar_x_m (column jar_x_m)")
        x = x - np.asarray(jar_x_m, float)
    if n < 8:
        raise ObserveError(f"{source}: track has {n} rows; need at least 8 frames")
    return t, x, y


def _checked_fps(t, fps, source) -> float:
    """The camera rate: ``fps`` (default 1 / the median frame spacing), checked against finite,
    increasing, uniformly spaced times."""
    if not np.all(np.isfinite(t)):
        bad = int(np.flatnonzero(~np.isfinite(t))[0])
        raise ObserveError(f"{source}: row {bad}, column t_s: not a finite time")
    dt = np.diff(t)
    if np.any(dt <= 0):
        bad = int(np.flatnonzero(dt <= 0)[0]) + 1
        raise ObserveError(f"{source}: row {bad}, column t_s: times must increase")
    fps_t = 1.0 / float(np.median(dt))
    if fps is None:
        fps = fps_t
    fps = float(fps)
    if not (fps > 0 and math.isfinite(fps)):
        raise ObserveError(f"{source}: fps must be > 0, got {fps}")
    if abs(fps_t / fps - 1) > 0.01:
        raise ObserveError(f"{source}: fps {fps} disagrees with the frame spacing of t_s "
                           f"({fps_t:.6g} frames/s)")
    if np.max(np.abs(dt * fps - 1)) > 0.05:
        bad = int(np.argmax(np.abs(dt * fps - 1))) + 1
        raise ObserveError(f"{source}: row {bad}, column t_s: frames not uniformly spaced "
                           f"(missing frames must be rows with NaN position, not skipped rows)")
    return fps


def _valid_frames(x, y, quality, max_gap_fraction, source):
    """(the frames with a position and not marked lost, the fraction lost), within the
    limit."""
    valid = np.isfinite(x) & np.isfinite(y)
    if quality is not None:
        q = np.asarray(quality).astype(str)
        unknown = ~np.isin(q, ["ok", "reacquired", "lost", "nan"])
        if np.any(unknown):
            bad = int(np.flatnonzero(unknown)[0])
            raise ObserveError(f"{source}: row {bad}, column quality: {q[bad]!r} is not "
                               f"ok / reacquired / lost")
        valid &= q != "lost"
    gap_fraction = 1.0 - valid.mean()
    if gap_fraction > max_gap_fraction:
        raise TrackGapError(f"{source}: {100 * gap_fraction:.1f} % of the frames are lost "
                            f"(limit {100 * max_gap_fraction:.0f} %); the track cannot give "
                            f"v_mean or f_col")
    return valid, gap_fraction


class _Sweep:
    """One pass over a track's runs of consecutive frames: velocities (finite differences,
    smoothed per run and per segment between kinks), the collisions (flips of the hysteresis
    state, bridged over short gaps), the speed's integral and the time measured."""

    def __init__(self, t, x, y, valid, fps, w, polyorder, db, bridge, *, sig_vraw,
                 kink_correction):
        self.fps, self.w, self.polyorder, self.db = fps, w, polyorder, db
        self.sig_vraw, self.kink_correction = sig_vraw, kink_correction
        m = len(t) - 1
        self.tm = 0.5 * (t[1:] + t[:-1])
        self.vxr = np.diff(x) * fps
        self.vyr = np.diff(y) * fps
        vpair = valid[1:] & valid[:-1]
        self.vxr[~vpair] = np.nan
        self.vyr[~vpair] = np.nan
        self.vxs = np.full(m, np.nan)
        self.vys = np.full(m, np.nan)
        self.runs = [(a, b) for a, b in _runs(vpair) if b - a >= 3]
        self.coll_times: list[float] = []
        self.coll_segments: list[int] = []  # the bridged stretch each collision lies in
        self.segment = -1
        self.n_kinks = 0
        self.duration = 0.0
        self.integral = 0.0
        self.integral_raw = 0.0
        self.count_extra = 0.0  # bridged gap time: counted for f_col, not for v_mean
        prev = (0, None, None)  # (state, end time, end index) of the last run
        for a, b in self.runs:
            prev = self._run(a, b, prev, bridge)

    def _run(self, a, b, prev, bridge):
        prev_state, prev_end_t, prev_end_idx = prev
        tm, fps = self.tm, self.fps
        vx_run = _smooth(self.vxr[a:b], self.w, self.polyorder)
        st = _hysteresis_states(vx_run, self.db)
        # collisions inside this run: state flips
        flips = np.flatnonzero((st[1:] != st[:-1]) & (st[:-1] != 0)) + 1
        # bridging from the previous run
        gap_frames = None if prev_end_idx is None else a - prev_end_idx
        first_state = st[np.flatnonzero(st != 0)[0]] if np.any(st != 0) else 0
        if gap_frames is not None and gap_frames <= bridge:
            self.count_extra += tm[a] - prev_end_t - 1.0 / fps
            if prev_state != 0 and first_state != 0 and first_state != prev_state:
                self.coll_times.append(0.5 * (prev_end_t + tm[a]))
                self.coll_segments.append(self.segment)
        else:
            self.segment += 1
        zc_idx = [self._collision(a, vx_run, st, fi) for fi in flips]
        drop = (self._kinks(self.vxr[a:b], zc_idx) if self.kink_correction
                else np.zeros(b - a, bool))
        self._integrate(a, b, drop)
        last_state = st[np.flatnonzero(st != 0)[-1]] if np.any(st != 0) else prev_state
        return last_state, tm[b - 1], b

    def _collision(self, a, vx_run, st, fi) -> int:
        """The collision at flip ``fi`` of a run from ``a``: its time (the smoothed vx's zero
        crossing) recorded; the crossing's FD index (left sample) in the run returned."""
        tm = self.tm
        # last sample before fi whose smoothed vx has the old sign
        old = st[fi - 1]
        j = fi - 1
        while j > 0 and np.sign(vx_run[j]) != old:
            j -= 1
        jj = j + 1
        while jj < fi and np.sign(vx_run[jj]) == old:
            jj += 1
        j = jj - 1
        v0, v1 = vx_run[j], vx_run[j + 1]
        frac = v0 / (v0 - v1) if v0 != v1 else 0.5
        self.coll_times.append(tm[a + j] + frac * (tm[a + j + 1] - tm[a + j]))
        self.coll_segments.append(self.segment)
        return j

    def _kinks(self, raw, zc_idx) -> np.ndarray:
        """The run's samples to drop around sharp impacts (a kink test at each zero
        crossing)."""
        n = len(raw)
        drop = np.zeros(n, bool)
        for j in zc_idx:
            L = np.arange(max(j - 6, 0), j - 1)
            R = np.arange(j + 3, min(j + 9, n))
            if len(L) < 3 or len(R) < 3:
                continue
            idx = np.concatenate([L, np.arange(j - 1, j + 3), R])
            idx = idx[(idx >= 0) & (idx < n)]
            A1 = np.vstack([idx, np.ones(len(idx))]).T
            res = raw[idx] - A1 @ np.linalg.lstsq(A1, raw[idx], rcond=None)[0]
            rms_line = float(np.sqrt(np.mean(res ** 2)))
            mL, mR = abs(np.mean(raw[L])), abs(np.mean(raw[R]))
            jump = abs(np.mean(raw[R]) - np.mean(raw[L]))
            # a kink: the velocity jumps (not linear through the turn) AND the ball is fast
            # on both sides (a reversal). A jump to a near-stop (jar frame, small e: the
            # relative speed drops to e*u, then turns smoothly) is left to the smoother:
            # its |v| minimum is not at the impact, and interpolating over it overshoots.
            if rms_line > max(4.0 * self.sig_vraw, 0.1 * jump) and \
                    min(mL, mR) >= 0.3 * max(mL, mR):
                # locate the straddling difference: the sample nearest the sign change of raw
                win = np.arange(max(j - 2, 0), min(j + 4, n))
                kc = win[np.argmin(np.abs(raw[win]))]
                drop[max(kc - 1, 0):min(kc + 2, n)] = True
                self.n_kinks += 1
        return drop

    def _integrate(self, a, b, drop):
        """Segment-wise smoothing between the dropped samples; the speed's integral over the
        kept ones and the run's time."""
        fps, tm, w, p = self.fps, self.tm, self.w, self.polyorder
        vx_seg = np.full(b - a, np.nan)
        vy_seg = np.full(b - a, np.nan)
        for sa, sb in _runs(~drop):
            vx_seg[sa:sb] = _smooth(self.vxr[a + sa:a + sb], w, p)
            vy_seg[sa:sb] = _smooth(self.vyr[a + sa:a + sb], w, p)
        self.vxs[a:b] = vx_seg
        self.vys[a:b] = vy_seg
        keep = ~drop
        sp = np.hypot(vx_seg[keep], vy_seg[keep])
        tk = tm[a:b][keep]
        # trapezoid over kept samples, plus half a frame at each end of the run
        self.integral += np.trapezoid(sp, tk) + 0.5 / fps * (sp[0] + sp[-1])
        self.integral_raw += np.sum(np.hypot(self.vxr[a:b], self.vyr[a:b])) / fps
        self.duration += (tm[b - 1] - tm[a]) + 1.0 / fps


# --------------------------------------------------------------------------------------------
# inputs: track files and twin recordings
# --------------------------------------------------------------------------------------------
def read_track(path) -> pd.DataFrame:
    """Read a track CSV (t_s, x_m, y_m, optional quality / jar_x_m); clear errors on bad input.

    A lost frame (a gap) is a row with its t_s and empty (or NaN) x_m and y_m, as in a dataset's
    tracks/ (docs/dataset_format.md); numbers implausible in seconds and metres (a track in mm,
    t_s in ms) are refused (:func:`analysis.measurements.check_track_units`)."""
    path = Path(path)
    if not path.is_file():
        raise ObserveError(f"{path}: no such track file")
    from analysis.measurements import DatasetError, check_track_units
    try:
        # utf-8-sig: a byte-order mark (a spreadsheet's "CSV UTF-8") is not part of the header
        df = pd.read_csv(path, encoding="utf-8-sig", skipinitialspace=True)
    except Exception as exc:  # pandas raises many kinds
        raise ObserveError(f"{path}: not a readable CSV ({exc})") from None
    df.columns = [str(c).strip() for c in df.columns]
    missing = [c for c in TRACK_COLUMNS if c not in df.columns]
    if missing:
        raise ObserveError(f"{path}: missing column(s) {', '.join(missing)}")
    cols = list(TRACK_COLUMNS) + (["jar_x_m"] if "jar_x_m" in df.columns else [])
    for c in cols:
        if not pd.api.types.is_numeric_dtype(df[c]):
            bad = pd.to_numeric(df[c], errors="coerce").isna() & df[c].notna()
            row = int(np.flatnonzero(bad.to_numpy())[0]) if bad.any() else 0
            raise ObserveError(f"{path}: row {row}, column {c}: not a number")
    try:      # the dataset check's plausibility bounds: a track in mm or ms is refused
        check_track_units(df["t_s"], df["x_m"], df["y_m"],
                          df["jar_x_m"] if "jar_x_m" in df.columns else None, str(path))
    except DatasetError as exc:
        raise ObserveError(str(exc)) from None
    return df


def observe_track_file(path, **kwargs) -> ObservationResult:
    """:func:`observe_track` on a track CSV; a ``quality`` / ``jar_x_m`` column is used if present."""
    df = read_track(path)
    q = df["quality"].to_numpy() if "quality" in df.columns else None
    jx = df["jar_x_m"].to_numpy() if "jar_x_m" in df.columns else None
    kwargs.setdefault("source", str(path))
    return observe_track(df["t_s"].to_numpy(), df["x_m"].to_numpy(), df["y_m"].to_numpy(),
                         quality=q, jar_x_m=jx, **kwargs)


@dataclass
class RecordingData:
    """A twin recording read from its folder (meta dict, trajectory and impacts tables)."""

    path: Path | None
    meta: dict
    trajectory: pd.DataFrame
    impacts: pd.DataFrame


def load_recording(recording) -> RecordingData:
    """Read a recording folder (meta.json, trajectory.csv, impacts.csv) or pass an object with
    ``.meta``, ``.trajectory``, ``.impacts`` through (e.g. analysis.twin's Recording)."""
    if all(hasattr(recording, a) for a in ("meta", "trajectory", "impacts")):
        return RecordingData(getattr(recording, "path", None), recording.meta,
                             recording.trajectory, recording.impacts)
    d = Path(recording)
    if not d.is_dir():
        raise ObserveError(f"{d}: not a recording folder")
    for name in ("meta.json", "trajectory.csv", "impacts.csv"):
        if not (d / name).is_file():
            raise ObserveError(f"{d}: missing {name}")
    try:
        meta = json.loads((d / "meta.json").read_text())
    except json.JSONDecodeError as exc:
        raise ObserveError(f"{d / 'meta.json'}: not valid JSON ({exc})") from None
    try:
        traj = pd.read_csv(d / "trajectory.csv")
        imp = pd.read_csv(d / "impacts.csv")
    except Exception as exc:
        raise ObserveError(f"{d}: unreadable CSV ({exc})") from None
    _check_columns(traj, TRAJECTORY_COLUMNS, d / "trajectory.csv")
    _check_columns(imp, IMPACT_COLUMNS, d / "impacts.csv")
    return RecordingData(d, meta, traj, imp)


def _check_columns(df: pd.DataFrame, cols, path) -> None:
    missing = [c for c in cols if c not in df.columns]
    if missing:
        raise ObserveError(f"{path}: missing column(s) {', '.join(missing)}")
    for c in cols:
        if c == "where":
            continue
        v = pd.to_numeric(df[c], errors="coerce").to_numpy()
        bad = ~np.isfinite(v)
        if bad.any():
            raise ObserveError(f"{path}: row {int(np.flatnonzero(bad)[0])}, column {c}: "
                               f"NaN or not a number")


def camera_track(recording, fps: float | None = None, frame: str = "lab") -> pd.DataFrame:
    """A recording's trajectory as the camera sees it: t_s, x_m (= x), y_m (= z), jar_x_m.

    Sampled at ``fps`` (default the camera's 2134/s): every k-th row when the recording's rate is
    an integer multiple, else linear interpolation of positions. ``frame='jar'`` subtracts
    jar_x_m from x.
    """
    rec = load_recording(recording)
    tr = rec.trajectory
    fps = CAMERA_FPS if fps is None else float(fps)
    if not fps > 0:
        raise ObserveError(f"fps must be > 0, got {fps}")
    t = tr["t_s"].to_numpy(float)
    if len(t) < 8:
        raise ObserveError(f"{rec.path}: trajectory.csv has {len(t)} rows; need at least 8")
    rate = 1.0 / float(np.median(np.diff(t)))
    ratio = rate / fps
    if ratio < 0.99:
        raise ObserveError(f"{rec.path}: trajectory rate {rate:.6g}/s is below the camera's "
                           f"{fps:.6g}/s; rerun the twin with output_fps >= fps")
    if abs(ratio - round(ratio)) < 1e-6:
        sel = slice(None, None, int(round(ratio)))
        ts = t[sel]
        cols = {c: tr[c].to_numpy(float)[sel] for c in ("x_m", "z_m", "jar_x_m")}
    else:
        ts = t[0] + np.arange(int(math.floor((t[-1] - t[0]) * fps + 1e-9)) + 1) / fps
        cols = {c: np.interp(ts, t, tr[c].to_numpy(float)) for c in ("x_m", "z_m", "jar_x_m")}
    x = cols["x_m"] - (cols["jar_x_m"] if frame == "jar" else 0.0)
    if frame not in ("lab", "jar"):
        raise ObserveError(f"frame must be 'lab' or 'jar', got {frame!r}")
    return pd.DataFrame({"t_s": ts, "x_m": x, "y_m": cols["z_m"], "jar_x_m": cols["jar_x_m"]})


def _ball_mass(meta: dict) -> float | None:
    if "ball_mass_kg" in meta:
        return float(meta["ball_mass_kg"])
    cfg = meta.get("config", {})
    if "ball_diameter_m" in cfg:
        rho = float(cfg.get("ball_density_kg_m3", STEEL_DENSITY_KG_M3))
        return rho * math.pi / 6 * float(cfg["ball_diameter_m"]) ** 3
    return None


def observe_recording(recording, fps: float | None = None, frame: str = "lab",
                      **kwargs) -> ObservationResult:
    """The observation operator on a twin recording (the 'video side' of the twin).

    The trajectory is sampled at the camera rate and projected on the camera plane (x, z); in the
    jar frame jar_x_m is subtracted. f and the ball mass come from meta.json unless given.
    """
    rec = load_recording(recording)
    tr = camera_track(rec, fps, frame="lab")
    cfg = rec.meta.get("config", {})
    kwargs.setdefault("frequency_hz", cfg.get("frequency_hz"))
    kwargs.setdefault("mass_kg", _ball_mass(rec.meta))
    kwargs.setdefault("source", str(rec.path or "recording"))
    return observe_track(tr["t_s"], tr["x_m"], tr["y_m"], fps=fps or CAMERA_FPS, frame=frame,
                         jar_x_m=tr["jar_x_m"], **kwargs)


def direct_figures(recording, frame: str = "lab") -> dict:
    """The twin's own figures, no camera: true 3-D mean speed, camera-plane (x, z) mean speed,
    and f_col = the rate of the end-cap collisions in impacts.csv by the scene's own rule
    (``collision_rate`` of each collision's first contact: (n - 1) / (t_n - t_1), not n / the
    record length, which moves in steps of 1 / record length).

    Returns
    -------
    dict with v_mean_3d_m_s, v_mean_2d_m_s, e_kin_j (3-D), f_col_hz, n_end_cap, duration_s.
    """
    rec = load_recording(recording)
    tr = rec.trajectory
    if frame not in ("lab", "jar"):
        raise ObserveError(f"frame must be 'lab' or 'jar', got {frame!r}")
    t = tr["t_s"].to_numpy(float)
    vx = tr["vx_m_s"].to_numpy(float) - (tr["jar_vx_m_s"].to_numpy(float) if frame == "jar"
                                         else 0.0)
    vy = tr["vy_m_s"].to_numpy(float)
    vz = tr["vz_m_s"].to_numpy(float)
    s3 = np.sqrt(vx ** 2 + vy ** 2 + vz ** 2)
    s2 = np.hypot(vx, vz)
    dur = float(t[-1] - t[0])
    v3 = float(np.trapezoid(s3, t) / dur)
    v2 = float(np.trapezoid(s2, t) / dur)
    imp = rec.impacts
    ts = pd.to_numeric(imp["t_start_s"]).to_numpy(float)
    end = (imp["where"].astype(str).to_numpy() == "end_cap") & (ts >= t[0]) & (ts <= t[-1])
    # collisions: re-contacts with the same end belong to one collision (collision_id, written by
    # the scene); recordings without the column count every end-cap contact
    if "collision_id" in imp.columns:
        first = pd.Series(ts[end]).groupby(imp["collision_id"].to_numpy()[end]).min()
    else:
        first = pd.Series(ts[end])
    n_col = int(len(first))
    m = _ball_mass(rec.meta)
    return {"v_mean_3d_m_s": v3, "v_mean_2d_m_s": v2,
            "e_kin_j": 0.5 * m * v3 ** 2 if m is not None else float("nan"),
            "f_col_hz": float(collision_rate(first.to_numpy(float), dur)[0]),
            "n_collisions": n_col, "n_end_cap": int(end.sum()), "duration_s": dur}


def operator_bias(recording, frame: str = "lab", fps: float | None = None,
                  **kwargs) -> pd.DataFrame:
    """Operator minus direct figures for one recording.

    Rows: v_mean (operator vs true 3-D speed, and vs the camera-plane 2-D speed, which splits the
    projection bias from the operator's own), e_kin, f_col. Columns: quantity, operator, direct,
    difference, relative, frame, flag (on the f_col_hz row, the operator's
    :meth:`ObservationResult.f_col_warning` when its f_col is far from 2 f; else empty).
    """
    obs = observe_recording(recording, fps=fps, frame=frame, **kwargs)
    d = direct_figures(recording, frame=frame)
    rows = [("v_mean_m_s vs 3d", obs.v_mean_m_s, d["v_mean_3d_m_s"]),
            ("v_mean_m_s vs 2d", obs.v_mean_m_s, d["v_mean_2d_m_s"]),
            ("e_kin_j", obs.e_kin_j, d["e_kin_j"]),
            ("f_col_hz", obs.f_col_hz, d["f_col_hz"])]
    out = pd.DataFrame(rows, columns=["quantity", "operator", "direct"])
    out["difference"] = out["operator"] - out["direct"]
    out["relative"] = out["difference"] / out["direct"]
    out["frame"] = frame
    out["flag"] = ["" if q != "f_col_hz" else (obs.f_col_warning() or "")
                   for q in out["quantity"]]
    return out


# --------------------------------------------------------------------------------------------
# CLI
# --------------------------------------------------------------------------------------------
#: the first columns of the tables ``--out`` writes (the one-row summary, the operator-bias
#: table): an existing file is replaced only when its header starts so
SUMMARY_HEAD = ("v_mean_m_s", "v_mean_raw_m_s", "e_kin_j", "f_col_hz")
BIAS_HEAD = ("quantity", "operator", "direct", "difference", "relative", "frame", "flag")


def _check_out(out, inputs):
    """``--out``'s path, after the project's output rule (``analysis.atomic_dir``): never an
    input, never an existing file this command did not write (an OutputError otherwise)."""
    from analysis.atomic_dir import check_out_file, own_csv
    summary, bias = own_csv(SUMMARY_HEAD, prefix=True), own_csv(BIAS_HEAD)
    return check_out_file(out, [p for p in inputs if p],
                          is_own=lambda q: summary(q) or bias(q), flag="--out")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m analysis.observe",
        description="Observation operator: track CSV or twin recording -> v_mean, E_kin, f_col. "
                    "A measured f_col outside %g-%g x 2f is flagged (column f_col_suspect, or "
                    "flag) with a warning on stderr." % F_COL_PLAUSIBLE_RATIO,
        epilog="example: python -m analysis.observe track.csv --fps 2134 --frequency-hz 25 "
               "--mass-kg 0.0357 --out summary.csv")
    p.add_argument("track", nargs="?", help="track CSV (t_s, x_m, y_m[, quality, jar_x_m])")
    p.add_argument("--recording", help="twin run folder: operator, direct figures and bias")
    p.add_argument("--fps", type=float, default=None,
                   help="camera frame rate [1/s] (default: from the track's t_s)")
    p.add_argument("--frequency-hz", type=float, default=None,
                   help="jar frequency [Hz] (default: from the spectrum of x, or the recording)")
    p.add_argument("--mass-kg", type=float, default=None, help="ball mass [kg] for E_kin")
    p.add_argument("--frame", choices=("lab", "jar"), default="lab")
    p.add_argument("--plain", action="store_true", help="no kink correction (paper's recipe)")
    p.add_argument("--noise-study", action="store_true",
                   help="moved: python -m analysis.synthvideo --noise-study (the synthetic films "
                   "belong to synthvideo, which reads this module)")
    p.add_argument("--out", help="CSV for the one-row summary (or the operator-bias table); "
                   "an existing file is replaced only when this command wrote it, never the "
                   "input")
    a = p.parse_args(argv)
    try:
        if a.noise_study:
            p.error("the noise/blur study moved: python -m analysis.synthvideo --noise-study "
                    "[--out CSV]")
        out = _check_out(a.out, [a.track, a.recording]) if a.out else None
        kw = dict(fps=a.fps, frame=a.frame, kink_correction=not a.plain)
        if a.frequency_hz is not None:
            kw["frequency_hz"] = a.frequency_hz
        if a.mass_kg is not None:
            kw["mass_kg"] = a.mass_kg
        if a.recording:
            table = operator_bias(a.recording, **kw)
            print(table.to_string(index=False))
            out_df = table
            warning = next((f for f in table["flag"] if f), None)
        elif a.track:
            res = observe_track_file(a.track, **kw)
            out_df = res.to_frame()
            print(out_df.T.to_string(header=False))
            warning = res.f_col_warning()
        else:
            p.error("give a track CSV or --recording DIR")
            return 2
        if out is not None:
            from analysis.atomic_dir import atomic_file
            _check_out(a.out, [a.track, a.recording])      # again: it may have appeared since
            with atomic_file(out) as tmp:
                out_df.to_csv(tmp, index=False)
    except (ObserveError, ValueError, OSError) as exc:
        print(f"analysis.observe: error: {exc}", file=sys.stderr)
        return 2
    if warning:
        print(f"analysis.observe: warning: {warning}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
