"""TEMPLATE: copy to effects/<name>.py, rename, fill in. (This file is not loaded as an effect.)

One paragraph on the physics: what happens in the real mill, the formula with its symbols and
units, what the parameter's null value means, and the YADE objects the hooks change (or, for a
kinetics effect, how the yield model changes). State the limits (update rates, what is not
modelled).
"""
from effects import base

DECLARATION = {
    "name": "template",                # = the file name without .py
    "kind": "dem",                     # 'dem' (YADE scene), 'kinetics' (yield model) or
                                       # 'observation' (the measurement chain)
    "physics": "one line: the effect and its formula",
    "parameters": {                    # every parameter: SI units, physical bounds
        "strength": {"default": 1.0, "lower": 0.0, "upper": 10.0, "unit": "-",
                     "description": "what it scales"},
    },
    "null": {"strength": 0.0},         # parameter values at which the scene is the base scene
    # its diagnose candidate (analysis.catalog; delete the entry if diagnose shall not look
    # for this effect): the parameter the strength sets, the top of its diagnose range s_max
    # (in the strength coordinate, within the parameter's bounds) and the parameter's unit;
    # optional: "coord" 'linear' (strength = param, default), 'inv_square' (= (p0 / param)^2) or
    # 'square' (= (param / p0)^2), chosen so that the response is near linear in the strength,
    # with "p0"; "fixed" ({other parameter: value}); "optional": True to
    # diagnose it only when asked for (loop --with-effect), "decoy": True for an effect too
    # small for the twin to see. "order" places it in the catalog (run ids, plots, tables): take
    # the next free multiple of 10 (python -c "import effects; print(effects.diagnose_entries())")
    "diagnose": {"order": 990, "param": "strength", "s_max": 5.0, "unit": "-"},
    "references": ["Author A (year) Journal vol, page"],
    "changes": "which YADE objects / which part of the kinetic model it changes",
}


# --- a DEM effect: implement the hooks you need (yade is imported inside them, so the module
# --- also imports in the analysis venv where yade is absent)
class Effect(base.Effect):
    def setup(self, twin):
        """After the scene is built: add engines (base.insert_engine_after, base.replace_engine,
        base.python_runner), keep references on self."""
        self.strength = self.params["strength"]

    def on_frequency(self, twin, f, phi, t):
        """The jar's frequency became f [Hz] with phase phi [rad] at time t [s]."""

    def on_event_start(self, twin, region, interactions, vn_in):
        """A contact with 'end+', 'end-' or 'cylinder' began; interactions are YADE
        Interaction objects (i.phys is a MindlinPhys); vn_in the normal approach speed [m/s].
        E.g. base.set_restitution(twin, interactions, e, vn_in)."""

    def on_sample(self, twin, t):
        """At every output frame (t [s])."""


# --- a kinetics effect instead: set "kind": "kinetics", delete the class above and write
#
# def modify_kinetics(e_kin_j, f_col_hz, time_s, slope_pct_per_kj, intercept_pct, params):
#     """Yield [%] with the effect; arrays broadcast; X = a * E[kJ] + b is the base line."""
#     ...
#
# class Effect(base.KineticsEffect):
#     modify = staticmethod(modify_kinetics)
#
# --- an observation effect instead (the measurement chain: no twin run, no design input):
# set "kind": "observation", "optional": True in "diagnose", delete the classes above and write
#
# def observed_factor(observable, f_col_hz, params, v_mean_m_s=None):
#     """The factor by which the chain reports the twin's true ``observable`` at each
#     condition (numpy); name only the keywords of the twin's state you need (v_mean_m_s,
#     frequency_hz, ball_diameter_m, the impact observables: effects.base.ObservationEffect)."""
#     ...
#
# class Effect(base.ObservationEffect):
#     factor = staticmethod(observed_factor)
