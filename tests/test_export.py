"""A run for ParaView (VTK) and as a movie: frames, coordinates, sizes, and bad input that leaves
nothing behind. Recordings are made from the 1-D bounce model (tests/test_observe.py), no YADE."""
import json
import math
import xml.etree.ElementTree as ET

import cv2
import numpy as np
import pandas as pd
import pytest
from PIL import Image

from analysis import export
from analysis.atomic_dir import MARKER
from analysis.config import DEFAULT_STL
from analysis.synthvideo import Camera, bounce_track, render_video
from analysis.tracking import read_frames
from geometry.stl_io import check_jar_mesh, read_stl, scale_for_units
from tests.test_observe import fake_recording

vtk_xml = pytest.importorskip("vtkmodules.vtkIOXML")
from vtkmodules.util.numpy_support import vtk_to_numpy  # noqa: E402

from tests.test_output_safety import tree_hash  # noqa: E402

BALL_D = 0.0206  # the fake recording's ball


def default_jar():
    tri = read_stl(str(DEFAULT_STL))
    return check_jar_mesh(tri, scale_for_units(tri, "auto"))


@pytest.fixture
def run(tmp_path):
    """A 0.05 s recording (106 frames at 2134/s) whose meta.json names the default jar."""
    d, _ = fake_recording(tmp_path, f=25.0, dur=0.05)
    meta = json.loads((d / "meta.json").read_text())
    info = default_jar()
    meta["run_id"] = "test-run"
    meta["config"].update({"stl_path": "geometry/mm400_25ml.stl", "stl_units": "auto"})
    meta["jar"] = {"inner_length_m": info["inner_length_m"],
                   "inner_diameter_m": info["inner_diameter_m"], "n_facets": info["n_facets"]}
    (d / "meta.json").write_text(json.dumps(meta))
    return d


def read_vtp(path):
    r = vtk_xml.vtkXMLPolyDataReader()
    r.SetFileName(str(path))
    r.Update()
    out = r.GetOutput()
    assert r.GetErrorCode() == 0 and out.GetNumberOfPoints() > 0, path
    return out


def pvd_entries(path):
    root = ET.parse(path).getroot()
    assert root.get("type") == "Collection"
    return [(float(e.get("timestep")), int(e.get("part")), e.get("file"))
            for e in root.iter("DataSet")]


def test_vtk_lists_every_frame_with_ball_and_jar(run, tmp_path, capsys):
    out = tmp_path / "vtk"
    assert export.main([str(run), "--vtk", str(out), "--every", "3"]) == 0
    tr = pd.read_csv(run / "trajectory.csv")
    rows = tr.iloc[::3].reset_index(drop=True)
    n = math.ceil(len(tr) / 3)
    assert len(rows) == n == 36
    ball = pvd_entries(out / "ball.pvd")
    jar = pvd_entries(out / "jar.pvd")
    both = pvd_entries(out / "run.pvd")
    assert len(ball) == len(jar) == n and len(both) == 2 * n
    assert [p for _, p, _ in both] == [0, 1] * n
    np.testing.assert_allclose([t for t, _, _ in ball], rows.t_s, rtol=0, atol=1e-12)
    n_facets = len(read_stl(str(DEFAULT_STL)))
    for i, ((tb, _, fb), (tj, _, fj)) in enumerate(zip(ball, jar)):
        assert tb == tj
        b = read_vtp(out / fb)
        assert b.GetNumberOfPoints() == 1 and b.GetNumberOfVerts() == 1
        p = vtk_to_numpy(b.GetPoints().GetData())[0]
        np.testing.assert_allclose(p, rows.loc[i, ["x_m", "y_m", "z_m"]].to_numpy(float),
                                   rtol=0, atol=1e-12)
        pd_ = b.GetPointData()
        assert vtk_to_numpy(pd_.GetArray("radius_m"))[0] == pytest.approx(BALL_D / 2)
        np.testing.assert_allclose(vtk_to_numpy(pd_.GetArray("velocity_m_s"))[0],
                                   rows.loc[i, ["vx_m_s", "vy_m_s", "vz_m_s"]].to_numpy(float),
                                   rtol=0, atol=1e-12)
        assert vtk_to_numpy(b.GetFieldData().GetArray("time_s"))[0] == tb
        j = read_vtp(out / fj)
        assert j.GetNumberOfPolys() == j.GetNumberOfCells() == n_facets
        pts = vtk_to_numpy(j.GetPoints().GetData())
        centre = 0.5 * (pts.min(axis=0) + pts.max(axis=0))
        # the mesh is centred at rest, so its box centre is the recorded jar displacement
        assert centre[0] == pytest.approx(rows.jar_x_m[i], abs=1e-7)
        assert abs(centre[1]) < 1e-7 and abs(centre[2]) < 1e-7
    assert (out / MARKER).is_file()
    meta = json.loads((out / "export.json").read_text())
    assert meta["n_frames"] == n and meta["jar_n_facets"] == n_facets
    assert "36 frames" in capsys.readouterr().out


def test_vtk_rerun_replaces_own_output_refuses_foreign(run, tmp_path, capsys):
    out = tmp_path / "vtk"
    n = len(pd.read_csv(run / "trajectory.csv"))
    assert export.main([str(run), "--vtk", str(out)]) == 0
    assert len(list((out / "ball").iterdir())) == n
    assert export.main([str(run), "--vtk", str(out), "--every", "10"]) == 0
    assert len(list((out / "ball").iterdir())) == math.ceil(n / 10)  # old ones gone
    foreign = tmp_path / "notes"
    foreign.mkdir()
    (foreign / "thesis.tex").write_text("precious")
    before = tree_hash(tmp_path)
    capsys.readouterr()
    assert export.main([str(run), "--vtk", str(foreign)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("analysis.export: error: --vtk")
    assert tree_hash(tmp_path) == before


def count_video_frames(path):
    cap = cv2.VideoCapture(str(path))
    assert cap.isOpened()
    size = (int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)))
    n = 0
    while cap.read()[0]:
        n += 1
    cap.release()
    return n, size


def test_movie_mp4_and_gif_frames_size_and_ball_position(run, tmp_path):
    t = pd.read_csv(run / "trajectory.csv")
    n_expected = int((t.t_s <= t.t_s[0] + 0.02 + 1e-12).sum())
    cam = export.movie_camera(export.load_run(run))
    mp4 = tmp_path / "m" / "run.mp4"
    assert export.main([str(run), "--movie", str(mp4), "--seconds", "0.02"]) == 0
    n, size = count_video_frames(mp4)
    assert n == n_expected and size == (cam.width_px, cam.height_px)
    side = json.loads((tmp_path / "m" / "run.mp4.json").read_text())
    assert side["n_frames"] == n and side["playback_fps"] == export.DEFAULT_MOVIE_FPS
    assert side["slow_motion_factor"] == pytest.approx(2134.0 / 50.0, rel=1e-3)

    gif = tmp_path / "m" / "run.gif"
    assert export.main([str(run), "--movie", str(gif), "--seconds", "0.02", "--fps",
                        "25"]) == 0
    im = Image.open(gif)
    assert im.n_frames == n_expected and im.size == (cam.width_px, cam.height_px)
    assert im.info["duration"] == 40
    # the ball is drawn where the trajectory puts it (x along the jar axis, z up)
    for k in (0, n_expected - 1):
        im.seek(k)
        f = np.asarray(im.convert("L"), float)
        f[:22] = 0  # the time label
        yy, xx = np.nonzero(f > 140)
        x_px, y_px = cam.to_px(t.x_m[k], t.z_m[k])
        assert np.mean(xx) == pytest.approx(x_px, abs=1.5)
        assert np.mean(yy) == pytest.approx(y_px, abs=3.0)  # highlight pulls it up a little
    # its own earlier output may be replaced
    assert export.main([str(run), "--movie", str(gif), "--seconds", "0.01"]) == 0
    assert Image.open(gif).n_frames == int((t.t_s <= t.t_s[0] + 0.01 + 1e-12).sum())


def test_movie_beside_measured_video(run, tmp_path, capsys):
    film = tmp_path / "film.mkv"
    fcam = Camera(width_px=160, height_px=80, m_per_px=6e-4, noise_sigma=0, flicker=0,
                  occluder=False, exposure_s=0)
    render_video(bounce_track(25.0, 0.01), film, fcam)  # film.json beside it: fps 2134
    measured = read_frames(film)
    out = tmp_path / "side.gif"
    assert export.main([str(run), "--movie", str(out), "--seconds", "0.03", "--beside",
                        str(film), "--beside-offset-s", "0.001"]) == 0
    err = capsys.readouterr().err
    assert "measured video ends" in err  # 0.01 s of film for 0.03 s asked
    side = json.loads((tmp_path / "side.gif.json").read_text())
    assert side["beside_fps"] == 2134.0 and side["beside_fps_source"] == "film.json"
    shift = round(0.001 * 2134.0)
    cam = export.movie_camera(export.load_run(run))
    w2 = round(160 * cam.height_px / 80)
    im = Image.open(out)
    assert im.n_frames == side["n_frames"] == len(measured) - shift
    assert im.size[0] in (cam.width_px + export.BESIDE_GAP_PX + w2,
                          cam.width_px + export.BESIDE_GAP_PX + w2 + 1)
    assert im.size[1] == cam.height_px
    for j in (0, 7):
        im.seek(j)
        right = np.asarray(im.convert("L"))[:, -w2:]
        want = cv2.resize(measured[j + shift], (w2, cam.height_px),
                          interpolation=cv2.INTER_LINEAR)
        assert np.array_equal(right[25:], want[25:])  # below the time label


def one_error_line(capsys):
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert err[0].startswith("analysis.export: error: ")
    return err[0]


@pytest.mark.parametrize("case", ["missing folder", "no trajectory", "unknown suffix",
                                  "no suffix", "no mode", "foreign movie", "foreign sidecar",
                                  "stl changed"])
def test_bad_input_one_line_exit_2_nothing_left(run, tmp_path, capsys, case):
    out = tmp_path / "new" / "out"
    args = {
        "missing folder": [str(tmp_path / "nope"), "--vtk", str(out)],
        "no trajectory": [str(run), "--movie", str(out) + ".mp4"],
        "unknown suffix": [str(run), "--movie", str(out) + ".avi"],
        "no suffix": [str(run), "--movie", str(out)],
        "no mode": [str(run)],
        "foreign movie": [str(run), "--movie", str(tmp_path / "mine.mp4")],
        "foreign sidecar": [str(run), "--movie", str(tmp_path / "x.gif")],
        "stl changed": [str(run), "--vtk", str(out)],
    }[case]
    if case == "no trajectory":
        (run / "trajectory.csv").unlink()
    elif case == "foreign movie":
        (tmp_path / "mine.mp4").write_bytes(b"someone's film")
    elif case == "foreign sidecar":
        (tmp_path / "x.gif.json").write_text('{"notes": 1}')
    elif case == "stl changed":
        meta = json.loads((run / "meta.json").read_text())
        meta["jar"]["n_facets"] += 2
        (run / "meta.json").write_text(json.dumps(meta))
    before = tree_hash(tmp_path)
    if case == "no mode":  # the argument parser's own error: same line, same code
        with pytest.raises(SystemExit) as ei:
            export.main(args)
        assert ei.value.code == 2
    else:
        assert export.main(args) == 2
    line = one_error_line(capsys)
    assert {"missing folder": "not a recording", "no trajectory": "trajectory.csv",
            "unknown suffix": "'.avi'", "no suffix": "unknown movie format",
            "no mode": "--vtk --movie", "foreign movie": "already exists",
            "foreign sidecar": "sidecar", "stl changed": "STL changed"}[case] in line
    assert tree_hash(tmp_path) == before
    assert not (tmp_path / "new").exists()


def test_failure_while_writing_leaves_nothing(run, tmp_path, capsys, monkeypatch):
    before = tree_hash(tmp_path)
    real = export.movie_frames

    def breaks(*a, **k):
        for i, f in enumerate(real(*a, **k)):
            if i == 5:
                raise RuntimeError("disk full (simulated)")
            yield f

    monkeypatch.setattr(export, "movie_frames", breaks)
    for name in ("a.mp4", "a.gif"):
        assert export.main([str(run), "--movie", str(tmp_path / "new" / "deep" / name),
                            "--seconds", "0.02"]) == 2
        assert "disk full" in one_error_line(capsys)
    calls = []
    real_vtp = export._write_vtp

    def vtp_breaks(poly, path):
        calls.append(path)
        if len(calls) == 9:
            raise OSError("disk full (simulated)")
        real_vtp(poly, path)

    monkeypatch.setattr(export, "_write_vtp", vtp_breaks)
    assert export.main([str(run), "--vtk", str(tmp_path / "new" / "vtk")]) == 2
    assert "disk full" in one_error_line(capsys)
    assert tree_hash(tmp_path) == before  # no movie, no sidecar, no staging folder, no dirs
    assert not (tmp_path / "new").exists()


def test_help_has_units_and_example(capsys):
    with pytest.raises(SystemExit):
        export.main(["--help"])
    h = capsys.readouterr().out
    assert "examples:" in h and "--vtk" in h.split("examples:")[1]
    for unit in ("[frames/s]", "[s]", "SI units"):
        assert unit in h
