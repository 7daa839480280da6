"""The exceptions of :mod:`analysis.tracking` (the bottom of the package: imports nothing)."""
from __future__ import annotations


class TrackingError(ValueError):
    """Bad video or a ball that cannot be followed (message names the file)."""


class VideoReadError(TrackingError):
    """The video cannot be opened or holds no decodable frame."""


class BallNotFoundError(TrackingError):
    """The detector never found the ball."""


class FpsMismatchError(TrackingError):
    """A given frame rate disagrees with the one the video file declares.

    Attributes
    ----------
    given_fps, declared_fps : float - the two frame rates [1/s]
    declared_by : str - 'the sidecar <name>' or 'the video container'
    """

    def __init__(self, message, given_fps, declared_fps, declared_by):
        super().__init__(message)
        self.given_fps = given_fps
        self.declared_fps = declared_fps
        self.declared_by = declared_by


class JarNotFoundError(TrackingError):
    """The jar's end walls cannot be found in the video."""
