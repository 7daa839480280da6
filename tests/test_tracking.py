"""Tracking a ball in small synthetic videos with known ground truth; bad inputs."""
import numpy as np
import pandas as pd
import pytest

from analysis.observe import observe_track
from analysis.synthvideo import Camera, bounce_track, render_video, write_video
from analysis.tracking import (BallNotFoundError, TrackingError, VideoReadError, main,
                               track_video, track_frames)

FPS = 2134.0


def small_cam(**kw):
    # 256x128 px, ball ~51 px across: small enough to be quick, large enough to be realistic
    base = dict(width_px=256, height_px=128, m_per_px=4e-4, exposure_s=100e-6, noise_sigma=2.0,
                flicker=0.03, occluder=True, occluder_x_px=200.0, occluder_width_px=6.0)
    base.update(kw)
    return Camera(**base)


@pytest.fixture(scope="module")
def video30(tmp_path_factory):
    d = tmp_path_factory.mktemp("v30")
    b = bounce_track(30.0, 0.25)
    truth = render_video(b, d / "v.mkv", small_cam(), seed=3)
    return d / "v.mkv", truth, b


def test_track_error_and_observables(video30):
    path, truth, b = video30
    res = track_video(path, FPS, m_per_px=4e-4, ball_diameter_m=0.0206)
    tk = res.track
    err = np.hypot(tk.x_px - truth.x_px, tk.y_px - truth.y_px)
    assert res.n_lost == 0
    assert np.sqrt(np.mean(err ** 2)) <= 0.5
    o = observe_track(tk.t_s, tk.x_m, tk.y_m, fps=FPS, frequency_hz=30.0, quality=tk.quality)
    t0, t1 = truth.t_s.iloc[0], truth.t_s.iloc[-1]
    assert abs(o.v_mean_m_s / b.true_mean_speed(t0, t1) - 1) < 0.01
    true_f = len(b.reversal_times(t0, t1)) / (t1 - t0)
    assert abs(o.f_col_hz - true_f) <= 1.0 / (t1 - t0) + 1e-9  # at most one edge reversal off


def test_scale_from_ball_diameter(video30):
    path, truth, b = video30
    res = track_video(path, FPS, ball_diameter_m=0.0206, m_per_px=None)
    assert res.scale_source == "ball_diameter"
    assert res.m_per_px == pytest.approx(4e-4, rel=0.01)


def test_cli_writes_track(video30, tmp_path, capsys):
    path, truth, _ = video30
    out = tmp_path / "track.csv"
    assert main([str(path), "--fps", "2134", "--m-per-px", "4e-4", "--out", str(out)]) == 0
    df = pd.read_csv(out)
    assert list(df.columns[:4]) == ["t_s", "x_m", "y_m", "quality"]
    assert len(df) == len(truth)


def test_long_loss_is_flagged_not_interpolated(tmp_path):
    b = bounce_track(25.0, 0.1)
    cam = small_cam(occluder=False, noise_sigma=1.0)
    path = tmp_path / "v.mkv"
    truth = render_video(b, path, cam)
    from analysis.tracking import read_frames
    frames = read_frames(path)
    for i in range(60, 90):  # the ball vanishes for 30 frames (a hand in front of the lens)
        frames[i] = np.full_like(frames[i], int(cam.background))
    res = track_frames(frames, FPS, m_per_px=4e-4, ball_diameter_m=0.0206)
    q = res.track.quality.to_numpy()
    assert np.all(q[60:90] == "lost") and res.track.x_m[60:90].isna().all()
    assert "reacquired" in set(q[90:95])
    ok = q != "lost"
    err = np.hypot(res.track.x_px - truth.x_px, res.track.y_px - truth.y_px)[ok]
    assert np.sqrt(np.mean(err ** 2)) <= 0.5


def test_bad_videos(tmp_path):
    with pytest.raises(VideoReadError, match="no such"):
        track_video(tmp_path / "missing.mkv", FPS, m_per_px=4e-4)
    empty = tmp_path / "empty.mkv"
    empty.write_bytes(b"")
    with pytest.raises(VideoReadError, match="empty"):
        track_video(empty, FPS, m_per_px=4e-4)
    corrupt = tmp_path / "corrupt.mkv"
    corrupt.write_bytes(np.random.default_rng(0).integers(0, 256, 4096, dtype=np.uint8).tobytes())
    with pytest.raises(VideoReadError):
        track_video(corrupt, FPS, m_per_px=4e-4)
    with pytest.raises(VideoReadError, match="no decodable frame"):
        track_frames(iter([]), FPS, m_per_px=4e-4, ball_diameter_m=0.0206)
    with pytest.raises(TrackingError, match="fps"):
        track_frames(iter([]), 0, m_per_px=4e-4)
    with pytest.raises(TrackingError, match="fps"):
        track_frames(iter([]), -5.0, m_per_px=4e-4)


def test_ball_never_found(tmp_path):
    frames = [np.full((128, 256), 70, np.uint8) + np.random.default_rng(i).integers(
        0, 3, (128, 256), dtype=np.uint8) for i in range(20)]
    p = tmp_path / "noball.mkv"
    write_video(p, frames, FPS, (256, 128))
    with pytest.raises(BallNotFoundError, match="never found"):
        track_video(p, FPS, m_per_px=4e-4, ball_diameter_m=0.0206)


def test_cli_bad_input_exit_code(tmp_path, capsys):
    assert main([str(tmp_path / "nope.mkv"), "--fps", "2134", "--m-per-px", "4e-4",
                 "--out", str(tmp_path / "t.csv")]) == 2
    assert "error" in capsys.readouterr().err
    assert not (tmp_path / "t.csv").exists()
    assert main([str(tmp_path / "nope.mkv"), "--fps", "-1", "--m-per-px", "4e-4",
                 "--out", str(tmp_path / "t.csv")]) == 2


def test_jar_frame_video_and_fast_rim_method(tmp_path):
    # a camera riding on the jar: the tracked speed is the jar-frame speed
    from analysis.tracking import TrackerSettings
    b = bounce_track(22.5, 0.2)
    path = tmp_path / "jar.mkv"
    truth = render_video(b, path, small_cam(), frame="jar", seed=5)
    for method in ("crossings", "contour"):
        res = track_video(path, FPS, m_per_px=4e-4, ball_diameter_m=0.0206,
                          settings=TrackerSettings(rim_method=method))
        tk = res.track
        err = np.hypot(tk.x_px - truth.x_px, tk.y_px - truth.y_px)
        assert np.sqrt(np.mean(err ** 2)) <= 0.5
        o = observe_track(tk.t_s, tk.x_m, tk.y_m, fps=FPS, frequency_hz=22.5,
                          quality=tk.quality)
        t0, t1 = truth.t_s.iloc[0], truth.t_s.iloc[-1]
        assert abs(o.v_mean_m_s / b.true_mean_speed(t0, t1, frame="jar") - 1) < 0.01


def test_band_rim_fit_matches_window_scan(video30):
    # the default 'band' fit reads the same sub-pixel rim crossings as the 'crossings' window
    # scan, on short profiles only: the two tracks agree far below the error budget
    from analysis.tracking import TrackerSettings
    path, truth, _ = video30
    res = {m: track_video(path, FPS, m_per_px=4e-4, ball_diameter_m=0.0206,
                          settings=TrackerSettings(rim_method=m, mosse_every=1))
           for m in ("band", "crossings")}
    a, b = res["band"].track, res["crossings"].track
    assert res["band"].n_lost == 0 and res["band"].n_reacquired == 0
    d = np.hypot(a.x_px - b.x_px, a.y_px - b.y_px)
    assert np.sqrt(np.mean(d ** 2)) < 0.05
    err = np.hypot(a.x_px - truth.x_px, a.y_px - truth.y_px)
    assert np.sqrt(np.mean(err ** 2)) <= 0.5
    # the diameter scale comes from the same scale-frame rim points
    assert res["band"].ball_diameter_px == pytest.approx(res["crossings"].ball_diameter_px,
                                                         abs=0.01)


def test_band_near_frame_border_falls_back_to_window_scan(tmp_path):
    # crop the frames so that the ball's left turn comes closer to the border than the band's
    # profiles reach: those frames use the window scan; the track stays exact
    from analysis.tracking import _BandRim, read_frames
    b = bounce_track(25.0, 0.1)
    path = tmp_path / "v.mkv"
    truth = render_video(b, path, small_cam(occluder=False), seed=2)
    crop = int(np.floor(truth.x_px.min())) - 30  # ball's leftmost centre 30 px from the border
    frames = [f[:, crop:] for f in read_frames(path)]
    reach = _BandRim(0.5 * 0.0206 / 4e-4, frames[0].shape[1]).reach
    assert (truth.x_px - crop < reach).sum() > 5  # some frames do need the fallback
    res = track_frames(frames, FPS, m_per_px=4e-4, ball_diameter_m=0.0206)
    assert res.n_lost == 0
    err = np.hypot(res.track.x_px - (truth.x_px - crop), res.track.y_px - truth.y_px)
    assert np.sqrt(np.mean(err ** 2)) <= 0.5


def test_bad_settings():
    from analysis.tracking import TrackerSettings
    frames = [np.zeros((64, 64), np.uint8)]
    with pytest.raises(TrackingError, match="rim_method"):
        track_frames(frames, FPS, m_per_px=4e-4, settings=TrackerSettings(rim_method="edges"))
    with pytest.raises(TrackingError, match="mosse_every"):
        track_frames(frames, FPS, m_per_px=4e-4, settings=TrackerSettings(mosse_every=0))


def test_decode_ahead_gives_every_frame(tmp_path):
    # frames decoded in the background into reused blocks: all of them, in order, for a
    # length that is no multiple of the block size; a reader that stops early does not hang
    from analysis.tracking import decode_ahead, open_video, read_frames
    rng = np.random.default_rng(7)
    frames = [rng.integers(0, 256, (24, 40), dtype=np.uint8) for _ in range(45)]
    p = tmp_path / "r.mkv"
    write_video(p, frames, FPS, (40, 24))
    ref = read_frames(p)
    assert len(ref) == 45
    cap = open_video(p)
    got = [f.copy() for f in decode_ahead(cap, batch=8, depth=2)]
    cap.release()
    assert len(got) == len(ref) and all(np.array_equal(g, r) for g, r in zip(got, ref))
    cap = open_video(p)
    gen = decode_ahead(cap, batch=8, depth=2)
    first = [next(gen).copy() for _ in range(3)]
    gen.close()
    cap.release()
    assert all(np.array_equal(g, r) for g, r in zip(first, ref))


def test_cli_rim_method_and_bad_mosse_every(video30, tmp_path, capsys):
    path, truth, _ = video30
    out = tmp_path / "track.csv"
    assert main([str(path), "--fps", "2134", "--m-per-px", "4e-4", "--rim-method", "crossings",
                 "--mosse-every", "1", "--out", str(out)]) == 0
    df = pd.read_csv(out)
    err = np.hypot(df.x_px - truth.x_px, df.y_px - truth.y_px)
    assert np.sqrt(np.mean(err ** 2)) <= 0.5
    bad = tmp_path / "bad.csv"
    assert main([str(path), "--fps", "2134", "--m-per-px", "4e-4", "--mosse-every", "0",
                 "--out", str(bad)]) == 2
    assert "mosse_every" in capsys.readouterr().err
    assert not bad.exists()


def test_jar_is_followed_by_its_end_walls(video30):
    """track_jar: the band just inside the jar's bottom wall is found, both end walls are
    followed to < 0.1 px rms (sub-pixel centroids of their dips), the result is the zero-mean
    jar displacement."""
    from analysis.tracking import track_jar_video
    path, truth, _ = video30
    x, info = track_jar_video(path, 4e-4)
    tj = truth["jar_x_m"].to_numpy() - truth["jar_x_m"].mean()
    err_px = (x - tj) / 4e-4
    assert info["n_lost"] == 0 and len(x) == len(truth)
    assert np.sqrt(np.mean(err_px ** 2)) < 0.1
    # wall centres: the inner length plus one wall thickness (half a wall outside each end)
    assert info["length_px"] == pytest.approx(0.042 / 4e-4 + small_cam().jar_wall_px, abs=0.1)


def test_impact_observables_from_a_video_with_the_jar(tmp_path, capsys):
    """Video -> ball and jar tracks (--jar) -> analysis.flights: the apparent restitution of a
    periodic e = 0.3 bounce and the jar amplitude are read back from the film."""
    from analysis.flights import flight_observables_frame
    b = bounce_track(25.0, 0.3, restitution=0.3, mode="periodic")
    path = tmp_path / "e30.mkv"
    render_video(b, path, small_cam(), seed=4)
    out = tmp_path / "track.csv"
    assert main([str(path), "--fps", "2134", "--m-per-px", "4e-4", "--jar", "--out",
                 str(out)]) == 0
    assert "jar: end walls followed" in capsys.readouterr().out
    tk = pd.read_csv(out)
    assert "jar_x_m" in tk.columns and tk["jar_x_m"].notna().all()
    res = flight_observables_frame(tk, 25.0)
    assert res.values["e_app"] == pytest.approx(0.3, abs=0.02)
    assert res.values["jar_amplitude_m"] == pytest.approx(0.0135, rel=0.01)


def test_jar_not_found_and_bad_band(tmp_path, capsys):
    from analysis.tracking import JarNotFoundError, track_jar
    blank = [np.full((64, 128), 90, np.uint8) for _ in range(3)]
    with pytest.raises(JarNotFoundError):
        track_jar(blank, 4e-4)
    with pytest.raises(JarNotFoundError, match="outside the frame"):
        track_jar(blank, 4e-4, band=(60, 80))
    with pytest.raises(JarNotFoundError, match="no frame"):
        track_jar([], 4e-4)
