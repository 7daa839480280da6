"""The length scale taken from the ball's apparent diameter under motion blur (observation).

A high-speed film's metres per pixel are often set from the ball's own image: the ball's
diameter d [m] over its apparent diameter in pixels. A ball moving at v during an exposure
t_exp smears by v t_exp along its path, so a tracker's fitted circle (or a thresholded blob)
comes out larger by some delta [m] - about 1 mm for 2 m/s over 1/2134 s, 5 % of a 20 mm ball.
The scale is then too small by d / (d + delta), and every length and speed measured from the
film with it - the mean speed, the impact speed, the jar's amplitude, the cross-axis rms -
is low by the same factor:

    x_obs = x / (1 + s),     s = delta / d  [-],

while ratios (the apparent restitution), phases and the collision rate are unchanged, and the
chemistry sees the true speed (the yields are not observed through the film). s = 0 is an
exact scale. The blur depends on the speed; here one s stands for the film's average (one
scale per film, as measured).
"""
from effects import base

#: the observables a wrong length scale multiplies (measured as lengths from the film)
SCALED = ("v_mean_m_s", "v_mean_jar_m_s", "v_in_m_s", "jar_amplitude_m", "vy_rms_m_s")

DECLARATION = {
    "name": "apparent_scale",
    "kind": "observation",
    "physics": "the film's scale from the blurred apparent diameter: lengths and speeds "
               "x / (1 + delta / d)",
    "parameters": {
        "blur_fraction": {"default": 0.05, "lower": 0.0, "upper": 0.3, "unit": "-",
                          "description": "apparent diameter's excess over the true one, "
                                         "delta / d"},
    },
    "null": {"blur_fraction": 0.0},
    "diagnose": {"order": 200, "param": "blur_fraction", "s_max": 0.1, "unit": "-",
                 "optional": True},
    "references": [
        "Anglou et al. (2024) ACS Sustain Chem Eng 12, 9003 (2134 fps, the ball's apparent "
        "diameter as the length scale)",
        "Bolme DS et al. (2010) CVPR, 2544 (MOSSE tracker)",
    ],
    "changes": "how a recording is observed: every length-derived observable / (1 + s); "
               "no twin run, not the yields",
}


def observed_factor(observable, f_col_hz, params):
    """1 / (1 + s) for a length-derived observable (:data:`SCALED`), else 1."""
    s = float(params["blur_fraction"])
    return 1.0 / (1.0 + s) if observable in SCALED else 1.0


class Effect(base.ObservationEffect):
    factor = staticmethod(observed_factor)
