"""Analytic 1-D bounce model and the synthetic video writer."""
import json
import math

import numpy as np
import pytest

from analysis.synthvideo import (BounceModelError, Camera, VideoWriteError, bounce_track,
                                 periodic_orbit, render_video, write_video)
from analysis.tracking import read_frames


@pytest.mark.parametrize("f", [22.5, 30.0])
def test_bounce_model_stays_in_jar_and_conserves_impact_law(f):
    b = bounce_track(f, 0.2)
    t = np.linspace(0, 0.2, 20001)
    x, y = b.position(t)
    rel = x - b.jar_position(t)
    h = b.half_gap_m
    assert np.all(np.abs(rel) <= h + 1e-9)
    # at every impact the velocity relative to the wall reverses and shrinks by e
    ti = b.impact_times()
    assert len(ti) > 0
    for tc in ti[:6]:
        vb, va = b.velocity(np.array([tc - 1e-9, tc + 1e-9]))
        vw = b.jar_velocity(tc)
        assert (va - vw) == pytest.approx(-b.restitution * (vb - vw), rel=1e-5, abs=1e-6)
    # lab speed per cycle of the settled motion: v_mean / f is a length (Table 3: ~0.083 m)
    assert 0.07 < b.true_mean_speed() / f < 0.09
    assert b.true_mean_speed(frame="jar") < b.true_mean_speed()


def test_bounce_reversals_are_two_per_cycle_in_lab():
    b = bounce_track(25.0, 0.4)
    assert len(b.reversal_times()) == pytest.approx(2 * 25 * 0.4, abs=1)


def test_periodic_orbit_formula():
    th, V = periodic_orbit(30.0)
    A, w, e, g = 0.0135, 2 * math.pi * 30, 0.11, 0.042 - 0.0206
    k = (1 + e) / (1 - e)
    assert k * math.pi * A * abs(math.cos(th)) == pytest.approx(g + 2 * A * math.sin(th))
    assert V == pytest.approx(k * A * w * abs(math.cos(th)))


def test_bounce_bad_params():
    with pytest.raises(BounceModelError, match="frequency"):
        bounce_track(-1, 0.1)
    with pytest.raises(BounceModelError, match="restitution"):
        bounce_track(25, 0.1, restitution=0)
    with pytest.raises(BounceModelError, match="inner_length"):
        bounce_track(25, 0.1, inner_length_m=0.01)


def test_video_round_trip_and_truth(tmp_path):
    b = bounce_track(30.0, 0.03)
    cam = Camera(width_px=160, height_px=80, m_per_px=6e-4, noise_sigma=0, flicker=0,
                 occluder=False, exposure_s=0)
    out = tmp_path / "v.mkv"
    truth = render_video(b, out, cam)
    frames = read_frames(out)
    assert len(frames) == len(truth) and frames[0].shape == (80, 160)
    side = json.loads((tmp_path / "v.json").read_text())
    assert side["fps"] == 2134.0 and side["ball_diameter_px"] == pytest.approx(0.0206 / 6e-4)
    # intensity centroid of the bright blob sits on the ground truth
    f = frames[5].astype(float)
    m = f > (cam.background + 0.5 * (cam.ball_level - cam.background))
    yy, xx = np.nonzero(m)
    assert np.mean(xx) == pytest.approx(truth.x_px[5], abs=0.3)
    assert np.mean(yy) == pytest.approx(truth.y_px[5], abs=0.3)
    # lossless: writing the same frames again gives identical pixels
    out2 = tmp_path / "w.mkv"
    write_video(out2, frames, 2134.0, (160, 80))
    assert all(np.array_equal(a, c) for a, c in zip(frames, read_frames(out2)))


def test_video_writer_errors(tmp_path):
    with pytest.raises(VideoWriteError, match="AVI"):
        write_video(tmp_path / "x.avi", [np.zeros((8, 8), np.uint8)], 2134.0, (8, 8))
    with pytest.raises(VideoWriteError, match="fps"):
        write_video(tmp_path / "x.mkv", [np.zeros((8, 8), np.uint8)], 0, (8, 8))
    with pytest.raises(VideoWriteError, match="no frames"):
        write_video(tmp_path / "x.mkv", [], 2134.0, (8, 8))
    assert not (tmp_path / "x.mkv").exists()
