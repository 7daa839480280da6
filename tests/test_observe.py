"""Observation operator against analytic tracks with known speed and collision times."""
import json
import math

import numpy as np
import pandas as pd
import pytest

from analysis.observe import (ObserveError, TrackGapError, observe_track, observe_track_file,
                              observe_recording, direct_figures, operator_bias, window_frames,
                              estimate_frequency)
from analysis.synthvideo import bounce_track

FPS = 2134.0


def sawtooth(f, V=2.0, dur=0.4, t0=0.37e-3):
    """Constant speed V, reversal every 1/(2f): exact reversal times known."""
    half = 1 / (2 * f)
    t = t0 + np.arange(int(dur * FPS)) / FPS
    ph = (t / half) % 2
    x = np.where(ph < 1, V * half * ph, V * half * (2 - ph))
    rev = np.arange(1, 1000) * half
    # reversals observable: at least 2 frames inside the record
    rev = rev[(rev > t[0] + 2 / FPS) & (rev < t[-1] - 2 / FPS)]
    return t, x, rev


@pytest.mark.parametrize("f", [22.5, 25.0, 30.0])
def test_sawtooth_speed_and_exact_collisions(f):
    t, x, rev = sawtooth(f)
    r = observe_track(t, x, 0 * x, fps=FPS, frequency_hz=f)
    assert abs(r.v_mean_m_s / 2.0 - 1) < 0.01
    assert r.n_collisions == len(rev)
    # collision times within one frame of the exact reversals
    assert np.max(np.abs(r.collision_times_s - rev)) < 1.0 / FPS
    # the rate from the collision times is the true 2 f, not a count quantised by the record
    assert r.f_col_hz == pytest.approx(2 * f, rel=1e-3)
    assert r.f_col_se_hz < 1e-3 * 2 * f


def test_plain_recipe_bias_is_what_kink_correction_removes():
    # smoothing straight through the impacts lowers mean |v| (rounded reversals)
    t, x, _ = sawtooth(30.0)
    plain = observe_track(t, x, 0 * x, fps=FPS, frequency_hz=30.0, kink_correction=False)
    fixed = observe_track(t, x, 0 * x, fps=FPS, frequency_hz=30.0)
    assert plain.v_mean_m_s < 0.99 * 2.0
    assert abs(fixed.v_mean_m_s - 2.0) < abs(plain.v_mean_m_s - 2.0)


@pytest.mark.parametrize("f", [22.5, 30.0])
def test_sinusoid_speed(f):
    a = 0.0107
    t = np.arange(int(0.5 * FPS)) / FPS
    x = a * np.sin(2 * np.pi * f * t + 0.3)
    r = observe_track(t, x, 0 * x, fps=FPS, frequency_hz=f)
    # mean |v| of a sinusoid over whole half periods: 4 a f; the record is not a whole number
    # of half periods, so compare with the exact average over the record
    tt = np.linspace(t[0], t[-1], 400001)
    truth = np.trapezoid(np.abs(a * 2 * np.pi * f * np.cos(2 * np.pi * f * tt + 0.3)), tt) / (
        t[-1] - t[0])
    assert abs(r.v_mean_m_s / truth - 1) < 0.01
    ph = 2 * np.pi * f * t + 0.3
    expected = np.sum(np.diff(np.floor((ph - np.pi / 2) / np.pi)) != 0)
    assert r.n_collisions == expected
    assert r.n_kinks == 0  # smooth turns are not treated as impacts


@pytest.mark.parametrize("sigma_m", [2e-5, 6e-5])
def test_noise_makes_no_false_collisions(sigma_m):
    rng = np.random.default_rng(7)
    t, x, rev = sawtooth(27.5)
    xn = x + rng.normal(0, sigma_m, len(x))
    yn = rng.normal(0, sigma_m, len(x))
    r = observe_track(t, xn, yn, fps=FPS, frequency_hz=27.5)
    assert r.n_collisions == len(rev)
    assert abs(r.v_mean_m_s / 2.0 - 1) < 0.01
    # a ball at rest or gliding at constant speed: noise alone never counts a collision
    t2 = np.arange(2000) / FPS
    for v in (0.0, 0.5):
        r0 = observe_track(t2, v * t2 + rng.normal(0, sigma_m, len(t2)),
                           rng.normal(0, sigma_m, len(t2)), fps=FPS, frequency_hz=27.5)
        assert r0.n_collisions == 0


def test_bounce_model_track_lab_and_jar():
    b = bounce_track(25.0, 0.4)
    for frame in ("lab", "jar"):
        tr = b.sample(FPS, frame=frame)
        r = observe_track(tr.t_s, tr.x_m, tr.y_m, fps=FPS, frequency_hz=25.0)
        assert abs(r.v_mean_m_s / b.true_mean_speed(frame=frame) - 1) < 0.01
    tr = b.sample(FPS)
    r = observe_track(tr.t_s, tr.x_m, tr.y_m, fps=FPS, frequency_hz=25.0)
    rt = np.sort(b.reversal_times())
    truth = (len(rt) - 1) / (rt[-1] - rt[0])
    assert r.f_col_hz == pytest.approx(truth, abs=max(3 * r.f_col_se_hz, 1e-3 * truth))
    # the jar frame via the jar_x_m column equals sampling in the jar frame
    rj = observe_track(tr.t_s, tr.x_m, tr.y_m, fps=FPS, frequency_hz=25.0, frame="jar",
                       jar_x_m=tr.jar_x_m)
    tj = b.sample(FPS, frame="jar")
    rj2 = observe_track(tj.t_s, tj.x_m, tj.y_m, fps=FPS, frequency_hz=25.0)
    assert rj.v_mean_m_s == pytest.approx(rj2.v_mean_m_s, rel=1e-12)


def test_result_shapes_and_frame():
    t, x, _ = sawtooth(30.0)
    r = observe_track(t, x, 0 * x, fps=FPS, frequency_hz=30.0, mass_kg=0.0357)
    assert r.vx_m_s.shape == (len(t) - 1,) == r.t_s.shape == r.vx_raw_m_s.shape
    assert r.collision_times_s.shape == (r.n_collisions,)
    assert r.e_kin_j == pytest.approx(0.5 * 0.0357 * r.v_mean_m_s ** 2)
    df = r.to_frame()
    assert len(df) == 1 and {"v_mean_m_s", "e_kin_j", "f_col_hz", "param_window_frames"} <= set(df)
    assert len(r.samples_frame()) == len(t) - 1


def test_window_rule():
    assert window_frames(2134, 30) == 7  # 35.6 frames between impacts / 4 = 8.9 -> 7
    assert window_frames(2134, 22.5) == 11
    assert window_frames(2134, 30) < 2134 / 60 / 2
    t = np.arange(3000) / FPS
    assert estimate_frequency(t, np.sin(2 * np.pi * 27.5 * t)) == pytest.approx(27.5, abs=0.2)


def test_gaps_are_not_differentiated_and_reported():
    t, x, rev = sawtooth(25.0)
    x = x.copy()
    q = np.array(["ok"] * len(x), dtype=object)
    x[100:104] = np.nan  # short gap (bridged)
    q[300:340] = "lost"  # long gap, inside a flight and across a reversal
    r = observe_track(t, x, 0 * x, fps=FPS, frequency_hz=25.0, quality=q)
    assert r.gap_fraction == pytest.approx(44 / len(x))
    assert abs(r.v_mean_m_s / 2.0 - 1) < 0.01  # no spike from differencing across a gap
    assert np.all(np.isnan(r.vx_raw_m_s[299:340]))
    assert r.count_duration_s < t[-1] - t[0]
    # the reversal lost in the long gap does not lengthen the mean interval: still 2 f
    assert r.n_collisions == len(rev) - 1
    assert r.f_col_hz == pytest.approx(50.0, rel=1e-3)


def test_collision_rate_against_known_processes():
    from yade_scripts.twin_modes import collision_rate
    # periodic at 55 /s in a 0.5 s record: 27 or 28 impacts, n / duration reads 54 or 56
    for t0 in (0.001, 0.009, 0.017):
        times = t0 + np.arange(40) / 55.0
        times = times[times < 0.5]
        rate, se = collision_rate(times, 0.5)
        assert rate == pytest.approx(55.0, rel=1e-12) and se < 1e-9
        assert abs(len(times) / 0.5 - 55.0) > 0.9
    # Poisson impacts at 50 /s: the stated se covers the truth as often as it claims
    rng = np.random.default_rng(3)
    z = []
    for _ in range(400):
        times = np.cumsum(rng.exponential(1 / 50.0, 60))
        rate, se = collision_rate(times, times[-1])
        z.append((rate - 50.0) / se)
    z = np.abs(np.array(z))
    assert 0.90 <= np.mean(z < 1.96) <= 0.99
    # a jittered periodic sequence: se shrinks with the jitter
    times = np.arange(30) / 45.0 + rng.normal(0, 1e-4, 30)
    rate, se = collision_rate(times, 30 / 45.0)
    assert abs(rate - 45.0) < 4 * se + 1e-3 and se < 0.05
    # segments: an impact missed in a gap does not count as a double interval
    times = np.delete(np.arange(30) / 50.0, 15)
    seg = (np.arange(29) >= 15).astype(int)
    assert collision_rate(times, 0.6, seg)[0] == pytest.approx(50.0)
    assert collision_rate(times, 0.6)[0] < 49.0
    # fewer than 2 intervals: the Poisson count
    assert collision_rate([0.1, 0.2], 0.5) == pytest.approx((4.0, math.sqrt(2) / 0.5))
    assert collision_rate([], 0.5) == pytest.approx((0.0, 2.0))


def test_too_many_gaps_is_a_clear_error():
    t, x, _ = sawtooth(25.0)
    q = np.array(["ok"] * len(x), dtype=object)
    q[: len(x) // 2] = "lost"
    with pytest.raises(TrackGapError, match="lost"):
        observe_track(t, x, 0 * x, fps=FPS, frequency_hz=25.0, quality=q)


def test_bad_inputs(tmp_path):
    t, x, _ = sawtooth(25.0)
    with pytest.raises(ObserveError, match="fps"):
        observe_track(t, x, 0 * x, fps=0, frequency_hz=25.0)
    with pytest.raises(ObserveError, match="fps"):
        observe_track(t, x, 0 * x, fps=-2134, frequency_hz=25.0)
    with pytest.raises(ObserveError, match="frequency"):
        observe_track(t, x, 0 * x, fps=FPS, frequency_hz=-5)
    with pytest.raises(ObserveError, match="increase"):
        observe_track(t[::-1], x, 0 * x, fps=FPS, frequency_hz=25.0)
    with pytest.raises(ObserveError, match="uniformly"):
        tt = t.copy()
        tt[50:] += 3 / FPS
        observe_track(tt, x, 0 * x, fps=FPS, frequency_hz=25.0)
    with pytest.raises(ObserveError, match="jar_x_m"):
        observe_track(t, x, 0 * x, fps=FPS, frequency_hz=25.0, frame="jar")
    p = tmp_path / "track.csv"
    pd.DataFrame({"t_s": t, "x_m": x}).to_csv(p, index=False)
    with pytest.raises(ObserveError, match="y_m"):
        observe_track_file(p, fps=FPS, frequency_hz=25.0)
    df = pd.DataFrame({"t_s": t, "x_m": x.astype(object), "y_m": 0 * x})
    df.loc[5, "x_m"] = "abc"
    df.to_csv(p, index=False)
    with pytest.raises(ObserveError, match="row 5, column x_m"):
        observe_track_file(p, fps=FPS, frequency_hz=25.0)
    with pytest.raises(ObserveError, match="no such"):
        observe_track_file(tmp_path / "nope.csv")


def fake_recording(tmp_path, f=25.0, dur=0.3):
    """A recording folder built from the 1-D bounce model (lab frame, z constant)."""
    b = bounce_track(f, dur)
    t = np.arange(int(dur * FPS)) / FPS
    x, _ = b.position(t)
    vx = b.velocity(t)
    z = np.full_like(t, -0.003)
    traj = pd.DataFrame({"t_s": t, "x_m": x, "y_m": 0 * t, "z_m": z, "vx_m_s": vx,
                         "vy_m_s": 0 * t, "vz_m_s": 0 * t, "wx_rad_s": 0 * t, "wy_rad_s": 0 * t,
                         "wz_rad_s": 0 * t, "jar_x_m": b.jar_position(t),
                         "jar_vx_m_s": b.jar_velocity(t)})
    ti = b.impact_times(0, t[-1])
    imp = pd.DataFrame({"event_id": np.arange(len(ti)), "t_start_s": ti, "t_end_s": ti + 1e-5,
                        "vn_in_m_s": 1.0, "vt_in_m_s": 0.0, "vn_out_m_s": 0.1, "fn_peak_n": 1e3,
                        "e_diss_j": 0.01, "where": "end_cap", "x_contact_jar_m": 0.0,
                        "n_facets": 1})
    d = tmp_path / "run"
    d.mkdir()
    traj.to_csv(d / "trajectory.csv", index=False)
    imp.to_csv(d / "impacts.csv", index=False)
    meta = {"config": {"frequency_hz": f, "ball_diameter_m": 0.0206,
                       "ball_density_kg_m3": 7800.0}, "ball_mass_kg": 0.0357,
            "jar": {"inner_length_m": 0.042, "inner_diameter_m": 0.0275}}
    (d / "meta.json").write_text(json.dumps(meta))
    return d, b


def test_recording_operator_direct_and_bias(tmp_path):
    d, b = fake_recording(tmp_path)
    obs = observe_recording(d)
    direct = direct_figures(d)
    assert direct["v_mean_3d_m_s"] == pytest.approx(b.true_mean_speed(0, direct["duration_s"]),
                                                    rel=2e-3)
    assert abs(obs.v_mean_m_s / direct["v_mean_3d_m_s"] - 1) < 0.01
    assert obs.e_kin_j == pytest.approx(0.5 * 0.0357 * obs.v_mean_m_s ** 2)
    bias = operator_bias(d)
    row = bias.set_index("quantity").loc["f_col_hz"]
    # the 1-D model hits each end twice per cycle but reverses once: the operator (sign
    # changes) sees 2f, impacts.csv counts 4f - operator_bias must show that difference
    assert row["direct"] == pytest.approx(4 * 25.0, abs=1 / 0.3 + 1e-9)
    assert row["operator"] == pytest.approx(2 * 25.0, abs=1 / 0.3 + 1e-9)
    objar = observe_recording(d, frame="jar")
    assert abs(objar.v_mean_m_s / b.true_mean_speed(0, direct["duration_s"], frame="jar") - 1) \
        < 0.01


def test_recording_errors(tmp_path):
    with pytest.raises(ObserveError, match="not a recording"):
        observe_recording(tmp_path / "missing")
    d, _ = fake_recording(tmp_path)
    tr = pd.read_csv(d / "trajectory.csv").drop(columns=["z_m"])
    tr.to_csv(d / "trajectory.csv", index=False)
    with pytest.raises(ObserveError, match="z_m"):
        observe_recording(d)
