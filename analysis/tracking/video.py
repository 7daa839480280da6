"""Video input for the trackers: open a film for grey frames, read or decode them ahead in a
background thread, and the frame rate it declares (a ``<stem>.json`` / ``video.json`` sidecar,
else the container) checked against a given one (:data:`FPS_TOLERANCE`).
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from analysis.tracking.errors import FpsMismatchError, TrackingError, VideoReadError


#: Largest relative difference between a given frame rate and the one the file declares
#: (:func:`declared_fps`) that is accepted without ``force_fps``.
FPS_TOLERANCE = 0.01


def load_cv2():
    """The cv2 module, imported on first use (importing the package does not load OpenCV)."""
    import cv2
    return cv2


def open_video(path):
    """Open a video for grey frames; raises VideoReadError for missing / unreadable files."""
    cv2 = load_cv2()
    try:
        cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)
    except AttributeError:  # pragma: no cover - older OpenCV
        pass
    path = Path(path)
    if not path.is_file():
        raise VideoReadError(f"{path}: no such video file")
    if path.stat().st_size == 0:
        raise VideoReadError(f"{path}: empty file")
    params = [cv2.CAP_PROP_CONVERT_RGB, 0]
    if hasattr(cv2, "CAP_PROP_N_THREADS"):
        # one FFmpeg thread: raw grey decodes in ~30 instead of ~45 us/frame of CPU (the default
        # thread pool only adds hand-overs); FFV1 is no faster with threads either
        params += [cv2.CAP_PROP_N_THREADS, 1]
    cap = cv2.VideoCapture(str(path), cv2.CAP_FFMPEG, params)
    if not cap.isOpened():
        cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        raise VideoReadError(f"{path}: OpenCV cannot open it (unreadable or corrupt video)")
    return cap


def iter_gray(cap):
    """Yield grey uint8 frames from an open capture."""
    cv2 = load_cv2()
    while True:
        ok, f = cap.read()
        if not ok or f is None:
            return
        if f.ndim == 3:
            f = cv2.cvtColor(f, cv2.COLOR_BGR2GRAY)
        elif f.dtype != np.uint8:
            f = cv2.convertScaleAbs(f)
        yield f


def read_frames(path) -> list[np.ndarray]:
    """All grey frames of a video (for benchmarks and small tests)."""
    cap = open_video(path)
    try:
        frames = list(iter_gray(cap))
    finally:
        cap.release()
    if not frames:
        raise VideoReadError(f"{path}: no decodable frame (empty or corrupt video)")
    return frames


def read_sidecar(path: Path):
    """The video's sidecar and its contents: ``<stem>.json``, else a measurement dataset's
    ``videos/video.json`` (DESIGN.md) beside it; (None, {}) when there is none."""
    import json
    side = path.with_name(path.stem + ".json")
    if not side.is_file():
        side = path.with_name("video.json")
    if not side.is_file():
        return None, {}
    from analysis.config import twin_config
    try:     # the one strict reader: a key written twice is refused, a byte-order mark ignored
        meta = twin_config.strict_json_loads(side.read_text(encoding="utf-8"))
    except twin_config.DuplicateKeyError as exc:
        raise TrackingError(f"{side}: {exc}") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise TrackingError(f"{side}: not valid JSON ({exc})") from None
    if not isinstance(meta, dict):
        raise TrackingError(f"{side}: not a JSON object")
    return side, meta


def declared_fps_from(side, meta: dict, cap):
    """(fps, declared_by) of an open video: the sidecar's fps when it has one (the recording
    rate), else the container's (OpenCV's CAP_PROP_FPS); (None, '') when the sidecar has none
    and the container's is not > 0. A sidecar fps that is not a finite number > 0 is an error."""
    if meta.get("fps") is not None:
        try:
            v = float(meta["fps"])
        except (TypeError, ValueError):
            v = float("nan")
        if not (v > 0 and math.isfinite(v)):
            raise TrackingError(f"{side}: fps must be a finite number > 0 [1/s], got "
                                f"{meta['fps']!r}")
        return v, f"the sidecar {side.name}"
    v = float(cap.get(load_cv2().CAP_PROP_FPS) or 0.0)
    if v > 0 and math.isfinite(v):
        return v, "the video container"
    return None, ""


def declared_fps(path):
    """The frame rate a video file declares [1/s] and who declares it.

    The sidecar (``<stem>.json``, else ``video.json`` beside the video) wins over the container:
    it records the camera's rate, while a high-speed camera's file may hold a playback rate.

    Returns
    -------
    (fps, declared_by) : (float, str) or (None, '') when the file declares no rate > 0
    """
    path = Path(path)
    side, meta = read_sidecar(path)
    cap = open_video(path)
    try:
        return declared_fps_from(side, meta, cap)
    finally:
        cap.release()


def fps_mismatch(path, given_fps: float, declared: float | None, declared_by: str):
    """FpsMismatchError when ``given_fps`` is more than FPS_TOLERANCE from ``declared``."""
    if declared is None or abs(given_fps / declared - 1.0) <= FPS_TOLERANCE:
        return None
    return FpsMismatchError(
        f"{path}: fps {given_fps:g} disagrees with {declared:g} fps declared by {declared_by} "
        f"({100 * abs(given_fps / declared - 1):.1f} % apart, more than "
        f"{100 * FPS_TOLERANCE:g} %)", given_fps, declared, declared_by)


def check_fps(path, fps: float):
    """Compare a given frame rate [1/s] with the one the file declares (:func:`declared_fps`).

    Returns
    -------
    FpsMismatchError or None - the mismatch (not raised), or None when they agree within
        :data:`FPS_TOLERANCE` or the file declares no rate
    """
    return fps_mismatch(path, float(fps), *declared_fps(path))


def decode_ahead(cap, batch: int = 32, depth: int = 3):
    """Grey frames of an open capture, decoded in a background thread (OpenCV releases the GIL)
    into a ring of ``depth`` preallocated blocks of ``batch`` frames while the caller tracks.

    No per-frame allocation (a fresh 128 kB frame costs page faults) and one queue hand-over per
    block, not per frame. A yielded frame is a view into a block that is refilled once the
    caller has asked for a frame of the following block: use each frame before the next one or
    copy it (:func:`analysis.tracking.ball.track_frames` does). Decoder errors are raised in the
    caller.
    """
    import queue
    import threading
    cv2 = load_cv2()
    first = next(iter_gray(cap), None)
    if first is None:
        return
    H, W = first.shape
    free: queue.Queue = queue.Queue()
    full: queue.Queue = queue.Queue()
    for _ in range(depth):
        free.put(np.empty((batch, H, W), np.uint8))
    stop = threading.Event()

    def read_into(dst):
        ok, f = cap.read(dst)
        if not ok or f is None:
            return False
        if f is dst:  # decoded in place (grey uint8 of the same size)
            return True
        if f.shape[:2] != dst.shape:
            return None
        if f.ndim == 3:
            cv2.cvtColor(f, cv2.COLOR_BGR2GRAY, dst)
        elif f.dtype != np.uint8:
            cv2.convertScaleAbs(f, dst)
        else:
            dst[...] = f
        return True

    def work():
        try:
            blk = free.get()
            blk[0] = first
            k, more = 1, True
            while more and not stop.is_set():
                while k < batch:
                    got = read_into(blk[k])
                    if got is None:
                        raise VideoReadError(f"frame size changed within the video "
                                             f"(first frame {W}x{H})")
                    if not got:
                        more = False
                        break
                    k += 1
                full.put((blk, k))
                if more:
                    while not stop.is_set():
                        try:
                            blk = free.get(timeout=0.1)
                            break
                        except queue.Empty:
                            continue
                    k = 0
        except BaseException as exc:  # handed to the caller
            full.put(exc)
        finally:
            full.put(None)

    th = threading.Thread(target=work, daemon=True)
    th.start()
    try:
        while True:
            item = full.get()
            if item is None:
                return
            if isinstance(item, BaseException):
                raise item
            blk, k = item
            for i in range(k):
                yield blk[i]
            free.put(blk)
    finally:
        stop.set()
        th.join(timeout=5)
