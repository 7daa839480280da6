"""A twin run for other eyes: VTK files to open in ParaView, and a movie of the ball in the jar.

Usage::

    python -m analysis.export RUN_DIR --vtk OUT_DIR [--every N]
    python -m analysis.export RUN_DIR --movie OUT.mp4|OUT.gif [--fps F] [--seconds S]
                                      [--beside VIDEO [--beside-fps F] [--beside-offset-s S]]

``RUN_DIR`` is a twin recording (meta.json, trajectory.csv, impacts.csv; the contract is in
docs/reference.md, "Recording", and is read through :func:`analysis.observe.load_recording`). The
jar is the mesh the run used: the run config's ``stl_path`` / ``stl_units`` (defaults from
``yade_scripts/twin_config.py``), read and checked by ``geometry/stl_io.py`` and compared with
meta.json's ``jar`` block, so an STL that changed after the run is an error, not a wrong picture.

VTK (:func:`write_vtk`): lab frame, SI units (m, m/s, rad/s, s). Per written frame ``i`` (every
N-th trajectory row):

* ``ball/ball_<i>.vtp`` - PolyData with one point (the ball centre) and one vertex cell; point
  arrays ``radius_m``, ``velocity_m_s`` and ``angular_velocity_rad_s``; field array ``time_s``.
* ``jar/jar_<i>.vtp`` - PolyData with the jar's triangles (one cell per facet of the mesh),
  moved along x by the frame's ``jar_x_m``; point array ``velocity_m_s`` (jar_vx_m_s, 0, 0);
  field arrays ``time_s``, ``jar_x_m``.
* ``run.pvd`` (ball and jar as parts 0 and 1 of one collection), ``ball.pvd`` and ``jar.pvd``
  (one each, to style them apart in ParaView), each listing the frames with their times [s];
  ``export.json`` says what was exported from where.

The folder is written beside its final place and renamed when complete
(:mod:`analysis.atomic_dir`): it replaces only an earlier output of this project.

Movie (:func:`write_movie`): the ball in the jar as the synthetic high-speed camera of
:mod:`analysis.synthvideo` sees it (looking horizontally across the jar axis: x, the jar axis and
the direction of motion, to the right; z up; lab frame; its renderer, without noise, flicker,
occluder or motion blur), one movie frame per trajectory row of the first ``--seconds`` of the
record, played at ``--fps``. ``--beside VIDEO`` puts a measured video's frames to the right,
scaled to the same height, the measured frame nearest to each movie time (measured time =
movie time since the first frame + ``--beside-offset-s``). MP4 (OpenCV, mp4v) or GIF (Pillow);
grey. Beside ``OUT`` a sidecar ``OUT.json`` (e.g. ``run.mp4.json``) records the source, the
times, the scale and the movie's sha256: an existing ``OUT`` is replaced only when that sidecar
shows it is this command's own earlier output; any other existing file is refused.

Errors (a run folder that is missing or incomplete, a missing trajectory.csv, an unknown movie
suffix, an output this command may not write): one line ``analysis.export: error: ...`` on
stderr, exit code 2, nothing written.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import math
import os
import shutil
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np
import pandas as pd

PROG = "analysis.export"
#: movie formats by file suffix
MOVIE_SUFFIXES = (".mp4", ".gif")
#: default playback rate of the movie [frames/s]; one movie frame per recorded frame
DEFAULT_MOVIE_FPS = 50.0
#: default length of the movie [s of recorded motion]
DEFAULT_MOVIE_SECONDS = 0.2
#: free room around the jar in the movie's field of view [m]
MOVIE_MARGIN_M = 0.005
#: grey gap between the twin's picture and a measured video beside it [px]
BESIDE_GAP_PX = 4
#: what a movie's sidecar says about who wrote it
SIDECAR_WRITER = "analysis.export"


class ExportError(ValueError):
    """The run cannot be exported as asked (the message says why)."""


def _warn(msg: str) -> None:
    print(f"{PROG}: warning: {msg}", file=sys.stderr)


# --------------------------------------------------------------------------------------------
# the run: recording plus the jar mesh it used
# --------------------------------------------------------------------------------------------
@dataclass
class Run:
    """A recording with what it takes to draw it.

    Attributes
    ----------
    path : Path
        The run folder.
    meta : dict
        meta.json.
    trajectory : DataFrame
        trajectory.csv (lab frame, SI).
    ball_radius_m : float
        Ball radius [m].
    jar_triangles_m : ndarray, shape (n, 3, 3)
        The jar's facets at rest (jar_x_m = 0), lab frame [m].
    jar_info : dict
        :func:`geometry.stl_io.check_jar_mesh` of the mesh (inner_length_m, inner_diameter_m,
        n_facets, ...), plus ``stl_path``.
    defaulted : list of str
        Config keys this export took from the declared defaults because meta.json lacks them.
    """

    path: Path
    meta: dict
    trajectory: pd.DataFrame
    ball_radius_m: float
    jar_triangles_m: np.ndarray
    jar_info: dict
    defaulted: list = field(default_factory=list)

    @property
    def run_id(self):
        return self.meta.get("run_id")


def jar_mesh(meta: dict) -> tuple[np.ndarray, dict, list]:
    """The jar mesh a run used: triangles [m], its checked dimensions and the defaulted keys.

    The STL is the run config's ``stl_path`` (relative paths from the repository root) in
    ``stl_units``; keys the config lacks take the defaults declared in ``twin_config``. When
    meta.json holds a ``jar`` block (every twin run does), the mesh's facet count and inner
    length must match it.

    Raises
    ------
    ExportError
        the mesh differs from the one the run recorded (the STL changed since).
    geometry.stl_io.MeshError
        the STL is missing, unreadable or not a closed, inward-oriented jar.
    """
    from analysis.config import REPO_ROOT, twin_config
    from effects import jar_config
    from geometry.jar import mesh_for_config
    given = meta.get("config") or {}
    cfg = twin_config.default_config()
    keys = ("stl_path", "stl_units", "effects") + twin_config.JAR_KEYS
    defaulted = [k for k in ("stl_path", "stl_units") if k not in given]
    cfg.update({k: given[k] for k in keys if k in given})
    path = twin_config.resolve_stl(cfg, str(REPO_ROOT))
    try:
        tri, info, scale = mesh_for_config(jar_config(cfg), path)
    except ValueError as exc:
        raise ExportError(f"parametric jar of the run: {exc}")
    if info.pop("source") == "parametric":
        info["stl_path"] = "parametric"
        path = "parametric jar"
    else:
        info["stl_path"] = (os.path.relpath(path, REPO_ROOT)
                            if Path(path).resolve().is_relative_to(Path(REPO_ROOT).resolve())
                            else str(path))
    rec = meta.get("jar")
    if isinstance(rec, dict):
        if "n_facets" in rec and int(rec["n_facets"]) != info["n_facets"]:
            raise ExportError(f"{path}: {info['n_facets']} facets, but the run recorded "
                              f"{rec['n_facets']}: the STL changed after the run")
        if ("inner_length_m" in rec
                and abs(float(rec["inner_length_m"]) - info["inner_length_m"]) > 1e-6):
            raise ExportError(f"{path}: inner length {info['inner_length_m']:.6g} m, but the "
                              f"run recorded {float(rec['inner_length_m']):.6g} m: the STL "
                              f"changed after the run")
    return tri, info, defaulted


def load_run(run_dir) -> Run:
    """Read a run folder and the jar mesh it used (see :func:`jar_mesh`).

    Raises
    ------
    analysis.observe.ObserveError
        not a recording folder, a missing file or column, a non-numeric value.
    ExportError
        an empty trajectory, or a jar mesh that differs from the recorded one.
    """
    from analysis.config import twin_config
    from analysis.observe import load_recording
    rec = load_recording(Path(run_dir))
    tr = rec.trajectory
    if len(tr) == 0:
        raise ExportError(f"{run_dir}: trajectory.csv has no rows")
    t = tr["t_s"].to_numpy(float)
    if len(t) > 1 and not np.all(np.diff(t) > 0):
        raise ExportError(f"{run_dir}: trajectory.csv times t_s do not increase")
    given = rec.meta.get("config") or {}
    defaulted = []
    if "ball_diameter_m" in given:
        d = float(given["ball_diameter_m"])
    else:
        d = float(twin_config.default_config()["ball_diameter_m"])
        defaulted.append("ball_diameter_m")
    tri, info, jar_def = jar_mesh(rec.meta)
    defaulted += jar_def
    if defaulted:
        _warn(f"{run_dir}: meta.json's config lacks {', '.join(defaulted)}; used the "
              f"declared default(s)")
    return Run(Path(run_dir), rec.meta, tr, 0.5 * d, tri, info, defaulted)


def _missing_folders(folder: Path) -> list[Path]:
    """``folder`` and its ancestors that do not exist yet, innermost first."""
    out = []
    p = Path(folder).absolute()
    while not p.exists():
        out.append(p)
        p = p.parent
    return out


def _remove_empty(folders) -> None:
    """Remove folders this call created (innermost first) when they are still empty."""
    for d in folders:
        try:
            d.rmdir()
        except OSError:
            break


# --------------------------------------------------------------------------------------------
# VTK
# --------------------------------------------------------------------------------------------
def _vtk_array(name: str, values) -> object:
    from vtkmodules.util.numpy_support import numpy_to_vtk
    a = np.ascontiguousarray(values, dtype=np.float64)
    arr = numpy_to_vtk(a, deep=True)
    arr.SetName(name)
    return arr


def _write_vtp(poly, path: Path) -> None:
    from vtkmodules.vtkIOXML import vtkXMLPolyDataWriter
    w = vtkXMLPolyDataWriter()
    w.SetFileName(str(path))
    w.SetInputData(poly)
    w.SetDataModeToBinary()
    if w.Write() != 1:
        raise ExportError(f"{path}: the VTK writer failed")


def _pvd(entries) -> str:
    """ParaView collection: entries are (time_s, part, relative file name)."""
    lines = ['<?xml version="1.0"?>',
             '<VTKFile type="Collection" version="0.1" byte_order="LittleEndian">',
             "  <Collection>"]
    for t, part, name in entries:
        lines.append(f'    <DataSet timestep="{t!r}" group="" part="{part}" '
                     f'file={quoteattr(name)}/>')
    lines += ["  </Collection>", "</VTKFile>", ""]
    return "\n".join(lines)


def _jar_topology(tri_m: np.ndarray):
    """Shared vertices (k, 3) and triangles (n, 3) of a facet soup (n, 3, 3)."""
    verts, inv = np.unique(tri_m.reshape(-1, 3), axis=0, return_inverse=True)
    return verts, inv.reshape(-1, 3)


def write_vtk(run_dir, out_dir, every: int = 1) -> dict:
    """Write a run as VTK PolyData time series plus ParaView collections (see module doc).

    Parameters
    ----------
    run_dir : path-like
        The twin recording.
    out_dir : path-like
        Folder to write; replaces only an earlier output of this project
        (:func:`analysis.atomic_dir.check_out_dir`).
    every : int
        Write every N-th trajectory row (>= 1).

    Returns
    -------
    dict
        What was written (also saved as ``export.json``): n_frames, times, jar facets, ...
    """
    from analysis.atomic_dir import publish_dir, staging_dir
    every = int(every)
    if every < 1:
        raise ExportError(f"--every must be >= 1, got {every}")
    run_dir = Path(run_dir)
    run = load_run(run_dir)
    from vtkmodules.util.numpy_support import numpy_to_vtkIdTypeArray
    from vtkmodules.vtkCommonCore import vtkPoints
    from vtkmodules.vtkCommonDataModel import vtkCellArray, vtkPolyData

    tr = run.trajectory.iloc[::every]
    t = tr["t_s"].to_numpy(float)
    pos = tr[["x_m", "y_m", "z_m"]].to_numpy(float)
    vel = tr[["vx_m_s", "vy_m_s", "vz_m_s"]].to_numpy(float)
    wcols = ["wx_rad_s", "wy_rad_s", "wz_rad_s"]
    omega = tr[wcols].to_numpy(float) if all(c in tr for c in wcols) else None
    jx = tr["jar_x_m"].to_numpy(float)
    jv = tr["jar_vx_m_s"].to_numpy(float)
    verts, tris = _jar_topology(run.jar_triangles_m)
    n_tri = len(tris)
    offsets = np.arange(0, 3 * n_tri + 1, 3, dtype=np.int64)

    made = _missing_folders(Path(out_dir).parent)
    tmp = staging_dir(out_dir, protected=[run_dir], flag="--vtk")
    try:
        (tmp / "ball").mkdir()
        (tmp / "jar").mkdir()
        ball_cells = vtkCellArray()
        ball_cells.SetData(numpy_to_vtkIdTypeArray(np.array([0, 1], np.int64), deep=True),
                           numpy_to_vtkIdTypeArray(np.array([0], np.int64), deep=True))
        jar_cells = vtkCellArray()
        jar_cells.SetData(numpy_to_vtkIdTypeArray(offsets, deep=True),
                          numpy_to_vtkIdTypeArray(tris.astype(np.int64).ravel(), deep=True))
        entries = []
        for i in range(len(t)):
            ball = vtkPolyData()
            pts = vtkPoints()
            pts.SetData(_vtk_array("points", pos[i:i + 1]))
            ball.SetPoints(pts)
            ball.SetVerts(ball_cells)
            ball.GetPointData().AddArray(_vtk_array("radius_m", [run.ball_radius_m]))
            ball.GetPointData().AddArray(_vtk_array("velocity_m_s", vel[i:i + 1]))
            if omega is not None:
                ball.GetPointData().AddArray(_vtk_array("angular_velocity_rad_s",
                                                        omega[i:i + 1]))
            ball.GetFieldData().AddArray(_vtk_array("time_s", [t[i]]))
            bname = f"ball/ball_{i:06d}.vtp"
            _write_vtp(ball, tmp / bname)

            jar = vtkPolyData()
            jpts = vtkPoints()
            jpts.SetData(_vtk_array("points", verts + np.array([jx[i], 0.0, 0.0])))
            jar.SetPoints(jpts)
            jar.SetPolys(jar_cells)
            jvel = np.zeros_like(verts)
            jvel[:, 0] = jv[i]
            jar.GetPointData().AddArray(_vtk_array("velocity_m_s", jvel))
            jar.GetFieldData().AddArray(_vtk_array("time_s", [t[i]]))
            jar.GetFieldData().AddArray(_vtk_array("jar_x_m", [jx[i]]))
            jname = f"jar/jar_{i:06d}.vtp"
            _write_vtp(jar, tmp / jname)
            entries.append((float(t[i]), bname, jname))
        (tmp / "run.pvd").write_text(_pvd([e for t_, b, j in entries
                                           for e in ((t_, 0, b), (t_, 1, j))]))
        (tmp / "ball.pvd").write_text(_pvd([(t_, 0, b) for t_, b, _ in entries]))
        (tmp / "jar.pvd").write_text(_pvd([(t_, 0, j) for t_, _, j in entries]))
        summary = {
            "written_by": SIDECAR_WRITER, "run_dir": str(run_dir.resolve()),
            "run_id": run.run_id, "frame": "lab", "units": "SI (m, m/s, rad/s, s)",
            "every": every, "n_frames": len(t), "t_first_s": float(t[0]),
            "t_last_s": float(t[-1]), "ball_radius_m": run.ball_radius_m,
            "jar_stl_path": run.jar_info["stl_path"], "jar_n_facets": n_tri,
            "jar_inner_length_m": run.jar_info["inner_length_m"],
            "jar_inner_diameter_m": run.jar_info["inner_diameter_m"],
            "jar_motion": "facets moved along x by jar_x_m (the recording holds no other "
                          "jar motion)",
            "defaulted_config_keys": run.defaulted,
            "files": {"collection": "run.pvd (part 0 ball, part 1 jar)",
                      "ball": "ball.pvd, ball/ball_NNNNNN.vtp",
                      "jar": "jar.pvd, jar/jar_NNNNNN.vtp"},
        }
        (tmp / "export.json").write_text(json.dumps(summary, indent=1))
        publish_dir(tmp, out_dir, protected=[run_dir], flag="--vtk")
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        _remove_empty(made)
        raise
    return summary


# --------------------------------------------------------------------------------------------
# movie
# --------------------------------------------------------------------------------------------
def _sha256(path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def sidecar_path(out_path) -> Path:
    """The movie's sidecar: ``OUT`` + ``.json`` (``run.mp4`` -> ``run.mp4.json``)."""
    out_path = Path(out_path)
    return out_path.with_name(out_path.name + ".json")


def _read_sidecar(path: Path):
    try:
        d = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return d if isinstance(d, dict) and d.get("written_by") == SIDECAR_WRITER else None


def is_own_movie(path) -> bool:
    """True when ``path`` is a movie this command wrote (its sidecar names this command and
    holds the file's current sha256), or when ``path`` is that sidecar itself."""
    path = Path(path)
    if path.suffix == ".json" and Path(path.stem).suffix.lower() in MOVIE_SUFFIXES:
        return _read_sidecar(path) is not None
    side = _read_sidecar(sidecar_path(path))
    return bool(side) and path.is_file() and side.get("sha256") == _sha256(path)


def movie_camera(run: Run):
    """The synthetic camera (its default scale, without noise, flicker, occluder or blur),
    its field of view centred on the jar's rest position and wide enough for the jar's whole
    recorded stroke."""
    from analysis.synthvideo import Camera
    base = Camera()
    m = base.m_per_px
    jx = run.trajectory["jar_x_m"].to_numpy(float)
    half_w = (np.max(np.abs(jx)) + 0.5 * run.jar_info["inner_length_m"]
              + base.jar_wall_px * m + MOVIE_MARGIN_M)
    half_h = 0.5 * run.jar_info["inner_diameter_m"] + base.jar_wall_px * m + MOVIE_MARGIN_M
    return Camera(width_px=2 * int(math.ceil(half_w / m)) + 2,
                  height_px=2 * int(math.ceil(half_h / m)) + 2,
                  m_per_px=m, exposure_s=0.0, noise_sigma=0.0, flicker=0.0, occluder=False,
                  jar_inner_diameter_m=run.jar_info["inner_diameter_m"])


def _label(img: np.ndarray, text: str) -> np.ndarray:
    import cv2
    img = np.ascontiguousarray(img)
    cv2.putText(img, text, (6, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4, 255, 1, cv2.LINE_AA)
    return img


def _video_fps(video: Path, cap, beside_fps: float | None) -> tuple[float, str]:
    """Capture rate of a measured video [frames/s] and where it came from."""
    import cv2
    if beside_fps is not None:
        return float(beside_fps), "--beside-fps"
    for side in (video.with_name(video.stem + ".json"), video.parent / "video.json"):
        if side.is_file():
            try:
                fps = float(json.loads(side.read_text())["fps"])
            except (OSError, ValueError, KeyError, TypeError):
                continue
            if fps > 0 and math.isfinite(fps):
                return fps, side.name
    fps = float(cap.get(cv2.CAP_PROP_FPS) or 0.0)
    if not (fps > 0 and math.isfinite(fps)):
        raise ExportError(f"{video}: no frame rate (no video.json / {video.stem}.json beside "
                          f"it and none in the file); give --beside-fps")
    _warn(f"{video}: frame rate {fps:g}/s taken from the file itself; high-speed cameras "
          f"often store a playback rate there - give --beside-fps if it is not the capture "
          f"rate")
    return fps, "container"


def movie_frames(run: Run, cam, t_s: np.ndarray, beside=None, beside_fps=None,
                 beside_offset_s: float = 0.0, info: dict | None = None):
    """Grey movie frames (uint8, all the same size) for the frame times ``t_s`` [s].

    The twin's picture comes from :func:`analysis.synthvideo.render_frames` with the time
    written in the corner; with ``beside`` (a video file) each frame gets the measured frame
    nearest to ``t - t_s[0] + beside_offset_s`` to its right, scaled to the same height. The
    stream stops early when the measured video ends (``info['stopped_early']``). ``info``
    (a dict) receives what was used: the measured frame rate and its source, the frame size.
    """
    import cv2
    from analysis.synthvideo import render_frames
    info = {} if info is None else info
    tr = run.trajectory
    t_all = tr["t_s"].to_numpy(float)
    x_all = tr["x_m"].to_numpy(float)
    z_all = tr["z_m"].to_numpy(float)
    jx_all = tr["jar_x_m"].to_numpy(float)
    twin = render_frames(lambda tt: (np.interp(tt, t_all, x_all), np.interp(tt, t_all, z_all)),
                         lambda tt: np.interp(tt, t_all, jx_all), cam, 2 * run.ball_radius_m,
                         run.jar_info["inner_length_m"], t_s=t_s, frame="lab")
    if beside is None:
        info["size"] = (cam.width_px, cam.height_px)
        for t, img in zip(t_s, twin):
            yield _label(img, f"twin  t = {t:.5f} s")
        return
    from analysis.tracking import iter_gray, open_video
    video = Path(beside)
    cap = open_video(video)
    try:
        fps, src = _video_fps(video, cap, beside_fps)
        info["beside_fps"], info["beside_fps_source"] = fps, src
        frames = iter_gray(cap)
        k_have, cur = -1, None
        scale = None
        for t, img in zip(t_s, twin):
            tau = (t - t_s[0]) + beside_offset_s
            k = int(round(tau * fps))
            while k_have < k:
                cur = next(frames, None)
                if cur is None:
                    break
                k_have += 1
            if cur is None:
                if k_have < 0:
                    raise ExportError(f"{video}: no decodable frame")
                info["stopped_early"] = float(t)
                info["beside_n_frames"] = k_have + 1
                return
            if scale is None:
                scale = cam.height_px / cur.shape[0]
                w2 = max(1, int(round(cur.shape[1] * scale)))
                total = cam.width_px + BESIDE_GAP_PX + w2
                pad = total % 2  # even sizes for the video codec
                info["size"] = (total + pad, cam.height_px)
            meas = cv2.resize(cur, (w2, cam.height_px),
                              interpolation=cv2.INTER_AREA if scale < 1 else cv2.INTER_LINEAR)
            gap = np.full((cam.height_px, BESIDE_GAP_PX + pad), 128, np.uint8)
            yield np.hstack([_label(img, f"twin  t = {t:.5f} s"), gap,
                             _label(meas, f"measured  t = {k / fps:.5f} s")])
    finally:
        cap.release()


def _write_gif(path: Path, frames, fps: float) -> int:
    """Grey frames -> animated GIF (Pillow). GIF delays are whole 1/100 s; identical
    consecutive frames would be merged by Pillow (the time label keeps them distinct)."""
    from PIL import Image
    it = iter(frames)
    first = next(it, None)
    if first is None:
        raise ExportError(f"{path}: no frames to write")
    count = [1]

    def rest():
        for f in it:
            count[0] += 1
            yield Image.fromarray(f)

    Image.fromarray(first).save(path, format="GIF", save_all=True, append_images=rest(),
                                duration=1000.0 / fps, loop=0)
    return count[0]


def write_movie(run_dir, out_path, fps: float = DEFAULT_MOVIE_FPS,
                seconds: float = DEFAULT_MOVIE_SECONDS, beside=None, beside_fps=None,
                beside_offset_s: float = 0.0) -> dict:
    """Render the first ``seconds`` of a run (one frame per trajectory row) to MP4 or GIF.

    Parameters
    ----------
    run_dir : path-like
        The twin recording.
    out_path : path-like
        ``.mp4`` (OpenCV, mp4v) or ``.gif`` (Pillow). An existing file is replaced only when it
        is this command's earlier output (:func:`is_own_movie`); the sidecar ``OUT.json``
        is written beside it.
    fps : float
        Playback rate [frames/s].
    seconds : float
        Recorded time to show [s], from the first trajectory row.
    beside : path-like, optional
        A measured video shown to the right.
    beside_fps : float, optional
        Its capture rate [frames/s] (default: ``video.json`` or ``<stem>.json`` beside it,
        else the file's own rate, with a warning).
    beside_offset_s : float
        Measured time [s] shown with the movie's first frame (>= 0).

    Returns
    -------
    dict
        The sidecar's content (n_frames, size, times, slow-motion factor, ...).
    """
    from analysis.atomic_dir import check_out_file
    out_path = Path(out_path)
    suffix = out_path.suffix.lower()
    if suffix not in MOVIE_SUFFIXES:
        raise ExportError(f"{out_path}: unknown movie format {out_path.suffix or '(none)'!r}; "
                          f"use {' or '.join(MOVIE_SUFFIXES)}")
    if not (fps > 0 and math.isfinite(fps)):
        raise ExportError(f"--fps must be a positive number, got {fps}")
    if not (seconds > 0 and math.isfinite(seconds)):
        raise ExportError(f"--seconds must be a positive number, got {seconds}")
    if beside_fps is not None and not (beside_fps > 0 and math.isfinite(beside_fps)):
        raise ExportError(f"--beside-fps must be a positive number, got {beside_fps}")
    if not (beside_offset_s >= 0 and math.isfinite(beside_offset_s)):
        raise ExportError(f"--beside-offset-s must be >= 0, got {beside_offset_s}")
    run_dir = Path(run_dir)
    protected = [run_dir] + ([Path(beside)] if beside is not None else [])
    side_path = sidecar_path(out_path)
    check_out_file(out_path, protected, is_own_movie, flag="--movie")
    check_out_file(side_path, protected, is_own_movie, flag="--movie's sidecar")
    if beside is not None and not Path(beside).is_file():
        raise ExportError(f"--beside {beside}: no such video file")
    run = load_run(run_dir)
    t_all = run.trajectory["t_s"].to_numpy(float)
    t0 = float(t_all[0])
    t_s = t_all[t_all <= t0 + seconds * (1 + 1e-9)]
    if t_all[-1] < t0 + seconds * (1 - 1e-9):
        _warn(f"{run_dir}: the record holds {t_all[-1] - t0:.4g} s, less than --seconds "
              f"{seconds:g}; the movie shows all of it")
    if len(t_s) < 2:
        raise ExportError(f"{run_dir}: fewer than 2 recorded frames in the first {seconds:g} s")
    rec_fps = 1.0 / float(np.median(np.diff(t_all))) if len(t_all) > 1 else float("nan")
    cam = movie_camera(run)
    info: dict = {}
    frames = movie_frames(run, cam, t_s, beside, beside_fps, beside_offset_s, info)

    # write beside the target (same file system), rename when complete
    parent = out_path.parent
    made = _missing_folders(parent)
    work = None
    try:
        parent.mkdir(parents=True, exist_ok=True)
        work = Path(tempfile.mkdtemp(prefix=f".{out_path.name}.tmp-", dir=parent))
        tmp_movie = work / out_path.name
        if suffix == ".gif":
            n = _write_gif(tmp_movie, frames, fps)
            gif_fps = 100.0 / max(1, round(100.0 / fps))
            if abs(gif_fps / fps - 1) > 0.01:
                _warn(f"GIF stores frame delays in 1/100 s: --fps {fps:g} plays at "
                      f"{gif_fps:g} frames/s")
        else:
            from analysis.synthvideo import write_video
            first = next(frames, None)
            if first is None:
                raise ExportError(f"{out_path}: no frames to write")
            size = (first.shape[1], first.shape[0])
            n = write_video(tmp_movie, _chain(first, frames), fps, size, codec="mp4v")
        if "stopped_early" in info:
            _warn(f"--beside {beside}: the measured video ends after "
                  f"{info['beside_n_frames']} frames; the movie stops there, at t = "
                  f"{t_s[n - 1]:.5f} s ({n} frames)")
        width, height = info["size"]
        side = {
            "written_by": SIDECAR_WRITER, "movie": out_path.name,
            "run_dir": str(run_dir.resolve()), "run_id": run.run_id, "frame": "lab",
            "view": "horizontal, across the jar axis: x (jar axis, motion) right, z up",
            "n_frames": n, "width_px": width, "height_px": height,
            "m_per_px": cam.m_per_px, "playback_fps": fps,
            "recorded_fps": rec_fps, "slow_motion_factor": rec_fps / fps,
            "t_first_s": float(t_s[0]), "t_last_s": float(t_s[n - 1]),
            "beside": str(Path(beside).resolve()) if beside is not None else None,
            "beside_fps": info.get("beside_fps"),
            "beside_fps_source": info.get("beside_fps_source"),
            "beside_offset_s": beside_offset_s if beside is not None else None,
            "defaulted_config_keys": run.defaulted,
            "sha256": _sha256(tmp_movie),
        }
        (work / side_path.name).write_text(json.dumps(side, indent=1))
        # check again right before replacing anything
        check_out_file(out_path, protected, is_own_movie, flag="--movie")
        check_out_file(side_path, protected, is_own_movie, flag="--movie's sidecar")
        os.replace(tmp_movie, out_path)
        os.replace(work / side_path.name, side_path)
    except BaseException:
        if work is not None:
            shutil.rmtree(work, ignore_errors=True)
        _remove_empty(made)
        raise
    shutil.rmtree(work, ignore_errors=True)
    return side


def _chain(first, rest):
    yield first
    yield from rest


# --------------------------------------------------------------------------------------------
# command line
# --------------------------------------------------------------------------------------------
class _Parser(argparse.ArgumentParser):
    """argparse with one error line (``analysis.export: error: ...``) and exit code 2."""

    def error(self, message):
        print(f"{PROG}: error: {message}", file=sys.stderr)
        sys.exit(2)


def build_parser() -> argparse.ArgumentParser:
    from analysis.config import twin_config
    from analysis.synthvideo import Camera
    rec_fps = float(twin_config.default_config()["output_fps"])  # the twin's recorded rate
    mm_per_px = Camera().m_per_px * 1e3
    slow = rec_fps / DEFAULT_MOVIE_FPS
    p = _Parser(
        prog="python -m analysis.export",
        description="Export a twin run (a results/runs/<run-id> folder):\n"
                    "  --vtk: VTK files to open in ParaView - the ball as a point series with\n"
                    "    radius_m, velocity_m_s, angular_velocity_rad_s; the jar's facets at\n"
                    "    their recorded position; lab frame, SI units (m, m/s, rad/s, s);\n"
                    "  --movie: a movie of the ball in the jar (the high-speed camera's side\n"
                    f"    view, lab frame, {mm_per_px:g} mm/px), optionally beside a measured\n"
                    "    video.",
        epilog="examples:\n"
               "  python -m analysis.export results/runs/<run-id> --vtk results/vtk/run1 "
               "--every 2\n"
               "  python -m analysis.export results/runs/<run-id> --movie "
               "results/movies/run1.mp4 --seconds 0.1 --fps 50\n"
               "  python -m analysis.export results/runs/<run-id> --movie "
               "results/movies/run1_vs_film.gif --beside film.mkv --beside-fps 2134",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("run_dir", metavar="RUN_DIR", help="twin recording folder (meta.json, "
                   "trajectory.csv, impacts.csv)")
    what = p.add_mutually_exclusive_group(required=True)
    what.add_argument("--vtk", metavar="OUT_DIR", help="write VTK files into this folder "
                      "(run.pvd, ball.pvd, jar.pvd, ball/*.vtp, jar/*.vtp, export.json)")
    what.add_argument("--movie", metavar="OUT", help="write a movie: OUT.mp4 (mp4v) or "
                      "OUT.gif; a sidecar OUT.json goes beside it")
    p.add_argument("--every", type=int, metavar="N", help="VTK: write every N-th recorded "
                   f"frame [frames] (default 1: all of them, {rec_fps:g} per s of record)")
    p.add_argument("--fps", type=float, metavar="F", help="movie: playback rate [frames/s] "
                   f"(default {DEFAULT_MOVIE_FPS:g}); every recorded frame is shown, so at "
                   f"the twin's {rec_fps:g} recorded frames/s the default slows the motion "
                   f"{slow:.3g}x: 0.1 s of motion plays for {0.1 * slow:.2g} s")
    p.add_argument("--seconds", type=float, metavar="S", help="movie: recorded time to show "
                   f"[s] from the start of the record (default {DEFAULT_MOVIE_SECONDS:g})")
    p.add_argument("--beside", metavar="VIDEO", help="movie: a measured video to show to the "
                   "right, frame nearest to each movie time, scaled to the same height")
    p.add_argument("--beside-fps", type=float, metavar="F", help="movie: the measured video's "
                   "capture rate [frames/s] (default: 'fps' of video.json or <stem>.json "
                   "beside it, else the file's own rate)")
    p.add_argument("--beside-offset-s", type=float, default=None, metavar="S",
                   help="movie: measured time [s] shown with the first movie frame (default 0)")
    return p


def main(argv=None) -> int:
    p = build_parser()
    a = p.parse_args(argv)
    movie_opts = {"--fps": a.fps, "--seconds": a.seconds, "--beside": a.beside,
                  "--beside-fps": a.beside_fps, "--beside-offset-s": a.beside_offset_s}
    try:
        if a.vtk is not None:
            given = [k for k, v in movie_opts.items() if v is not None]
            if given:
                raise ExportError(f"{', '.join(given)} "
                                      f"{'applies' if len(given) == 1 else 'apply'} only to "
                                      f"--movie")
            s = write_vtk(a.run_dir, a.vtk, every=1 if a.every is None else a.every)
            print(f"{a.vtk}: {s['n_frames']} frames (t = {s['t_first_s']:.6g} to "
                  f"{s['t_last_s']:.6g} s), jar of {s['jar_n_facets']} facets; open "
                  f"{Path(a.vtk) / 'run.pvd'} in ParaView")
        else:
            if a.every is not None:
                raise ExportError("--every only applies to --vtk")
            if a.beside is None:
                given = [k for k in ("--beside-fps", "--beside-offset-s")
                         if movie_opts[k] is not None]
                if given:
                    raise ExportError(f"{', '.join(given)} "
                                      f"{'applies' if len(given) == 1 else 'apply'} only "
                                      f"with --beside")
            s = write_movie(a.run_dir, a.movie,
                            fps=DEFAULT_MOVIE_FPS if a.fps is None else a.fps,
                            seconds=DEFAULT_MOVIE_SECONDS if a.seconds is None else a.seconds,
                            beside=a.beside, beside_fps=a.beside_fps,
                            beside_offset_s=a.beside_offset_s or 0.0)
            print(f"{a.movie}: {s['n_frames']} frames {s['width_px']}x{s['height_px']} px "
                  f"(t = {s['t_first_s']:.6g} to {s['t_last_s']:.6g} s) at "
                  f"{s['playback_fps']:g} frames/s, {s['slow_motion_factor']:.3g}x slower "
                  f"than real time")
    except (ValueError, RuntimeError, OSError) as exc:
        msg = " ".join(str(exc).split())  # one line
        print(f"{PROG}: error: {msg}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
