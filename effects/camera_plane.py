"""The camera's plane against the twin's 3-D speed (observation).

The twin's v_mean is the mean of its 3-D speed |v| = sqrt(v_x^2 + v_y^2 + v_z^2) (x the jar's
axis, z up, y the depth; yade_scripts/mill.py ``summarize``); a film sees the projection on its
image plane. A camera whose optical axis is tilted by alpha from the normal of the jar's
axial-vertical plane (a rotation about the vertical) sees

    x_cam = x cos(alpha) + y sin(alpha),    z_cam = z,

so its speed is sqrt((v_x cos a + v_y sin a)^2 + v_z^2). With the vertical speed's share
rho = vy_rms / v (the twin's own ``vy_rms_m_s``: camera y is the twin's z, v the twin's mean
3-D speed) and the depth speed's d = k rho (k = depth rms / vertical rms), for a ball flying
at a near-constant |v_x| between the end impacts (the ping-pong) with transverse speeds of
either sign, small and uncorrelated with v_x, expanding both means to second order in rho
and d - the 3-D mean is |v_x| + (v_y^2 + v_z^2) / (2 |v_x|), the film's
|v_x| cos a + v_z^2 / (2 |v_x| cos a): the depth speed's projection on camera x averages out of
the mean instead of adding in quadrature - the mean speed the film reports is

    v_obs = v sqrt(cos^2(alpha) (1 - d^2) + rho^2 sin^2(alpha))

(alpha = 0: the camera plane against the 3-D speed, v sqrt(1 - d^2); d = 0: the foreshortened
axial speed with the vertical one in full, v sqrt(cos^2 alpha + rho^2 sin^2 alpha)); the
neglected terms are of order d^4, rho^4. The axial observables read from the film are
foreshortened by cos(alpha): the approach speed v_in (the normal speed at an end wall, from
x_cam) and the jar's amplitude (the jar moves along x only); the vertical rms, the apparent
restitution (a ratio), the impact phase and the collision count are not.

Why the tilt is the strength and the depth ratio 0 by default: the twin's ball moves along
the axis; over the 1969 committed twin runs (data/twin_runs/runs.csv) vy_rms / v_mean has
median 0.005, 90th percentile 0.10, maximum 0.19, so a depth motion as large as the vertical
one (k = 1) changes v_mean by 1e-5 at the median, 0.5 % at the 90th percentile and 1.8 % at
the maximum: the 3-D magnitude against the camera plane is below the data's 1.5 % at almost
every state the twin reaches. A camera a few degrees off square is not: 1 - cos(alpha) is
0.4 % at 5 degrees, 1.5 % at 10 degrees, on the speed, the approach speed and the amplitude at
once. The response is quadratic in alpha, so the diagnosis works in the strength
(alpha / 0.2 rad)^2 (near linear). k > 0 (switched on by hand) needs the twin's vy_rms_m_s
(jar tracks give it) and is refused without it; with k = 0 and no vy_rms_m_s, rho = 0 is taken
(an error of rho^2 sin^2(alpha) / (2 cos alpha)). A scale from the ball's apparent diameter
does not correct the tilt (the ball is round in every direction); a calibration target in the
jar's axial plane foreshortens with the jar and does. The tilt is a constant factor on the
speed, the approach speed and the amplitude - apparent_scale's footprint but for the vertical
rms, which apparent_scale scales and the tilt does not.
"""
import numpy as np

from effects import base

#: the mean speeds (3-D in the twin, the camera plane's on the film)
SPEEDS = ("v_mean_m_s", "v_mean_jar_m_s")
#: the axial observables read from camera x (foreshortened by cos alpha)
AXIAL = ("v_in_m_s", "jar_amplitude_m")

DECLARATION = {
    "name": "camera_plane",
    "kind": "observation",
    "physics": "the film's plane, tilted by alpha about the vertical, against the twin's 3-D "
               "speed: v sqrt(cos^2 alpha (1 - d^2) + rho^2 sin^2 alpha), d = k rho, "
               "rho = vy_rms / v; axial lengths x cos alpha",
    "parameters": {
        "tilt_rad": {"default": 0.1, "lower": 0.0, "upper": 0.6, "unit": "rad",
                     "description": "angle between the image plane and the jar's "
                                    "axial-vertical plane (a rotation about the vertical)"},
        "depth_ratio": {"default": 0.0, "lower": 0.0, "upper": 5.0, "unit": "-",
                        "description": "rms depth speed over the rms vertical speed "
                                       "(vy_rms_m_s) of the twin's ball"},
    },
    "null": {"tilt_rad": 0.0, "depth_ratio": 0.0},
    "diagnose": {"order": 230, "param": "tilt_rad", "s_max": 1.0, "unit": "rad",
                 "coord": "square", "p0": 0.2, "optional": True},
    "references": [
        "Hartley R, Zisserman A (2004) Multiple View Geometry in Computer Vision, 2nd ed., "
        "Cambridge University Press (orthographic projection)",
        "Anglou et al. (2024) ACS Sustain Chem Eng 12, 9003 (camera-plane speeds, eq 3)",
    ],
    "changes": "how a recording is observed: the mean speed x sqrt(cos^2 alpha (1 - d^2) + "
               "rho^2 sin^2 alpha), v_in and the jar amplitude x cos alpha; no twin run, not "
               "the yields, not f_col",
}


def observed_factor(observable, f_col_hz, params, v_mean_m_s=None, vy_rms_m_s=None):
    """The factor of the tilted camera plane on the twin's ``observable`` (module doc).

    v_mean_m_s, vy_rms_m_s : the twin's mean speed and rms vertical speed per condition [m/s]
        (needed for the speeds when the depth ratio is > 0; without them, or where either is
        not finite, the vertical share is taken as 0 when the depth ratio is 0)
    """
    alpha, k = float(params["tilt_rad"]), float(params["depth_ratio"])
    if observable in AXIAL:
        return np.cos(alpha)
    if observable not in SPEEDS:
        return 1.0
    if vy_rms_m_s is None or v_mean_m_s is None:
        if k > 0.0:
            raise ValueError("camera_plane with depth_ratio > 0 needs the twin's v_mean_m_s "
                             "and vy_rms_m_s (the impact observables of jar tracks)")
        rho2 = np.zeros(np.shape(f_col_hz))
    else:
        v, s = np.broadcast_arrays(np.asarray(v_mean_m_s, float), np.asarray(vy_rms_m_s, float))
        ok = np.isfinite(v) & np.isfinite(s) & (v > 0) & (s >= 0)
        if k > 0.0 and not np.all(ok):
            raise ValueError("camera_plane with depth_ratio > 0: v_mean_m_s must be finite "
                             "and > 0, vy_rms_m_s finite and >= 0, got %r, %r" % (v, s))
        rho2 = np.where(ok, np.minimum((np.where(ok, s, 0.0) / np.where(ok, v, 1.0)) ** 2,
                                       1.0), 0.0)
    d2 = np.minimum(k * k * rho2, 1.0)
    c2 = np.cos(alpha) ** 2
    return np.sqrt(c2 * (1.0 - d2) + rho2 * (1.0 - c2))


class Effect(base.ObservationEffect):
    factor = staticmethod(observed_factor)
