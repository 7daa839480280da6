"""A dataset's films -> tracks: what the loop does with ``videos/`` (ball and jar, cached).

A measurement dataset may bring high-speed films instead of tracks (``videos/<condition_id>.*``
with ``videos/video.json``: fps, and m_per_px or ball_diameter_px). :func:`track_dataset_videos`
follows the ball and, in a lab-frame film, the jar (:func:`analysis.tracking.track_video` with
``jar=True``) in every film whose condition has no track, with a progress bar, and returns the
tracks (t_s, x_m, y_m [, jar_x_m]) and a quality table: frames, lost frames, re-acquisitions,
the scale and where it came from, the jar's lost frames. A track is cached under the film's
content hash (``cache_dir/<sha>.csv``), so a rerun of the loop does not track again.
"""
from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pandas as pd

QUALITY_COLUMNS = ["condition_id", "video", "sha256", "fps", "n_frames", "n_lost",
                   "n_reacquired", "m_per_px", "scale_source", "ball_diameter_px",
                   "jar_n_lost", "cached"]


def file_hash(path, chunk=1 << 20) -> str:
    """sha256 of a file's bytes (first 16 hex digits)."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        while True:
            b = fh.read(chunk)
            if not b:
                break
            h.update(b)
    return h.hexdigest()[:16]


def check_films(dataset) -> None:
    """Open every film the loop would track (a condition without a track) and decode its first
    frame: an unreadable or empty film is one VideoReadError naming the file before any
    tracking or twin run, not after the films before it were tracked."""
    from analysis.tracking.errors import VideoReadError
    from analysis.tracking.video import iter_gray, open_video
    for cid, f in sorted(dataset.video_files.items()):
        if cid in dataset.tracks:
            continue
        cap = open_video(f)
        try:
            if next(iter_gray(cap), None) is None:
                raise VideoReadError("%s: no decodable frame (empty or corrupt video)" % f)
        finally:
            cap.release()


def track_dataset_videos(dataset, cache_dir=None, progress=True, force=False):
    """Track every film of ``dataset`` whose condition has no track.

    Parameters
    ----------
    dataset : analysis.measurements.Dataset (with ``video`` and ``video_files``)
    cache_dir : path-like or None - where tracks are cached by film hash (None: no cache)
    progress : bool - a tqdm bar over the films
    force : bool - track again even when cached

    Returns
    -------
    tracks : dict condition_id -> DataFrame (t_s, x_m, y_m [, jar_x_m])
    quality : DataFrame (:data:`QUALITY_COLUMNS`)

    Raises
    ------
    analysis.tracking.TrackingError
        a film that cannot be read or followed (the message names the file)
    """
    from tqdm.auto import tqdm
    from analysis.tracking import track_video
    todo = {cid: Path(f) for cid, f in sorted(dataset.video_files.items())
            if cid not in dataset.tracks}
    meta = dict(dataset.video or {})
    conds = dataset.conditions.set_index("condition_id")
    jar = dataset.velocity_frame == "lab"
    cache = Path(cache_dir) if cache_dir is not None else None
    tracks, rows = {}, []
    for cid, f in tqdm(todo.items(), desc="tracking films", unit="film", disable=not progress):
        sha = file_hash(f)
        hit = cache / ("%s.csv" % sha) if cache is not None else None
        qfile = cache / ("%s.json" % sha) if cache is not None else None
        if hit is not None and hit.exists() and qfile.exists() and not force:
            tr = pd.read_csv(hit)
            q = json.loads(qfile.read_text())
            q["cached"] = True
        else:
            ball_m = (None if "m_per_px" in meta
                      else float(conds.loc[cid, "ball_diameter_mm"]) * 1e-3)
            res = track_video(f, float(meta["fps"]), ball_diameter_m=ball_m,
                              m_per_px=meta.get("m_per_px"), jar=jar)
            cols = ["t_s", "x_m", "y_m"] + (["jar_x_m"] if "jar_x_m" in res.track else [])
            tr = res.track[cols]
            q = {"condition_id": cid, "video": f.name, "sha256": sha, "fps": res.fps,
                 "n_frames": res.n_frames, "n_lost": res.n_lost,
                 "n_reacquired": res.n_reacquired, "m_per_px": res.m_per_px,
                 "scale_source": res.scale_source, "ball_diameter_px": res.ball_diameter_px,
                 "jar_n_lost": res.params.get("jar", {}).get("n_lost"), "cached": False}
            if cache is not None:
                cache.mkdir(parents=True, exist_ok=True)
                tmp = hit.with_suffix(".tmp")
                tr.to_csv(tmp, index=False)
                tmp.replace(hit)
                qfile.write_text(json.dumps(q, default=float))
        q["condition_id"] = cid
        tracks[cid] = tr
        rows.append(q)
    return tracks, pd.DataFrame(rows, columns=QUALITY_COLUMNS)
