"""Chord speeds of a film sampled every frame, and the exposure's blur (observation).

A film gives positions, not velocities: the speed of frame k is the chord
|x(t_k + dt) - x(t_k)| / dt over one frame interval dt = 1 / fps. Between impacts the ball flies
at a near-constant speed and a chord is exact; an end impact reverses v_x within a contact far
shorter than a frame (~0.1 ms), and the chord that holds the flip is short: a flip at a fraction
u of the interval (u uniform over the frames: the impacts are not locked to the camera) gives
|v_chord| = V |1 - 2u| instead of V, a loss of V dt (1 - |1 - 2u|), on average V dt / 2 per
flip (for a ping-pong, piecewise-constant |v_x| = V with instantaneous flips, f_col flips per
second, dt < 1 / f_col). The exposure t_e blurs the ball's image over t_e; a tracker's
centroid of the blurred ball is the time average of its position over the exposure, so the
chord speed is the true v_x averaged over two boxes (widths dt and t_e). A flip then loses
2 V E|T_1 + T_2| (T_i uniform over each box), and with p = max(dt, t_e), q = min(dt, t_e):

    v_obs = v (1 - f_col (p / 2 + q^2 / (6 p))),      E|T_1 + T_2| = p / 4 + q^2 / (12 p),

i.e. v (1 - f_col dt / 2) with no exposure, v (1 - 2 f_col dt / 3) with a fully open shutter
(t_e = dt). The twin's v_mean is the mean of its instantaneous speed at its output frames
(yade_scripts/mill.py ``summarize``), which no chord and no exposure touch: the null is
dt = 0 (and t_e = 0), not the twin's 1 / 2134 s. A film at 2134 fps with a short exposure
gives 1.4 % at f_col = 60 /s; 500 fps 6 %. The blur's other footprint, the apparent diameter
that sets a film's scale, is apparent_scale's (a length factor on every observable): the two
do not overlap (this one is the centroid's time average at a flip, a loss per flip).

Limits: a symmetric flip (-V to +V: the lab frame's steady ping-pong; in the jar frame the
rebound is slower than the approach and the loss is smaller, dt V_1 V_2 / (V_1 + V_2) per flip
for the chord alone); at most one flip per chord; flips not locked to the frames (a flip
interval that is a whole number of frames, exactly, fixes u and gives between 0 and V dt per
flip: at 40 /s and 1000 fps the chords lose 0.9 %, not 2 %). Only the mean speed changes: the collision
count (one sign change per flip survives), the impact observables (straight-line fits that skip
the frames next to the impact) and the chemistry are untouched. Smoothing the chord speeds
(smoothing_window) widens the same corner; its loss is not the sum of the two (two boxes of
widths tau >= dt lose tau / 2 + dt^2 / (6 tau), not (tau + dt) / 2): switch on one of them for
a dataset's speeds, or state the frame rate (docs/loop.md). A track observed by the loop itself
(analysis.observe, kink correction on) drops the frames at the flip and has no such loss.
"""
import numpy as np

from effects import base

#: the observables the chord speeds are the mean of
CHORD_SPEEDS = ("v_mean_m_s", "v_mean_jar_m_s")

DECLARATION = {
    "name": "frame_rate",
    "kind": "observation",
    "physics": "chord speeds over a frame dt (and an exposure t_e) cut each v_x flip: "
               "v (1 - f_col (p/2 + q^2/(6p))), p, q = max, min(dt, t_e)",
    "parameters": {
        "frame_interval_s": {"default": 1.0 / 2134.0, "lower": 0.0, "upper": 0.01, "unit": "s",
                             "description": "the film's frame interval 1 / fps"},
        "exposure_s": {"default": 0.0, "lower": 0.0, "upper": 0.01, "unit": "s",
                       "description": "exposure per frame (the centroid of the blurred ball "
                                      "is its mean position over the exposure)"},
    },
    "null": {"frame_interval_s": 0.0, "exposure_s": 0.0},
    "diagnose": {"order": 220, "param": "frame_interval_s", "s_max": 0.002, "unit": "s",
                 "optional": True},
    "references": [
        "Anglou et al. (2024) ACS Sustain Chem Eng 12, 9003 (speeds as frame-to-frame "
        "differences of tracked positions at 2134 fps, eqs 1-3)",
        "Papoulis A, Pillai SU (2002) Probability, Random Variables and Stochastic Processes, "
        "4th ed., McGraw-Hill (the sum of two uniform variables)",
    ],
    "changes": "how a recording is observed: the mean speed x (1 - f_col (p/2 + q^2/(6p))); "
               "no twin run, not the yields, not f_col",
}


def flip_loss_s(frame_interval_s, exposure_s):
    """Mean speed lost per flip over the speed [s]: p / 2 + q^2 / (6 p), p, q = max, min of
    the frame interval and the exposure (0 when both are 0)."""
    dt, te = float(frame_interval_s), float(exposure_s)
    p, q = max(dt, te), min(dt, te)
    return 0.0 if p <= 0.0 else p / 2.0 + q * q / (6.0 * p)


def observed_factor(observable, f_col_hz, params):
    """1 - f_col (p/2 + q^2/(6p)) (>= 0) for the mean speed (:data:`CHORD_SPEEDS`), else 1."""
    if observable not in CHORD_SPEEDS:
        return 1.0
    f = base.nonnegative_array("f_col_hz", f_col_hz)
    loss = flip_loss_s(params["frame_interval_s"], params["exposure_s"])
    return np.maximum(1.0 - f * loss, 0.0)


class Effect(base.ObservationEffect):
    factor = staticmethod(observed_factor)
