"""Follow one ball (and the jar) through a high-speed video: video -> track CSV (t_s, x_m, y_m,
quality [, jar_x_m]).

The package, bottom to top (each module imports only the ones above it in this list):

* :mod:`~analysis.tracking.errors` - the exceptions (:class:`TrackingError` and its kinds);
* :mod:`~analysis.tracking.video` - open a film for grey frames, decode ahead in a thread, the
  frame rate it declares (sidecar or container) checked against a given one;
* :mod:`~analysis.tracking.jar` - the jar by its two end walls (``jar_x_m``);
* :mod:`~analysis.tracking.ball` - the ball tracker (Hough detection, MOSSE, sub-pixel rim fit;
  the method is described there), :func:`track_video`;
* :mod:`~analysis.tracking.cli` - :func:`write_track` and the command line
  (``python -m analysis.tracking VIDEO [--jar] --out track.csv``).

Every public name is re-exported here: import from ``analysis.tracking``.
"""
from analysis.tracking.errors import (BallNotFoundError, FpsMismatchError, JarNotFoundError,
                                      TrackingError, VideoReadError)
from analysis.tracking.video import (FPS_TOLERANCE, check_fps, declared_fps, decode_ahead,
                                     iter_gray, open_video, read_frames)
from analysis.tracking.jar import jar_band, track_jar, track_jar_video
from analysis.tracking.ball import (MOSSE_BOX_RADII, RIM_METHODS, BandRim, TrackerSettings,
                                    TrackResult, detect_ball, refine_centre, track_frames,
                                    track_video, window_level)
from analysis.tracking.cli import main, write_track

#: The old private name of :class:`BandRim` (tests import it).
_BandRim = BandRim

__all__ = [
    "BallNotFoundError", "FpsMismatchError", "JarNotFoundError", "TrackingError",
    "VideoReadError",
    "FPS_TOLERANCE", "check_fps", "declared_fps", "decode_ahead", "iter_gray", "open_video",
    "read_frames",
    "jar_band", "track_jar", "track_jar_video",
    "MOSSE_BOX_RADII", "RIM_METHODS", "BandRim", "TrackerSettings", "TrackResult", "detect_ball",
    "refine_centre", "track_frames", "track_video", "window_level",
    "main", "write_track",
]
