"""Collisions counted as sign changes of a noisy, smoothed v_x: spurious counts (observation).

A film's collision rate is often the number of sign changes of the smoothed axial velocity
v_x per second (Anglou et al. 2024). At an end impact v_x flips from -V to +V within a
contact far shorter than a frame; the smoothing (moving-average equivalent width tau) turns the
flip into a ramp through zero of slope 2 V / tau. Tracking noise leaves a stationary Gaussian
error n(t) on the smoothed v_x, with an rms rate of change sigma' [m/s^2]. Near the ramp the sum
can cross zero more than once. Rice's formula for the expected number of zero crossings of
m(t) + n(t), with m linear through zero (slope m'), counts them exactly:

    N = integral phi(m / sigma) / sigma E|m' + n'| dt = E|1 + r Z|,   r = sigma' / m',
    E|1 + r Z| = erf(1 / (r sqrt 2)) + r sqrt(2 / pi) exp(-1 / (2 r^2))        (Z ~ N(0, 1)),

one crossing for r -> 0 and 1 + 2 r phi(1/r) - 2 Phi(-1/r) beyond (+0.9 % at r = 0.5, +17 % at
r = 1, +45 % at r = 1.5). The flip's slope is 2 V / tau with V the ball's speed, so

    f_obs = f_col E|1 + (b / v) Z|,     b = sigma' tau / 2  [m/s],

with v the twin's mean speed at the condition (V ~ v in the lab frame's ping-pong, where the
ball's speed is near constant between the end impacts). b, the strength, is the noise's change
over half the window: a property of the tracking and the smoothing; the count excess falls
steeply with the ball's speed, so slow conditions show it first. b = 0 counts every flip once.
Between the flips |v_x| ~ V stands many sigma above zero and adds no crossings (for
sigma << V). Only f_col changes: the speeds, the impact observables and the chemistry (the
true collisions) are untouched.

Not modelled: missed counts (two flips within one window, or a dead band wider than a weak
rebound), which would lower f_col - the strength is one-sided. The loop's own operator
(analysis.observe: a dead band, the sign state flips only across the opposite threshold) makes
no spurious count from noise near zero: a track the loop observes itself has b = 0; the effect
is for a dataset whose summary f_col was counted without one.
"""
import math

import numpy as np

from effects import base

DECLARATION = {
    "name": "collision_count",
    "kind": "observation",
    "physics": "sign changes of a noisy smoothed v_x counted at each flip: f_col E|1 + (b/v) Z| "
               "(Rice), b = sigma' tau / 2 the noise's change over half the window",
    "parameters": {
        "flip_noise_m_s": {"default": 0.5, "lower": 0.0, "upper": 5.0, "unit": "m/s",
                           "description": "rms rate of change of the smoothed v_x noise times "
                                          "half the smoothing window, sigma' tau / 2"},
    },
    "null": {"flip_noise_m_s": 0.0},
    "diagnose": {"order": 240, "param": "flip_noise_m_s", "s_max": 1.5, "unit": "m/s",
                 "optional": True},
    "references": [
        "Rice SO (1944) Bell Syst Tech J 23, 282-332 (the expected number of zero crossings)",
        "Anglou et al. (2024) ACS Sustain Chem Eng 12, 9003 (collisions as sign changes of "
        "the smoothed v_x)",
    ],
    "changes": "how a recording is observed: the collision rate x E|1 + (b/v) Z|; no twin "
               "run, not the speeds, not the yields",
}


def crossings_per_flip(r):
    """E|1 + r Z| [-] (Z standard normal): the expected zero crossings of a linear ramp through
    zero under Gaussian noise whose rate of change has sd r times the ramp's slope (Rice)."""
    r = np.asarray(r, dtype=float)
    safe = np.where(r > 0, r, 1.0)
    out = (np.vectorize(math.erf)(1.0 / (safe * math.sqrt(2.0)))
           + safe * math.sqrt(2.0 / math.pi) * np.exp(-0.5 / safe ** 2))
    return np.where(r > 0, out, 1.0)


def observed_factor(observable, f_col_hz, params, v_mean_m_s=None):
    """E|1 + (b / v) Z| for the collision rate, else 1 (v: the twin's mean speed [m/s])."""
    if observable != "f_col_hz":
        return 1.0
    b = float(params["flip_noise_m_s"])
    if b == 0.0:
        return 1.0
    if v_mean_m_s is None:
        raise ValueError("collision_count needs the twin's mean speed v_mean_m_s")
    v = base.nonnegative_array("v_mean_m_s", v_mean_m_s)
    if np.any(v <= 0):
        raise ValueError("collision_count: v_mean_m_s must be > 0, got %r" % (v_mean_m_s,))
    return crossings_per_flip(b / v)


class Effect(base.ObservationEffect):
    factor = staticmethod(observed_factor)
