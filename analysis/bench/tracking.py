"""Benchmark: frames/s of ball tracking on a synthetic 512x256 video vs the camera's 2134 fps.

Goal: >= 3x real time, i.e. >= 6402 frames/s, end to end (decode + track, as
:func:`analysis.tracking.track_video` runs). Prints decode-only rates, then tracking-only (frames
already in memory) and end-to-end rates for the default ('band' rim fit, MOSSE every 4th frame)
and the alternatives: 'band' with MOSSE on every frame, 'crossings' with MOSSE on every frame
(the earlier default) and 'contour'; with each one's tracking error against the ground truth and
the machine's load average before and after (other jobs slow every figure; compare the rows of
one run).

Run: python -m analysis.bench.tracking [--frames 1067] [--codec GREY]
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from analysis.synthvideo import CAMERA_FPS, Camera, bounce_track, render_video
from analysis.tracking import (TrackerSettings, decode_ahead, open_video, read_frames,
                               track_frames, track_video)

GOAL_FPS = 3 * CAMERA_FPS


def _best(fn, reps):
    """Best wall time of ``reps`` calls, and the best CPU time of this process (all threads)."""
    best = cpu = float("inf")
    out = None
    for _ in range(reps):
        t0, c0 = time.perf_counter(), time.process_time()
        out = fn()
        best = min(best, time.perf_counter() - t0)
        cpu = min(cpu, time.process_time() - c0)
    return best, out, cpu


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m analysis.bench.tracking", description=__doc__,
                                epilog="example: python -m analysis.bench.tracking --frames 1067 "
                                       "--codec GREY",
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--frames", type=int, default=1067,
                   help="video length [frames] (default %(default)s: 0.5 s at 2134 fps)")
    p.add_argument("--codec", default="GREY", help="GREY (raw, default) or FFV1")
    p.add_argument("--reps", type=int, default=3,
                   help="repeats; the best is reported [repeats] (default %(default)s)")
    a = p.parse_args(argv)
    with tempfile.TemporaryDirectory() as td:
        vid = Path(td) / "bench.mkv"
        b = bounce_track(30.0, a.frames / CAMERA_FPS + 0.01)
        t0 = time.perf_counter()
        truth = render_video(b, vid, Camera(), duration_s=(a.frames - 0.5) / CAMERA_FPS,
                             codec=a.codec)
        t_render = time.perf_counter() - t0
        t_dec, frames, _ = _best(lambda: read_frames(vid), a.reps)
        n = len(frames)

        def decode_ring():
            cap = open_video(vid)
            try:
                return sum(1 for _ in decode_ahead(cap))
            finally:
                cap.release()

        t_ring, n_ring, c_ring = _best(decode_ring, a.reps)
        assert n_ring == n
        print(f"synthetic video: {n} frames, 512x256, codec {a.codec}, rendered in "
              f"{t_render:.1f} s; load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} "
              f"CPUs")
        print(f"camera rate           : {CAMERA_FPS:8.0f} frames/s (goal >= 3x = {GOAL_FPS:.0f})")
        print(f"decode only, to a list: {n / t_dec:8.0f} frames/s ({1e6 * t_dec / n:.0f} us/frame)")
        print(f"decode only, ring     : {n / t_ring:8.0f} frames/s ({1e6 * t_ring / n:.0f} us/frame,"
              f" CPU {1e6 * c_ring / n:.0f} us/frame; track_video's reader: background thread, "
              f"preallocated buffers)")
        print("rates in frames/s (x real time); CPU = CPU time per frame of all threads, less "
              "sensitive to other jobs than the rates")
        cases = [("band", 4, "default"), ("band", 1, ""), ("crossings", 1, "earlier default"),
                 ("contour", 4, "")]
        verdict = None
        for method, every, note in cases:
            st = TrackerSettings(rim_method=method, mosse_every=every)
            t_tr, res, c_tr = _best(lambda: track_frames(frames, CAMERA_FPS, m_per_px=2e-4,
                                                         ball_diameter_m=0.0206, settings=st),
                                    a.reps)
            t_e2e, _, c_e2e = _best(lambda: track_video(vid, CAMERA_FPS, m_per_px=2e-4,
                                                        ball_diameter_m=0.0206, settings=st),
                                    a.reps)
            err = np.hypot(res.track.x_px - truth.x_px, res.track.y_px - truth.y_px)
            label = f"{method}, MOSSE 1/{every}"
            print(f"[{label:20s}] tracking only {n / t_tr:6.0f} ({n / t_tr / CAMERA_FPS:.2f}x, "
                  f"CPU {1e6 * c_tr / n:3.0f} us); end to end {n / t_e2e:6.0f} "
                  f"({n / t_e2e / CAMERA_FPS:.2f}x, CPU {1e6 * c_e2e / n:3.0f} us); "
                  f"RMS error {np.sqrt(np.nanmean(err ** 2)):.3f} px, lost {res.n_lost}"
                  + (f" ({note})" if note else ""))
            if verdict is None:
                verdict = (n / t_e2e, n / c_e2e)
        load = os.getloadavg()[0]
        print(f"goal (default, end to end >= {GOAL_FPS:.0f} frames/s): "
              f"{'MET' if verdict[0] >= GOAL_FPS else 'NOT met'} at {verdict[0]:.0f} frames/s, "
              f"load average {load:.1f} at the end; its CPU time alone allows "
              f"{verdict[1]:.0f} frames/s ({verdict[1] / CAMERA_FPS:.2f}x) on one free core")
    return 0


if __name__ == "__main__":
    sys.exit(main())
