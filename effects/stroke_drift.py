"""The stroke changes with the set frequency: a drive (motor, arm, mounting) under load.

The twin moves the jar with one half stroke A at every frequency, as the paper's DEM does. A
real drive under a load that grows with frequency (the jar's inertia m A (2 pi f)^2, the
ball's impacts) may lose stroke as f rises. The effect makes the half stroke at the set
frequency f

    A(f) = A0 (1 - k (f - f_ref)),

A0 the run config's ``amplitude_m`` (the stroke at f_ref), k = ``fall_per_hz`` [1/Hz] (> 0: the
stroke falls with f; < 0: it rises), f_ref = ``f_ref_hz``. k = 0 is the base twin. Since the
ball's speed scales about as A f, a fall of k per Hz makes v/f fall by about k per Hz: Table 3's
17.5 mm ball loses 6.9 % of v/f from 22.5 to 30 Hz in the paper's DEM and about 7 % in the
measurements, i.e. k ~ 0.009 /Hz. A jar track pins A(f) directly (the impact observable
``jar_amplitude_m``).

YADE: the hook ``amplitude(cfg, a)`` of :class:`effects.base.Effect` gives the scene its half
stroke before the jar's motion is built (the harmonic engine in the lab frame, the inertial
force in the jar frame), so both frames and every other effect (the arc reads ``twin.A``) see
A(f); the ramp runs at A(f) of the set frequency. The run config and its id keep A0 and k.
"""
from effects import ConfigError, base

DECLARATION = {
    "name": "stroke_drift",
    "kind": "dem",
    "physics": "the half stroke falls with the set frequency: A(f) = A0 (1 - k (f - f_ref))",
    "parameters": {
        "fall_per_hz": {"default": 0.005, "lower": -0.03, "upper": 0.03, "unit": "1/Hz",
                        "description": "relative fall of the half stroke per Hz above f_ref"},
        "f_ref_hz": {"default": 25.0, "lower": 3.0, "upper": 35.0, "unit": "Hz",
                     "description": "the frequency at which the half stroke is amplitude_m"},
    },
    "null": {"fall_per_hz": 0.0},
    # an apparatus effect (docs/apparatus.md): diagnosed only when asked for
    # (python -m analysis.loop --with-effect stroke_drift)
    "diagnose": {"order": 120, "param": "fall_per_hz", "s_max": 0.015, "unit": "1/Hz",
                 "optional": True},
    "references": ["issue 26 of this project: a stroke that changes with frequency as the "
                   "hypothesis for Table 3's falling v/f (untested against the real mill)"],
    "changes": "the scene's half stroke twin.A before the jar's motion is built; no engine",
}

#: the smallest stroke factor 1 - k (f - f_ref) accepted (the stroke must stay a stroke)
MIN_FACTOR = 0.2


def stroke_factor(frequency_hz, params):
    """A(f) / A0 at the set frequency; ConfigError when it falls below :data:`MIN_FACTOR`."""
    k, f_ref = float(params["fall_per_hz"]), float(params["f_ref_hz"])
    factor = 1.0 - k * (float(frequency_hz) - f_ref)
    if factor < MIN_FACTOR:
        raise ConfigError("effect stroke_drift: the stroke factor 1 - %g (%g - %g) = %.3g at the "
                          "set frequency is below %g" % (k, frequency_hz, f_ref, factor,
                                                         MIN_FACTOR))
    return factor


class Effect(base.Effect):
    """The half stroke at the set frequency; nothing else changes."""

    def amplitude(self, cfg, a):
        return a * stroke_factor(cfg["frequency_hz"], self.params)
