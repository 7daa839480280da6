"""Impact observables of a track that also follows the jar: what each end impact did.

The observation operator (:mod:`analysis.observe`) reduces a track to v_mean and f_col. Two
numbers per condition leave most physical effects indistinguishable once the restitution and the
stroke are recalibrated (restitution and amplitude absorb 58-95 % of each effect's footprint on
them). A camera that sees the ball also sees the jar; with the jar's position in the track
(column ``jar_x_m``, the same column a jar-frame track needs) each end impact can be read:

1. ``r = x - jar_x`` is the ball in the jar frame; an end visit is a run of frames with r within
   ``end_band`` of the travel's 2nd / 98th percentile; the impact frame is the visit's extreme.
2. Just before and just after the impact (skipping ``skip`` frames each side, which also covers
   the sub-millisecond contact), the ball's lab velocity is a straight-line fit over ``n_fit``
   frames and the jar's a local fit of c + a cos(2 pi f t) + b sin(2 pi f t) (the jar
   accelerates at up to 4 pi^2 f^2 A ~ 430 m/s^2; a quadratic would miss its jerk), both
   evaluated at the impact time, where the two sides' fits of the jar-frame position meet.
   The normal approach and rebound speeds relative to the
   wall are ``v_in = s (u_before - V_before)`` and ``v_out = -s (u_after - V_after)``
   (s = +1 at the +x end, -1 at the -x end), their ratio the impact's apparent restitution.
3. The jar's fundamental (least squares on cos, sin at f, with a constant) gives the jar
   amplitude and the phase of every impact on the jar cycle (impacts at the -x end are shifted
   by pi so that both ends fold on one phase).

Observables per track (all SI):

* ``e_app``: median apparent restitution of the end impacts with v_in above ``v_in_min_m_s``
  and 30 % of the median (re-contacts of a ball that stuck are not impacts of the flight);
* ``v_in_m_s``: their median approach speed relative to the wall [m/s];
* ``impact_phase_rad``: circular mean of the jar phase at impact [rad], 0 = jar at its centre
  moving towards +x;
* ``jar_amplitude_m``: amplitude of the jar's fundamental [m];
* ``vy_rms_m_s``: rms vertical (camera y) velocity of the ball (Savitzky-Golay derivative, the
  tracking noise's share removed) [m/s].

Each comes with a standard error over the impacts (frames for vy_rms: over 8 blocks of the
record). Physics this reads: velocity-dependent restitution and a powder layer change e_app and
its trend with v_in; jar compliance changes the jar's amplitude and the impact phase; the swing
arm's vertical motion and tilt feed vertical velocity; restitution and stroke are pinned by e_app
and jar_amplitude_m directly instead of through v_mean alone.

Gaps (frames where the ball or the jar was not found: NaN in x_m, y_m or jar_x_m, the empty
cells of a dataset track, docs/dataset_format.md) are allowed up to the dataset's limit
(:data:`MAX_GAP_FRACTION`): the jar is fitted on its found frames, an impact whose fit windows
touch a gap is left out, the vertical velocity is taken over the gap-free runs.
"""
from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy.signal import savgol_coeffs, savgol_filter

#: names of the impact observables, in the order :func:`flight_observables` returns them
FLIGHT_OBSERVABLES = ("e_app", "v_in_m_s", "impact_phase_rad", "jar_amplitude_m", "vy_rms_m_s")
#: the per-impact table's columns (``--impacts``)
IMPACT_TABLE_COLUMNS = ("t_s", "end", "v_in_m_s", "v_out_m_s", "e", "phase_rad")
#: most frames that may be gaps: the dataset contract's limit (analysis.measurements)
from analysis.measurements import TRACK_MAX_GAP_FRACTION as MAX_GAP_FRACTION  # noqa: E402


class FlightError(ValueError):
    """A track from which impact observables cannot be read (named reason)."""


@dataclass
class FlightResult:
    """Impact observables of one track.

    values, se : dict name -> float (names in FLIGHT_OBSERVABLES)
    impacts : DataFrame, one row per end impact (t_s, end, v_in_m_s, v_out_m_s, e, phase_rad)
    """
    values: dict
    se: dict
    impacts: pd.DataFrame

    def to_frame(self) -> pd.DataFrame:
        return pd.DataFrame({"observable": list(self.values), "value": list(self.values.values()),
                             "se": [self.se[k] for k in self.values]})


def _visits(r, lo, hi):
    """(index of the extreme, end +1/-1) of each run of frames with r >= hi or r <= lo."""
    out = []
    for end, mask in ((1, r >= hi), (-1, r <= lo)):
        idx = np.flatnonzero(mask)
        if not len(idx):
            continue
        breaks = np.flatnonzero(np.diff(idx) > 1)
        starts = np.r_[idx[0], idx[breaks + 1]]
        stops = np.r_[idx[breaks], idx[-1]]
        for a, b in zip(starts, stops):
            seg = r[a:b + 1]
            k = a + int(np.argmax(seg) if end > 0 else np.argmin(seg))
            out.append((k, end, a, b))
    out.sort()
    return out


def _noise_sd(y):
    """White tracking noise sd from third differences (a smooth motion's third differences are
    ~0; white noise's have variance 20 sigma^2), robustly (MAD) so impacts do not count."""
    d3 = np.diff(y, 3)
    d3 = d3[np.isfinite(d3)]              # gaps (NaN frames) left out
    if not len(d3):
        return 0.0
    return 1.4826 * float(np.median(np.abs(d3 - np.median(d3)))) / math.sqrt(20.0)


#: resamples and seed of the end-stratified bootstrap (deterministic: one track, one se)
BOOTSTRAP_DRAWS = 400
BOOTSTRAP_SEED = 0


def _end_bootstrap_se(ends, e, vin, z, zm):
    """Bootstrap sds of median(e), median(v_in) and the circular mean phase, each end's
    impacts resampled within that end."""
    rng = np.random.default_rng(BOOTSTRAP_SEED)
    idx = np.concatenate([np.flatnonzero(ends == s)[rng.integers(
        0, int(np.sum(ends == s)), (BOOTSTRAP_DRAWS, int(np.sum(ends == s))))]
        for s in (-1, 1)], axis=1)
    ph = np.angle(z[idx].mean(axis=1) * np.conj(zm))
    return (float(np.median(e[idx], axis=1).std(ddof=1)),
            float(np.median(vin[idx], axis=1).std(ddof=1)), float(ph.std(ddof=1)))


def _median_se(a):
    """Standard error of a median: 1.2533 x a robust sd (1.4826 MAD) / sqrt(n)."""
    a = np.asarray(a, float)
    mad = 1.4826 * float(np.median(np.abs(a - np.median(a))))
    return 1.2533 * mad / math.sqrt(len(a))


def _fit_at(t, y, sl, t0, deg):
    """Value of the derivative at t0 of a degree-``deg`` polynomial fitted to y[sl]."""
    tt = t[sl] - t0
    c = np.polyfit(tt, y[sl], deg)
    return float(np.polyval(np.polyder(c), 0.0))


def _jar_velocity_at(t, jx, sl, t0, w):
    """Jar velocity at t0 from a local fit of c + a cos(w t) + b sin(w t) to jx[sl]: exact for
    the harmonic drive (a quadratic's extrapolation misses the jerk A w^3: 0.15 m/s at 25 Hz)."""
    tt = t[sl] - t0
    B = np.column_stack([np.ones_like(tt), np.cos(w * tt), np.sin(w * tt)])
    c = np.linalg.lstsq(B, jx[sl], rcond=None)[0]
    return float(w * c[2])


def _contact_time(t, x, jx, bs, as_, k, skip):
    """Impact time: where the one-sided fits of the ball's jar-frame position meet (the ball
    is at the wall on both sides of the contact); the impact frame's time if they do not meet
    within the skipped frames."""
    cb = np.polyfit(t[bs] - t[k], x[bs] - jx[bs], 2)
    ca = np.polyfit(t[as_] - t[k], x[as_] - jx[as_], 2)
    lo, hi = t[max(0, k - skip - 1)] - t[k], t[min(len(t) - 1, k + skip + 1)] - t[k]
    roots = [float(z.real) for z in np.roots(cb - ca) if abs(z.imag) < 1e-12
             and lo <= z.real <= hi]
    if not roots:
        return float(t[k])
    return float(t[k] + min(roots, key=abs))


def flight_observables(t_s, x_m, y_m, jar_x_m, frequency_hz, *, skip=2, n_fit=6,
                       end_band=0.15, v_in_min_m_s=0.2, source="track") -> FlightResult:
    """Impact observables of a lab-frame track with the jar's position (see module notes).

    Parameters
    ----------
    t_s : array_like, shape (n,) - frame times [s], uniform
    x_m, y_m : array_like, shape (n,) - ball centre in the camera plane [m], x along the jar axis
    jar_x_m : array_like, shape (n,) - jar displacement along x [m] (same frames)
    frequency_hz : float - jar frequency [Hz]
    skip : int - frames skipped on each side of an impact frame
    n_fit : int - frames in each one-sided fit
    end_band : float - end visits: within this fraction of the travel of its 2 / 98 % quantile
    v_in_min_m_s : float - impacts slower than this are left out of e_app (grazing contacts)

    Returns
    -------
    FlightResult
    """
    t, x, y, jx = _checked_flight_track(t_s, x_m, y_m, jar_x_m, frequency_hz, skip, n_fit,
                                        source)
    w = 2 * math.pi * float(frequency_hz)
    jar = _JarFundamental.fit(t, jx, w, source)
    imp = _impact_table(t, x, y, jx, w, jar.phi0, skip, n_fit, end_band, source)
    fast = imp["v_in_m_s"] > max(v_in_min_m_s, 0.3 * float(np.nanmedian(imp["v_in_m_s"]))
                                 if len(imp) else v_in_min_m_s)
    good = imp[fast & np.isfinite(imp["e"])]
    if len(good) < 3:
        raise FlightError(f"{source}: {len(good)} end impacts faster than {v_in_min_m_s} m/s "
                          "found; need >= 3 (is the ball in end-to-end flight?)")
    ng = len(good)
    e = good["e"].to_numpy(float)
    vin = good["v_in_m_s"].to_numpy(float)
    z = np.exp(1j * good["phase_rad"].to_numpy(float))
    zm = z.mean()
    phase = float(np.angle(zm))
    # circular se: sqrt((1 - R2)/(2 n R^2)) with R2 the mean of cos(2 (phi - mean))
    R = abs(zm)
    r2 = float(np.mean(np.cos(2 * (np.angle(z) - phase))))
    phase_se = math.sqrt(max(1e-12, (1 - r2) / (2 * ng * max(R, 1e-6) ** 2)))
    vy_rms, vy_rms_se = _vy_rms(t, y, source)
    values = {"e_app": float(np.median(e)), "v_in_m_s": float(np.median(vin)),
              "impact_phase_rad": phase, "jar_amplitude_m": float(jar.amp),
              "vy_rms_m_s": vy_rms}
    ends = good["end"].to_numpy()
    if min(np.sum(ends > 0), np.sum(ends < 0)) >= 3:
        # the two ends' impacts differ systematically (one end clean, the other with slow
        # double hits), a fixed property of the motion, not noise: the se of a statistic is
        # its bootstrap sd with each end's impacts resampled on their own. The pooled
        # formulas overstated the scatter of a record's value between twin runs 3x for the
        # phase and 2x for v_in (24 groups of 3 seeds); this bootstrap: 0.85x, 0.45x, e 0.92x
        e_se, vin_se, phase_se = _end_bootstrap_se(ends, e, vin, z, zm)
    else:
        e_se, vin_se = _median_se(e), _median_se(vin)
    se = {"e_app": e_se, "v_in_m_s": vin_se,
          "impact_phase_rad": phase_se, "jar_amplitude_m": jar.amp_se,
          "vy_rms_m_s": vy_rms_se}
    return FlightResult(values, se, imp)


def _checked_flight_track(t_s, x_m, y_m, jar_x_m, frequency_hz, skip, n_fit, source):
    """(t, x, y, jar_x) as float arrays, checked: one length, finite times increasing over
    two jar cycles or more, gaps within :data:`MAX_GAP_FRACTION`, sane options."""
    t = np.asarray(t_s, float)
    x = np.asarray(x_m, float)
    y = np.asarray(y_m, float)
    jx = np.asarray(jar_x_m, float)
    n = len(t)
    if not (len(x) == len(y) == len(jx) == n):
        raise FlightError(f"{source}: t_s, x_m, y_m, jar_x_m differ in length")
    if not np.all(np.isfinite(t)):
        raise FlightError(f"{source}: column t_s has NaN at row "
                          f"{int(np.flatnonzero(~np.isfinite(t))[0])} (every frame needs its time)")
    # gaps: frames where the ball (x_m, y_m) or the jar (jar_x_m) was not found (NaN); an
    # impact whose fit windows touch a gap is left out, the jar is fitted on its found frames
    ok = np.isfinite(x) & np.isfinite(y) & np.isfinite(jx)
    gap_fraction = 1.0 - float(ok.mean()) if n else 0.0
    if gap_fraction > MAX_GAP_FRACTION:
        raise FlightError(f"{source}: {100 * gap_fraction:.1f} % of the frames are gaps (NaN in "
                          f"x_m, y_m or jar_x_m; limit {100 * MAX_GAP_FRACTION:.0f} %)")
    if not (frequency_hz is not None and np.isfinite(frequency_hz) and frequency_hz > 0):
        raise FlightError(f"{source}: frequency_hz must be > 0, got {frequency_hz}")
    if skip < 0 or n_fit < 3:
        raise FlightError(f"{source}: need skip >= 0 and n_fit >= 3")
    if n < 8 or np.any(np.diff(t) <= 0):
        raise FlightError(f"{source}: need >= 8 frames at increasing times")
    if (t[-1] - t[0]) * frequency_hz < 2:
        raise FlightError(f"{source}: the track spans less than two jar cycles")
    return t, x, y, jx


@dataclass(frozen=True)
class _JarFundamental:
    """The jar's motion at the drive's frequency, fitted on its found frames:
    jar_x ~ amp sin(w t + phi0) + const; amp's se from the fit's residual."""
    amp: float
    phi0: float
    amp_se: float

    @classmethod
    def fit(cls, t, jx, w, source):
        ok_j = np.isfinite(jx)
        A = np.column_stack([np.cos(w * t), np.sin(w * t), np.ones(len(t))])
        coef = np.linalg.lstsq(A[ok_j], jx[ok_j], rcond=None)[0]
        ca, cb = float(coef[0]), float(coef[1])
        amp = math.hypot(ca, cb)
        if amp <= 0:
            raise FlightError(f"{source}: the jar does not move (jar_x_m constant)")
        res = jx[ok_j] - A[ok_j] @ coef
        nj = int(ok_j.sum())
        amp_se = float(np.sqrt(np.sum(res ** 2) / max(1, nj - 3)) * math.sqrt(2.0 / nj))
        return cls(amp, math.atan2(ca, cb), amp_se)


def _impact_table(t, x, y, jx, w, phi0, skip, n_fit, end_band, source) -> pd.DataFrame:
    """One row per end impact whose fit windows are gap-free (:data:`IMPACT_TABLE_COLUMNS`):
    its contact time, end, approach and rebound speeds relative to the jar, their ratio and
    the jar's phase at contact."""
    n = len(t)
    ok = np.isfinite(x) & np.isfinite(y) & np.isfinite(jx)
    r = x - jx
    q_lo, q_hi = np.nanquantile(r, [0.02, 0.98])
    travel = q_hi - q_lo
    if not travel > 1e-3:
        raise FlightError(f"{source}: the ball moves {travel * 1e3:.3g} mm relative to the jar "
                          "(< 1 mm): no end-to-end flight")
    rows = []
    for k, end, a, b in _visits(r, q_lo + end_band * travel, q_hi - end_band * travel):
        bs = slice(k - skip - n_fit, k - skip)
        as_ = slice(k + skip + 1, k + skip + 1 + n_fit)
        if bs.start < 0 or as_.stop > n or not ok[bs.start:as_.stop].all():
            continue
        tc = _contact_time(t, x, jx, bs, as_, k, skip)
        u_b = _fit_at(t, x, bs, tc, 1)
        u_a = _fit_at(t, x, as_, tc, 1)
        V_b = _jar_velocity_at(t, jx, bs, tc, w)
        V_a = _jar_velocity_at(t, jx, as_, tc, w)
        v_in = end * (u_b - V_b)
        v_out = -end * (u_a - V_a)
        ph = (w * tc + phi0 + (math.pi if end < 0 else 0.0)) % (2 * math.pi)
        rows.append((tc, end, v_in, v_out, v_out / v_in if v_in > 0 else np.nan, ph))
    return pd.DataFrame(rows, columns=list(IMPACT_TABLE_COLUMNS))


def _vy_rms(t, y, source):
    """(rms of the vertical velocity, its se over 8 blocks): a Savitzky-Golay derivative (7
    frames, order 2: a motion at 2f = 50 Hz reads 1.4 % low, at 60 Hz 2 %, on both sides
    alike) over each gap-free run of 7 frames or more; the tracking noise's share of the mean
    square (noise sd from the track's third differences) taken out, so a clean twin track and
    a noisy measured one read the same motion."""
    dt = float(np.median(np.diff(t)))
    fin = np.isfinite(y)
    edges = np.flatnonzero(np.diff(np.r_[0, fin.astype(int), 0]))
    vy = np.concatenate([savgol_filter(y[a:b], 7, 2, deriv=1, delta=dt)
                         for a, b in zip(edges[::2], edges[1::2]) if b - a >= 7] or [np.zeros(0)])
    if len(vy) < 8:
        raise FlightError(f"{source}: fewer than 8 frames in gap-free runs of 7 or more")
    gain2 = float(np.sum(savgol_coeffs(7, 2, deriv=1, delta=dt) ** 2))
    noise_var = _noise_sd(y) ** 2 * gain2
    vy_rms = math.sqrt(max(0.0, float(np.mean(vy ** 2)) - noise_var))
    blk = np.array([math.sqrt(max(0.0, float(np.mean(b ** 2)) - noise_var))
                    for b in np.array_split(vy, 8)])
    return vy_rms, float(blk.std(ddof=1) / math.sqrt(len(blk)))


def flight_observables_frame(track: pd.DataFrame, frequency_hz, **kwargs) -> FlightResult:
    """:func:`flight_observables` on a track table (t_s, x_m, y_m, jar_x_m)."""
    missing = [c for c in ("t_s", "x_m", "y_m", "jar_x_m") if c not in track.columns]
    if missing:
        raise FlightError("%s: missing column(s) %s (impact observables need the jar's "
                          "position, column jar_x_m)" % (kwargs.get("source", "track"),
                                                         ", ".join(missing)))
    return flight_observables(track["t_s"], track["x_m"], track["y_m"], track["jar_x_m"],
                              frequency_hz, **kwargs)


#: sd floors of the measured side, in each observable's unit (the operator's se over a record
#: can come out smaller than what the measurement chain allows)
SD_FLOORS = {"e_app": 0.005, "impact_phase_rad": 0.02, "vy_rms_m_s": 0.001}

#: relative sd of one film's length scale (the scale from the ball's imaged diameter, see
#: results/observe): every length and speed read off one film is off by the same factor
FILM_SCALE_REL_SD = 0.005

#: the impact observables that are lengths or speeds: they carry their film's scale together
SCALED_OBSERVABLES = ("v_in_m_s", "jar_amplitude_m", "vy_rms_m_s")


def has_jar_track(track: pd.DataFrame) -> bool:
    """True when a track table carries the jar's position (column jar_x_m)."""
    return "jar_x_m" in track.columns


def dataset_flights(dataset, **kwargs) -> pd.DataFrame:
    """Impact observables of every track of a measurement dataset that carries jar_x_m.

    Returns the observations table (condition_id, observable, value, sd, shared_sd) diagnose
    reads: shared_sd the film's scale error (:data:`FILM_SCALE_REL_SD` of the value) that a
    track's lengths and speeds (:data:`SCALED_OBSERVABLES`) share, 0 for the others; sd that
    and the operator's standard error over the record (floored by :data:`SD_FLOORS`) in
    quadrature. Tracks in the
    jar frame (dataset velocity_frame 'jar') are moved to the lab frame first (x + jar_x).
    Conditions without a jar track give no rows; a track the operator cannot read is an error
    naming its file.
    """
    conds = dataset.conditions.set_index("condition_id")
    rows = []
    for cid, tr in sorted(dataset.tracks.items()):
        if not has_jar_track(tr):
            continue
        x = tr["x_m"].to_numpy(float)
        if getattr(dataset, "velocity_frame", "lab") == "jar":
            x = x + tr["jar_x_m"].to_numpy(float)
        res = flight_observables(tr["t_s"], x, tr["y_m"], tr["jar_x_m"],
                                 float(conds.loc[cid, "frequency_hz"]),
                                 source="%s: tracks/%s.csv" % (dataset.name, cid), **kwargs)
        for k in FLIGHT_OBSERVABLES:
            own = max(res.se[k], SD_FLOORS.get(k, 0.0))
            shared = FILM_SCALE_REL_SD * abs(res.values[k]) if k in SCALED_OBSERVABLES else 0.0
            rows.append((cid, k, res.values[k], math.hypot(own, shared), shared))
    return pd.DataFrame(rows, columns=["condition_id", "observable", "value", "sd", "shared_sd"])


def recording_flights(recording, fps=None, **kwargs) -> FlightResult:
    """:func:`flight_observables` on a twin recording as the camera sees it."""
    from analysis.observe import camera_track, load_recording
    rec = load_recording(recording)
    tr = camera_track(rec, fps)
    f = rec.meta.get("config", {}).get("frequency_hz")
    kwargs.setdefault("source", str(rec.path or "recording"))
    return flight_observables_frame(tr, f, **kwargs)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 epilog="example: python -m analysis.flights "
                                 "results/open_world/effects/eff_p01/tracks/c1.csv "
                                 "--frequency-hz 26")
    ap.add_argument("source", help="a track CSV (t_s, x_m, y_m, jar_x_m) or a recording folder")
    ap.add_argument("--frequency-hz", type=float, help="jar frequency [Hz] (tracks; recordings "
                    "read it from meta.json)")
    ap.add_argument("--impacts", help="write the per-impact table to this CSV (an existing "
                    "file is replaced only when this command wrote it, never the input)")
    a = ap.parse_args(argv)
    from pathlib import Path
    from analysis.atomic_dir import atomic_file, check_out_file, own_csv
    # the project's output rule, before any work: never the input, never an existing file this
    # command did not write (its own earlier table is recognised by its header)
    is_own = own_csv(IMPACT_TABLE_COLUMNS)
    try:
        imp_out = (check_out_file(a.impacts, [a.source], is_own=is_own, flag="--impacts")
                   if a.impacts else None)
        p = Path(a.source)
        if p.is_dir():
            res = recording_flights(p)
        else:
            if a.frequency_hz is None:
                raise FlightError("a track needs --frequency-hz")
            # the checked reader of analysis.observe: a byte-order mark, gaps (empty x_m,
            # y_m) and numbers implausible in seconds and metres (a track in mm) refused
            from analysis.observe import ObserveError, read_track
            try:
                tr = read_track(p)
            except ObserveError as exc:
                raise FlightError(str(exc)) from None
            res = flight_observables_frame(tr, a.frequency_hz, source=str(p))
    except (FlightError, ValueError, OSError) as exc:
        print("analysis.flights: error: %s" % exc, file=sys.stderr)
        return 2
    print(res.to_frame().to_string(index=False))
    if imp_out is not None:
        try:
            check_out_file(a.impacts, [a.source], is_own=is_own, flag="--impacts")
            with atomic_file(imp_out) as tmp:
                res.impacts.to_csv(tmp, index=False)
        except (ValueError, OSError) as exc:
            print("analysis.flights: error: %s" % exc, file=sys.stderr)
            return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
