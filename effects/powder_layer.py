"""A powder layer on the walls that absorbs a fixed energy per impact.

A ball landing on a powder layer of thickness h compacts a spherical cap of depth h: the plastic
work is E_p = p_c * V_cap, V_cap = pi h^2 (r - h/3) (p_c the powder's crushing/compaction
pressure, r the ball radius). The rebound keeps the wall's restitution e on what is left:

    e_eff^2 = e^2 - 2 E_p / (m vn^2),   clipped to [0.001, 1],

so slow impacts lose much more of their restitution than fast ones (at h = 0.1 mm, p_c = 1 MPa,
r = 10.3 mm: E_p = 3.2e-4 J; e_eff = 0.11 -> 0.105 at 4 m/s, 0.087 at 2 m/s, 0.001 below
~1.2 m/s).

YADE: at the start of every ball-wall contact event (end caps and cylinder) the interactions'
MindlinPhys.betan is set for e_eff(vn_in) (effects.base.set_restitution, same machinery as
viscoelastic_restitution; e is the restitution the interaction has at that moment, so the two
effects compose). The powder's mass, its coverage changes and its cushioning of the contact
stiffness are not modelled.
"""
import math

from effects import base

DECLARATION = {
    "name": "powder_layer",
    "kind": "dem",
    "physics": "powder layer of thickness h on the walls absorbs E_p = p_c pi h^2 (r - h/3) per "
               "impact: e_eff^2 = e^2 - 2 E_p / (m vn^2)",
    "parameters": {
        "layer_thickness_m": {"default": 1e-4, "lower": 0.0, "upper": 2e-3, "unit": "m",
                              "description": "powder layer thickness h on the walls"},
        "crush_pressure_pa": {"default": 1e6, "lower": 1e4, "upper": 1e8, "unit": "Pa",
                              "description": "pressure p_c needed to compact the powder"},
    },
    "null": {"layer_thickness_m": 0.0},
    "diagnose": {"order": 40, "param": "layer_thickness_m", "s_max": 1.0, "unit": "m",
                 "coord": "square", "p0": 5e-4},
    "references": [
        "Anglou et al. (2024) ACS Sustain Chem Eng 12, 9003 (PET powder in the jar)",
        "Thornton C, Ning Z (1998) Powder Technol 99, 154 (plastic energy loss per impact)",
    ],
    "changes": "MindlinPhys.betan of each new ball-wall interaction, from the event's normal "
               "approach speed",
}


def energy_per_impact_j(layer_thickness_m, crush_pressure_pa, ball_radius_m):
    """E_p = p_c * pi h^2 (r - h/3) [J] (h clipped to the ball radius)."""
    h = min(layer_thickness_m, ball_radius_m)
    return crush_pressure_pa * math.pi * h * h * (ball_radius_m - h / 3.0)


def effective_restitution(e, vn_m_s, mass_kg, e_p_j):
    """e_eff = sqrt(e^2 - 2 E_p / (m vn^2)), clipped to [0.001, 1] [-]."""
    if vn_m_s <= 0.0:
        return base.E_MIN
    e2 = e * e - 2.0 * e_p_j / (mass_kg * vn_m_s * vn_m_s)
    return min(1.0, max(base.E_MIN, math.sqrt(e2) if e2 > 0.0 else 0.0))


class Effect(base.Effect):
    def setup(self, twin):
        self.e_p_j = energy_per_impact_j(self.params["layer_thickness_m"],
                                         self.params["crush_pressure_pa"], twin.r)

    def on_event_start(self, twin, region, interactions, vn_in):
        if self.e_p_j <= 0.0:
            return
        e_now = base.current_restitution(twin, interactions[0])
        e = effective_restitution(e_now, vn_in, twin.mass, self.e_p_j)
        base.set_restitution(twin, interactions, e, vn_in)
