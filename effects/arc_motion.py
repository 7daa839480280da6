"""The MM400's swing arm: the jar rides an arc about a pivot instead of a straight line.

With the pivot at distance R_arm = 1/c below the jar centre (c = curvature_1_m > 0; c < 0 puts
the pivot above), the arm's angle is theta(t) = theta0 sin(phi(t)), sin(theta0) = A c, and the
jar centre moves as

    x = R sin(theta) = A sin(phi) + O(A^3 c^2),
    z = -sign(c) R (1 - cos theta) = -(A^2 c / 4)(1 - cos 2 phi) + O(A^4 c^3),

a vertical oscillation at 2f of amplitude A^2 |c| / 4 (0.91 mm at A = 13.5 mm, c = 20 1/m), while
the jar tilts by theta ~ A c sin(phi) about y. (A pivot below lowers the jar at the stroke ends,
one above raises it.)

YADE, tilt = 1 (the exact arc): a HarmonicRotationEngine (rotateAroundZero about the pivot, axis
sign(c) y, amplitude theta0) is inserted after the scene's HarmonicMotionEngine; being a kinematic
engine it resets the facets' velocities, so the jar follows the exact arc (chord velocities,
positions stay on their circles). It halves the scene's speed (measured 8k against 14k steps/s
at 25 Hz; the cost is the rotating facets, independent of c). tilt = 0 (translation only): the
scene's HarmonicMotionEngine is combined (CombinedKinematicEngine) with a second
HarmonicMotionEngine along z at 2f, amplitude A^2 c / 4, so the jar moves x = A sin(phi),
z = -(A^2 c/4)(1 - cos 2 phi) without tilting, at the scene's speed. Either way on_frequency
copies the scene's frequency and phase (the same mid-step convention), so the motion stays
phase-locked through the ramp. c = 0 adds nothing.

Recording: the scene's jar_x_m / jar_vx_m_s read facet 0, which under the tilt is off the jar
centre's x by up to |z_facet0| theta0 (see effects/README.md, "hooks wanted"); the contact
monitor's jar velocity has the same offset.
"""
import math

from effects import ConfigError, base

DECLARATION = {
    "name": "arc_motion",
    "kind": "dem",
    "physics": "jar on a swing arm of radius 1/c: x = A sin(phi), vertical motion "
               "-(A^2 c/4)(1 - cos 2phi) at 2f, tilt theta = A c sin(phi)",
    "parameters": {
        "curvature_1_m": {"default": 5.0, "lower": -20.0, "upper": 20.0, "unit": "1/m",
                          "description": "1/R_arm; > 0 pivot below the jar, < 0 above, 0 straight"},
        "tilt": {"default": 1.0, "lower": 0.0, "upper": 1.0, "unit": "-",
                 "description": "1: exact arc, the jar rotates about the pivot (2x slower "
                                "scene); 0: translation only (x and the 2f vertical motion); "
                                "no other value"},
    },
    "null": {"curvature_1_m": 0.0},
    "diagnose": {"order": 20, "param": "curvature_1_m", "s_max": 15.0, "unit": "1/m"},
    "references": ["Retsch MM400 manual (grinding jars on swing arms, radial oscillation)"],
    "changes": "tilt 1: adds a HarmonicRotationEngine on the jar facets about the arm's pivot "
               "after the scene's HarmonicMotionEngine (which it overrides); tilt 0: combines "
               "the scene's HarmonicMotionEngine with a vertical one at 2f",
}


def arc_pose(phase_rad, amplitude_m, curvature_1_m):
    """(x [m], z [m], theta [rad]) of the jar centre on the arc at the stroke phase."""
    if curvature_1_m == 0.0:
        return amplitude_m * math.sin(phase_rad), 0.0, 0.0
    s = 1.0 if curvature_1_m > 0 else -1.0
    radius = 1.0 / abs(curvature_1_m)
    theta0 = math.asin(min(1.0, amplitude_m / radius))
    th = theta0 * math.sin(phase_rad)
    return radius * math.sin(th), -s * radius * (1.0 - math.cos(th)), s * th


class Effect(base.Effect):
    needs_lab_frame = True             # it moves the jar itself
    engine = None
    vertical = None

    def setup(self, twin):
        from yade import O, HarmonicMotionEngine, HarmonicRotationEngine, Vector3
        c = self.params["curvature_1_m"]
        if self.params["tilt"] not in (0.0, 1.0):
            raise ConfigError("effect arc_motion: tilt must be 0 or 1, got %g"
                              % self.params["tilt"])
        if c == 0.0:
            return
        s = 1.0 if c > 0 else -1.0
        radius = 1.0 / abs(c)
        if twin.A >= radius:
            raise ConfigError("effect arc_motion: stroke A = %g m exceeds the arm radius "
                              "1/c = %g m" % (twin.A, radius))
        if self.params["tilt"] == 0.0:
            self.vertical = HarmonicMotionEngine(ids=list(twin.jar_ids),
                                                 A=Vector3(0, 0, twin.A ** 2 * c / 4.0),
                                                 f=Vector3(0, 0, 0), fi=Vector3(0, 0, 0),
                                                 label="arc_motion_vertical")
            base.replace_engine(twin.motion, twin.motion + self.vertical)
            self.on_frequency(twin, twin.f_now, twin.phase_at(O.time), O.time)
            return
        ps = [O.bodies[i].state.pos for i in twin.jar_ids]
        centre = [sum(p[k] for p in ps) / len(ps) for k in range(3)]
        self.engine = HarmonicRotationEngine(
            ids=list(twin.jar_ids), A=math.asin(twin.A / radius), f=twin.f_now,
            fi=twin.motion.fi[0], rotationAxis=Vector3(0, s, 0), rotateAroundZero=True,
            zeroPoint=Vector3(centre[0], centre[1], centre[2] - s * radius), label="arc_motion")
        base.insert_engine_after(twin.motion, self.engine)

    def on_frequency(self, twin, f, phi, t):
        from yade import Vector3
        if self.engine is not None:
            self.engine.f = f
            self.engine.fi = twin.motion.fi[0]
        if self.vertical is not None:
            # velocity -Az w2 sin(w2 t + fi) = d/dt[-(A^2 c/4)(1 - cos 2 phi)] at mid-step:
            # w2 t + fi = 2 phi(t + dt/2)
            w2 = 4 * math.pi * f
            fi = 2 * phi + w2 * (0.5 * twin.dt - t)
            self.vertical.f = Vector3(0, 0, 2 * f)
            self.vertical.fi = Vector3(0, 0, fi)
