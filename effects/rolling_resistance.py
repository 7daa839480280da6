"""Extra rolling resistance of the ball on the cylinder (powder film, polymer hysteresis).

The scene's rolling friction caps the rolling moment at RF * r * |Fn| (MindlinPhys.maxBendPl =
RF * r; kr sized so the elastic rolling angle at the cap stays below 1e-2 rad up to 100 N). This
effect raises the cap on cylinder contacts to (RF + drf) * r * |Fn| (rolling on a soft or
powder-covered surface: the ball ploughs a groove whose front pushes back; the cap is the
constant-torque rolling model, Ai et al. 2011 model A/C), scaling kr in proportion.

YADE: at the start of every 'cylinder' contact event, the interactions' maxBendPl and kr are set;
a ball rolling along the cylinder crosses onto new facets within one event, so on_sample (every
output frame, 0.47 ms) also sets them on every ball-cylinder interaction that lacks them: a new
facet contact has the scene's cap for at most one frame. If the scene has rolling friction off
(RF = 0, no moments computed), setup switches the law's includeMoment on. End caps keep the
scene's values.
"""
from effects import base

DECLARATION = {
    "name": "rolling_resistance",
    "kind": "dem",
    "physics": "rolling moment cap on the cylinder raised from RF r |Fn| to (RF + drf) r |Fn| "
               "(constant-torque rolling resistance)",
    "parameters": {
        "extra_rolling_friction": {"default": 0.2, "lower": 0.0, "upper": 2.0, "unit": "-",
                                   "description": "drf, added to the rolling friction RF on "
                                                  "cylinder contacts"},
    },
    "null": {"extra_rolling_friction": 0.0},
    "diagnose": {"order": 50, "param": "extra_rolling_friction", "s_max": 2.0,
                 "unit": "-"},
    "references": [
        "Ai J, Chen J-F, Rotter JM, Ooi JY (2011) Powder Technol 206, 269 (rolling resistance "
        "models)",
        "Iwashita K, Oda M (1998) J Eng Mech 124, 285",
    ],
    "changes": "MindlinPhys.maxBendPl and kr of each new ball-cylinder interaction; "
               "Law2_ScGeom_MindlinPhys_Mindlin.includeMoment if RF = 0",
}

#: elastic rolling angle at the cap (rad) at this normal force (N): the scene's kr sizing
ROLL_ANGLE_RAD, ROLL_FORCE_N = 1e-2, 100.0


class Effect(base.Effect):
    def setup(self, twin):
        rf = twin.cfg["rolling_friction"] + self.params["extra_rolling_friction"]
        self.max_bend_pl = rf * twin.r
        self.kr = rf * twin.r * ROLL_FORCE_N / ROLL_ANGLE_RAD
        if self.params["extra_rolling_friction"] > 0.0 and not twin.law.includeMoment:
            twin.law.includeMoment = True

    def on_event_start(self, twin, region, interactions, vn_in):
        if region != "cylinder" or self.params["extra_rolling_friction"] <= 0.0:
            return
        for i in interactions:
            self._apply(i)

    def on_sample(self, twin, t):
        from yade import O
        if self.params["extra_rolling_friction"] <= 0.0:
            return
        pos = O.bodies[twin.ball_id].state.pos
        for i in O.interactions.withBody(twin.ball_id):
            if not i.isReal or i.phys.maxBendPl == self.max_bend_pl and (
                    i.phys.kno == 0.0 or i.phys.kr == self.kr):
                continue
            n = i.geom.contactPoint - pos
            if abs(n[0]) < 0.5 * n.norm():  # the scene's 'cylinder' region
                self._apply(i)

    def _apply(self, i):
        i.phys.maxBendPl = self.max_bend_pl
        if i.phys.kno > 0.0:  # contacts the scene suppressed (kno = 0) stay without moment
            i.phys.kr = self.kr
