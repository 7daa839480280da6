"""Benchmark: frames/s of ball tracking on a synthetic 512x256 video vs the camera's 2134 fps.

Goal: >= 3x real time, i.e. >= 6402 frames/s. Prints decode-only, tracking-only (frames already
in memory) and end-to-end (decode + track) rates, and the per-frame time split.

Run: python -m analysis.bench.tracking [--frames 1067] [--codec GREY]
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

from analysis.synthvideo import CAMERA_FPS, Camera, bounce_track, render_video
from analysis.tracking import read_frames, track_frames, track_video

GOAL_FPS = 3 * CAMERA_FPS


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m analysis.bench.tracking", description=__doc__)
    p.add_argument("--frames", type=int, default=1067, help="video length (default 0.5 s)")
    p.add_argument("--codec", default="GREY", help="GREY (raw, default) or FFV1")
    a = p.parse_args(argv)
    with tempfile.TemporaryDirectory() as td:
        vid = Path(td) / "bench.mkv"
        b = bounce_track(30.0, a.frames / CAMERA_FPS + 0.01)
        t0 = time.perf_counter()
        render_video(b, vid, Camera(), duration_s=(a.frames - 0.5) / CAMERA_FPS,
                     codec=a.codec)
        t_render = time.perf_counter() - t0
        t0 = time.perf_counter()
        frames = read_frames(vid)
        t_dec = time.perf_counter() - t0
        n = len(frames)
        t0 = time.perf_counter()
        res = track_frames(frames, CAMERA_FPS, m_per_px=2e-4, ball_diameter_m=0.0206)
        t_track = time.perf_counter() - t0
        t0 = time.perf_counter()
        track_video(vid, CAMERA_FPS, m_per_px=2e-4, ball_diameter_m=0.0206)
        t_e2e = time.perf_counter() - t0
    print(f"synthetic video: {n} frames, 512x256, codec {a.codec}, rendered in {t_render:.1f} s")
    print(f"camera rate           : {CAMERA_FPS:8.0f} frames/s (goal >= 3x = {GOAL_FPS:.0f})")
    print(f"decode only           : {n / t_dec:8.0f} frames/s ({1e6 * t_dec / n:.0f} us/frame)")
    print(f"tracking only (memory): {n / t_track:8.0f} frames/s ({1e6 * t_track / n:.0f} us/frame)"
          f"  = {n / t_track / CAMERA_FPS:.2f}x real time")
    print(f"end to end            : {n / t_e2e:8.0f} frames/s = {n / t_e2e / CAMERA_FPS:.2f}x "
          f"real time -> goal {'MET' if n / t_e2e >= GOAL_FPS else 'NOT met'}")
    print(f"lost {res.n_lost}, reacquired {res.n_reacquired}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
