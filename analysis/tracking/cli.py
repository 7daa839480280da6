"""The command line of :mod:`analysis.tracking` (``python -m analysis.tracking``): a video ->
the ball's (and with ``--jar`` the jar's) track CSV."""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import pandas as pd

from analysis.tracking.ball import RIM_METHODS, TrackerSettings, track_video
from analysis.tracking.errors import FpsMismatchError, TrackingError
from analysis.tracking.video import FPS_TOLERANCE, check_fps


def write_track(track: pd.DataFrame, out) -> Path:
    """Write a track CSV atomically (temp file, then rename)."""
    from analysis.atomic_dir import atomic_file
    out = Path(out)
    with atomic_file(out) as tmp:
        track.to_csv(tmp, index=False)
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m analysis.tracking",
                                description="Track one ball in a high-speed video -> track CSV "
                                            "(t_s, x_m, y_m, quality, x_px, y_px, r_px "
                                            "[, jar_x_m]).",
                                epilog="example: python -m analysis.tracking film.mkv --fps 2134 "
                                       "--ball-diameter-mm 20.6 --out track.csv")
    p.add_argument("video")
    p.add_argument("--fps", type=float, default=None,
                   help="frame rate [1/s] (default: the sidecar's, else the container's); "
                        f"refused when more than {100 * FPS_TOLERANCE:g} %% from the rate the "
                        "file declares, unless --force-fps")
    p.add_argument("--force-fps", action="store_true",
                   help="track at --fps even when the file declares another rate (warns)")
    p.add_argument("--ball-diameter-mm", type=float, default=None,
                   help="real ball diameter [mm]; the scale comes from its size in pixels")
    p.add_argument("--m-per-px", type=float, default=None,
                   help="scale [m/px], overrides the ball size")
    p.add_argument("--rim-method", choices=RIM_METHODS, default=TrackerSettings.rim_method,
                   help="sub-pixel rim points: 'band' (default, fast), 'crossings' (scan of the "
                        "whole window, the earlier default), 'contour' (OpenCV contours)")
    p.add_argument("--mosse-every", type=int, default=TrackerSettings.mosse_every,
                   help="update MOSSE on every this-many-th frame [frames] (default %(default)s)")
    p.add_argument("--jar", action="store_true",
                   help="also follow the jar by its end walls (lab-frame video): column jar_x_m, "
                        "for the impact observables (python -m analysis.flights)")
    p.add_argument("--jar-band", type=int, nargs=2, metavar=("ROW0", "ROW1"), default=None,
                   help="image rows [px] where the jar's end walls are followed (default: "
                        "found, just inside the jar's bottom wall)")
    p.add_argument("--out", required=True, help="track CSV to write")
    a = p.parse_args(argv)
    try:
        if a.fps is not None and a.force_fps and math.isfinite(a.fps) and a.fps > 0:
            forced = check_fps(a.video, a.fps)
            if forced is not None:
                print(f"analysis.tracking: warning: {forced}; tracking at {a.fps:g} fps as "
                      "--force-fps asks", file=sys.stderr)
        res = track_video(a.video, a.fps,
                          ball_diameter_m=None if a.ball_diameter_mm is None
                          else a.ball_diameter_mm * 1e-3, m_per_px=a.m_per_px,
                          settings=TrackerSettings(rim_method=a.rim_method,
                                                   mosse_every=a.mosse_every),
                          jar=a.jar or a.jar_band is not None,
                          jar_band_rows=None if a.jar_band is None else tuple(a.jar_band),
                          force_fps=a.force_fps)
        write_track(res.track, a.out)
    except FpsMismatchError as exc:
        print(f"analysis.tracking: error: {exc}; leave out --fps to use {exc.declared_fps:g}, "
              f"or add --force-fps to track at {exc.given_fps:g} anyway", file=sys.stderr)
        return 2
    except (TrackingError, OSError) as exc:
        print(f"analysis.tracking: error: {exc}", file=sys.stderr)
        return 2
    print(f"{a.out}: {res.n_frames} frames, {res.n_lost} lost, {res.n_reacquired} reacquired, "
          f"scale {res.m_per_px * 1e3:.5f} mm/px ({res.scale_source}, ball "
          f"{res.ball_diameter_px:.2f} px), {res.n_frames / res.wall_s:.0f} frames/s")
    if "jar" in res.params:
        j = res.params["jar"]
        print(f"jar: end walls followed in rows {j['band_rows'][0]}-{j['band_rows'][1]}, "
              f"{j['length_px']:.2f} px apart, {j['n_lost']} frame(s) lost")
    return 0
