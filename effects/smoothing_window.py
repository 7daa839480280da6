"""Smoothing of the tracked speed straight through the impacts (observation).

Speeds from a film are differences of tracked positions, smoothed (a Savitzky-Golay filter of
some width, often unstated) before the mean is taken. The ball's axial velocity v_x flips sign
at every end-cap impact, within a contact far shorter than a frame; a smoothing window of
width tau carries the flip over the whole window. For a window that averages evenly (a moving
average of width tau) the smoothed v_x passes from -V to +V linearly over tau, so |v| loses
V tau / 2 at every flip, and with f_col flips per second the mean speed is

    v_obs = v (1 - f_col tau / 2),       tau [s] (the window's moving-average equivalent),

a loss that grows with the collision rate - with the frequency: a measurement chain that makes
v / f fall. A Savitzky-Golay window of w frames at a frame rate fps keeps a step sharper than a
moving average of the same width: its equivalent tau is a fraction of w / fps - on the twin's
own recordings (camera plane at 2134 fps, lab frame, 21-31 Hz, polyorder 2, smoothed straight
through) about a quarter to a third of it, tau ~ 0.3 w / fps, varying by some 7 % between
runs; the straight-line form leaves about 1 % of the speed unexplained at 31 frames. tau = 0 is the raw difference. The
collision count (sign changes) and the impact observables (fitted flights, not the smoothed
speed) are unchanged, and the chemistry sees the true speed.
"""
import numpy as np

from effects import base

#: the observables the smoothed speed is the mean of
SMOOTHED = ("v_mean_m_s", "v_mean_jar_m_s")

DECLARATION = {
    "name": "smoothing_window",
    "kind": "observation",
    "physics": "the tracked speed smoothed through the impacts: v (1 - f_col tau / 2)",
    "parameters": {
        "window_s": {"default": 0.004, "lower": 0.0, "upper": 0.02, "unit": "s",
                     "description": "the smoothing window's moving-average equivalent width"},
    },
    "null": {"window_s": 0.0},
    "diagnose": {"order": 210, "param": "window_s", "s_max": 0.006, "unit": "s",
                 "optional": True},
    "references": [
        "Savitzky A, Golay MJE (1964) Anal Chem 36, 1627",
        "Anglou et al. (2024) ACS Sustain Chem Eng 12, 9003 (speeds from Savitzky-Golay "
        "smoothed tracks, width not stated)",
    ],
    "changes": "how a recording is observed: the mean speed x (1 - f_col tau / 2); no twin "
               "run, not the yields, not f_col",
}


def observed_factor(observable, f_col_hz, params):
    """1 - f_col tau / 2 (>= 0) for the mean speed (:data:`SMOOTHED`), else 1."""
    if observable not in SMOOTHED:
        return 1.0
    f = base.nonnegative_array("f_col_hz", f_col_hz)
    return np.maximum(1.0 - f * float(params["window_s"]) / 2.0, 0.0)


class Effect(base.ObservationEffect):
    factor = staticmethod(observed_factor)
