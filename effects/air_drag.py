"""Air drag on the ball (a decoy: physically negligible in this mill).

F = -1/2 rho_air C_d pi r^2 |v_rel| v_rel, v_rel the ball's velocity relative to the air, taken
as moving with the closed jar (v_rel = v_ball - v_jar). Footprint for the 20.6 mm ball at 3 m/s:
F = 8.5e-4 N, i.e. 2.4e-3 of its weight, 7e-5 of the jar's inertial force m A (2 pi f)^2 at
25 Hz, ~1e-6 of an impact's peak force; over a 20 mm flight it removes ~1e-4 of the ball's
kinetic energy (:func:`footprint`). drag_scale = 1 is physical; large values exist for tests.

YADE: a permanent force on the ball (O.forces.setPermF, YADE 2023.02a), recomputed at every
output frame (on_sample, 2134/s by default: the force lags the velocity by up to 0.47 ms).
"""
import math

from effects import base

AIR_DENSITY_KG_M3 = 1.2

DECLARATION = {
    "name": "air_drag",
    "kind": "dem",
    "physics": "quadratic air drag on the ball, F = -1/2 rho C_d pi r^2 |v_rel| v_rel "
               "(air moving with the jar)",
    "parameters": {
        "drag_scale": {"default": 1.0, "lower": 0.0, "upper": 1e4, "unit": "-",
                       "description": "multiplier of the physical drag (1 = physical)"},
        "drag_coefficient": {"default": 0.47, "lower": 0.05, "upper": 2.0, "unit": "-",
                             "description": "sphere drag coefficient C_d (0.47 at Re ~ 1e3-1e5)"},
    },
    "null": {"drag_scale": 0.0},
    # a decoy: its footprint is below the twin's chaos, diagnose must never name it
    "diagnose": {"order": 60, "param": "drag_scale", "s_max": 1.0, "unit": "-",
                 "decoy": True},
    "references": ["Schlichting H, Boundary-Layer Theory (sphere drag curve, C_d ~ 0.47)"],
    "changes": "a permanent force on the ball, updated at every output frame",
}


def drag_force_n(v_rel_m_s, ball_radius_m, drag_coefficient=0.47, drag_scale=1.0,
                 air_density_kg_m3=AIR_DENSITY_KG_M3):
    """Drag force vector [N] for a relative velocity vector (3 floats) [m/s]."""
    speed = math.sqrt(sum(c * c for c in v_rel_m_s))
    k = drag_scale * 0.5 * air_density_kg_m3 * drag_coefficient * math.pi * ball_radius_m ** 2
    return [-k * speed * c for c in v_rel_m_s]


def footprint(ball_diameter_m=0.0206, speed_m_s=3.0, flight_m=0.02, density_kg_m3=7800.0,
              frequency_hz=25.0, amplitude_m=0.0135, gravity_m_s2=9.81, drag_coefficient=0.47):
    """Size of physical drag against the scene's other forces and energies (dict of ratios)."""
    r = ball_diameter_m / 2.0
    m = density_kg_m3 * 4.0 / 3.0 * math.pi * r ** 3
    f = abs(drag_force_n([speed_m_s, 0.0, 0.0], r, drag_coefficient)[0])
    w = 2 * math.pi * frequency_hz
    return {"force_n": f, "over_weight": f / (m * gravity_m_s2),
            "over_jar_inertia": f / (m * amplitude_m * w * w),
            "energy_fraction_per_flight": f * flight_m / (0.5 * m * speed_m_s ** 2)}


class Effect(base.Effect):
    def setup(self, twin):
        self.jar_id = twin.jar_ids[0]

    def on_sample(self, twin, t):
        from yade import O, Vector3
        if self.params["drag_scale"] <= 0.0:
            return
        v = O.bodies[twin.ball_id].state.vel - O.bodies[self.jar_id].state.vel
        f = drag_force_n((v[0], v[1], v[2]), twin.r, self.params["drag_coefficient"],
                         self.params["drag_scale"])
        O.forces.setPermF(twin.ball_id, Vector3(*f))
