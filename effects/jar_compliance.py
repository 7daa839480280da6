"""The jar and its clamp as a mass on a spring-damper driven by the motor's stroke.

The jar's position along its axis is x_jar = x_drive(t) + u, with x_drive = A sin(phi(t)) the
motor's motion and u the deviation of a base-excited oscillator of mass M, natural frequency f_n
and damping ratio zeta, pushed by the ball's contact forces:

    M u'' = -k u - c u' - M x_drive''(t) + F_x,   k = M (2 pi f_n)^2,   c = 2 zeta sqrt(k M),

F_x the ball's contact force on the jar along x.

The ball's impacts push the jar back (a rigid jar has M = infinity), which lowers the ball's
rebound speed in the lab frame; the drive term makes the stroke A / (1 - (f/f_n)^2) at steady
state without impacts (a 1.6 % larger stroke at f = 25 Hz, f_n = 200 Hz).

YADE: the jar facets' kinematic engine (the scene's HarmonicMotionEngine, or arc_motion's
rotation when that effect is on) is replaced by a CombinedKinematicEngine adding a
TranslationEngine along x whose velocity is u'. A PyRunner after the NewtonIntegrator
integrates the oscillator every 2 steps while the ball touches the jar and every 10 steps (20 us
at dt = 2e-6 s) in flight, with sub-steps of at most 1/(40 f_n). The ball's force on the jar is
taken from the ball's momentum change over that interval (F_x dt = -m dv_x; gravity is along
z), so the impulse is exact whatever the update rate and momentum is conserved; the jar's
response lags the contact force by up to one interval (20 us at the onset of a contact, 4 us
during it, against ~200 us contacts). Only the axial (x) compliance is modelled; the facet
velocity the scene records as jar_vx_m_s includes u'. f_n_hz at its upper bound (1e4 Hz) means a
rigid jar: no engine is added.

Side effects to know: YADE's contact damping uses the ball's mass (the facets are not dynamic),
not the ball-jar reduced mass, so the relative restitution of an impact on a light jar is a
little lower than the configured one (0.100 against 0.11 for 0.3 kg); the scene's e_diss
energy balance uses the harmonic jar acceleration, not u''. Cost: ~1.3-1.4x the scene's wall
time (the PyRunner).
"""
import math

from effects import base

DECLARATION = {
    "name": "jar_compliance",
    "kind": "dem",
    "physics": "jar + clamp as mass m_jar on a spring-damper (f_n, zeta) about the driven stroke; "
               "the ball's impacts push it back",
    "parameters": {
        "m_jar_kg": {"default": 0.3, "lower": 0.01, "upper": 100.0, "unit": "kg",
                     "description": "moving mass of jar and clamp"},
        "f_n_hz": {"default": 200.0, "lower": 5.0, "upper": 1e4, "unit": "Hz",
                   "description": "natural frequency of the jar on its mount (1e4 = rigid)"},
        "zeta": {"default": 0.1, "lower": 0.0, "upper": 2.0, "unit": "-",
                 "description": "damping ratio of the mount"},
    },
    "null": {"f_n_hz": 1e4},
    # the 20.6 mm ball's flight is bistable under compliance: a start either locks into the
    # 'normal' impacts or a 'late' pattern (approach 4.4 vs 1.3 m/s at 30 Hz, the same
    # strength), from (100 Hz / f_n)^2 ~ 0.5 up (the emulator's motion modes)
    "diagnose": {"order": 30, "param": "f_n_hz", "s_max": 1.5, "unit": "Hz",
                 "coord": "inv_square", "p0": 100.0},
    "references": [
        "Retsch MM400 manual (jar clamps on swing arms)",
        "Den Hartog JP, Mechanical Vibrations (base excitation of a damped oscillator)",
    ],
    "changes": "the jar facets' kinematic engine becomes a CombinedKinematicEngine(drive + "
               "TranslationEngine(u')); a PyRunner integrates u from the ball's momentum change",
}

RIGID_F_N_HZ = DECLARATION["parameters"]["f_n_hz"]["upper"]
N_CONTACT, N_FREE = 2, 10


def oscillator_step(u, du, h, omega, zeta, base_acc, impulse_per_mass, n_sub):
    """Advance the deviation (u [m], u' [m/s]) by h [s]: a kick, then n_sub symplectic substeps.

    u'' = -omega^2 u - 2 zeta omega u' - base_acc (base_acc [m/s2] held over h);
    ``impulse_per_mass`` [m/s] is added to u' first."""
    du += impulse_per_mass
    hs = h / n_sub
    for _ in range(n_sub):
        du += hs * (-omega * omega * u - 2.0 * zeta * omega * du - base_acc)
        u += hs * du
    return u, du


class Effect(base.Effect):
    needs_lab_frame = True             # it moves the jar itself
    def setup(self, twin):
        from yade import O, TranslationEngine, Vector3
        self.active = self.params["f_n_hz"] < RIGID_F_N_HZ
        if not self.active:
            return
        self.twin = twin
        self.M = self.params["m_jar_kg"]
        self.omega = 2 * math.pi * self.params["f_n_hz"]
        self.zeta = self.params["zeta"]
        self.u = self.du = self.u_act = 0.0
        self.trans = TranslationEngine(ids=list(twin.jar_ids), translationAxis=Vector3(1, 0, 0),
                                       velocity=0.0, label="jar_compliance")
        drive = base.jar_kinematic_engine(twin)
        base.replace_engine(drive, drive + self.trans)
        self.runner = base.python_runner(self, "step", N_FREE, "jar_compliance")
        O.engines = list(O.engines) + [self.runner]
        self.t_prev = O.time
        self.vx_prev = O.bodies[twin.ball_id].state.vel[0]
        self.h_max = 1.0 / (40.0 * self.params["f_n_hz"])

    def step(self):
        from yade import O
        twin = self.twin
        t = O.time
        h = t - self.t_prev
        vx = O.bodies[twin.ball_id].state.vel[0]
        if h > 0.0:
            kick = -twin.mass * (vx - self.vx_prev) / self.M  # the ball's impulse on the jar / M
            base_acc = twin.jar_acceleration(t - 0.5 * h)
            n_sub = max(1, int(math.ceil(h / self.h_max)))
            self.u, self.du = oscillator_step(self.u, self.du, h, self.omega, self.zeta,
                                              base_acc, kick, n_sub)
            self.u_act += self.trans.velocity * h
        self.t_prev, self.vx_prev = t, vx
        touching = any(i.isReal for i in O.interactions.withBody(twin.ball_id))
        self.runner.iterPeriod = N_CONTACT if touching else N_FREE
        # velocity until the next update, correcting the facets' drift from the integrated u
        self.trans.velocity = self.du + (self.u - self.u_act) / (self.runner.iterPeriod * twin.dt)
