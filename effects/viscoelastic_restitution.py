"""Velocity-dependent restitution of the polymer wall (viscoelastic Hertz contact).

For a viscoelastic Hertzian impact, 1 - e grows with the impact speed like v^(1/5)
(Kuwabara & Kono 1987; Brilliantov et al. 1996; Ramirez et al. 1999). Here

    e(v) = e0 - k [(v / v_ref)^(1/5) - 1],   clipped to [0.001, 1],

with e0 the scene's restitution (config ``restitution``, the value at v_ref) and k the strength:
k = 0 is the base scene, k = 1 - e0 the pure law 1 - e = (1 - e0) (v / v_ref)^(1/5).

YADE: at the start of every ball-wall contact event the new interactions' MindlinPhys.betan is set
so that the impact rebounds with e(vn_in) (effects.base.set_restitution: Thornton 2013 B6 betan,
the scene's dt compensation en_yade / restitution). The scene sees an event up to ~20 us after
onset, and a heavily damped contact (e = 0.11) has by then lost up to a third of its approach
speed under the scene's damping, so the betan for the rest of the contact is solved from the
damped Hertz equation (base.remaining_contact_betan, ~5 ms per event): measured e within 0.3 % of
e(v) at 1 and 4 m/s (e0 = 0.11, k = 0.05 and e0 = 0.5, k = 0.2); without the solve the 4 m/s
impact was 2-3 % off. Composes multiplicatively with an effect that set the interaction's
restitution before it (powder_layer): e <- e * e(v) / e0. Facets the ball reaches later within
the same event keep the scene's damping (see effects/README.md, "Hooks wanted").
"""
from effects import base

DECLARATION = {
    "name": "viscoelastic_restitution",
    "kind": "dem",
    "physics": "restitution falls with impact speed: e(v) = e0 - k((v/v_ref)^(1/5) - 1) "
               "(viscoelastic Hertz contact)",
    "parameters": {
        "k": {"default": 0.1, "lower": 0.0, "upper": 1.0, "unit": "-",
              "description": "strength: drop of e per unit of (v/v_ref)^(1/5) "
                             "(1 - e0 gives the pure Kuwabara-Kono form)"},
        "v_ref_m_s": {"default": 1.0, "lower": 0.1, "upper": 10.0, "unit": "m/s",
                      "description": "impact speed at which e equals the configured restitution"},
    },
    "null": {"k": 0.0},
    "diagnose": {"order": 10, "param": "k", "s_max": 0.6, "unit": "-"},
    "references": [
        "Kuwabara G, Kono K (1987) Jpn J Appl Phys 26, 1230",
        "Brilliantov NV, Spahn F, Hertzsch J-M, Poeschel T (1996) Phys Rev E 53, 5382",
        "Ramirez R, Poeschel T, Brilliantov NV, Schwager T (1999) Phys Rev E 60, 4465",
        "Thornton C, Cummins SJ, Cleary PW (2013) Powder Technol 233, 30 (eq. B6)",
    ],
    "changes": "MindlinPhys.betan of each new ball-wall interaction (end caps and cylinder), "
               "from the event's normal approach speed",
}


def restitution(v_m_s, e0, k, v_ref_m_s=1.0):
    """e(v) = e0 - k((v/v_ref)^(1/5) - 1), clipped to [0.001, 1].

    Parameters
    ----------
    v_m_s : float - normal impact speed [m/s], >= 0
    e0 : float - restitution at v_ref [-]
    k : float - strength [-]
    v_ref_m_s : float - reference speed [m/s]
    """
    if v_m_s < 0:
        raise ValueError("impact speed must be >= 0, got %r" % v_m_s)
    e = e0 - k * ((v_m_s / v_ref_m_s) ** 0.2 - 1.0)
    return min(1.0, max(base.E_MIN, e))


class Effect(base.Effect):
    def on_event_start(self, twin, region, interactions, vn_in):
        e0 = twin.cfg["restitution"]
        ev = restitution(max(vn_in, 0.0), e0, self.params["k"], self.params["v_ref_m_s"])
        e_now = base.current_restitution(twin, interactions[0])
        base.set_restitution(twin, interactions, e_now * ev / e0 if e0 > 0 else ev, vn_in)
