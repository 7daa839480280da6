"""The MM400's swing arm: the jar rides an arc about a pivot instead of a straight line.

With the pivot at distance R_arm = 1/c below the jar centre (c = curvature_1_m > 0; c < 0 puts
the pivot above), the arm's angle is theta(t) = theta0 sin(phi(t)), sin(theta0) = A c, and the
jar centre moves as

    x = R sin(theta) = A sin(phi) + O(A^3 c^2),
    z = -sign(c) R (1 - cos theta) = -(A^2 c / 4)(1 - cos 2 phi) + O(A^4 c^3),

a vertical oscillation at 2f of amplitude A^2 |c| / 4 (0.91 mm at A = 13.5 mm, c = 20 1/m), while
the jar tilts by theta ~ A c sin(phi) about y. (A pivot below lowers the jar at the stroke ends,
one above raises it.)

YADE: a HarmonicRotationEngine (rotateAroundZero about the pivot, axis sign(c) y, amplitude
theta0) is inserted after the scene's HarmonicMotionEngine; being a kinematic engine it resets
the facets' velocities, so the jar follows the exact arc (chord velocities, positions stay on
their circles). on_frequency copies the scene's frequency and phase offset (the same mid-step
phase convention), so the arm stays phase-locked through the ramp. c = 0 adds nothing.

Recording: the scene's jar_x_m / jar_vx_m_s read facet 0, which under the tilt is off the jar
centre's x by up to |z_facet0| theta0 (see effects/README.md, "hooks wanted"); the contact
monitor's jar velocity has the same offset.
"""
import math

from effects import base

DECLARATION = {
    "name": "arc_motion",
    "kind": "dem",
    "physics": "jar on a swing arm of radius 1/c: x = A sin(phi), vertical motion "
               "-(A^2 c/4)(1 - cos 2phi) at 2f, tilt theta = A c sin(phi)",
    "parameters": {
        "curvature_1_m": {"default": 5.0, "lower": -20.0, "upper": 20.0, "unit": "1/m",
                          "description": "1/R_arm; > 0 pivot below the jar, < 0 above, 0 straight"},
    },
    "null": {"curvature_1_m": 0.0},
    "references": ["Retsch MM400 manual (grinding jars on swing arms, radial oscillation)"],
    "changes": "adds a HarmonicRotationEngine on the jar facets about the arm's pivot after the "
               "scene's HarmonicMotionEngine (which it overrides)",
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
    engine = None

    def setup(self, twin):
        from yade import O, HarmonicRotationEngine, Vector3
        c = self.params["curvature_1_m"]
        if c == 0.0:
            return
        s = 1.0 if c > 0 else -1.0
        radius = 1.0 / abs(c)
        if twin.A >= radius:
            raise ValueError("arc_motion: stroke A = %g m exceeds the arm radius 1/c = %g m"
                             % (twin.A, radius))
        ps = [O.bodies[i].state.pos for i in twin.jar_ids]
        centre = [sum(p[k] for p in ps) / len(ps) for k in range(3)]
        self.engine = HarmonicRotationEngine(
            ids=list(twin.jar_ids), A=math.asin(twin.A / radius), f=twin.f_now,
            fi=twin.motion.fi[0], rotationAxis=Vector3(0, s, 0), rotateAroundZero=True,
            zeroPoint=Vector3(centre[0], centre[1], centre[2] - s * radius), label="arc_motion")
        base.insert_engine_after(twin.motion, self.engine)

    def on_frequency(self, twin, f, phi, t):
        if self.engine is not None:
            self.engine.f = f
            self.engine.fi = twin.motion.fi[0]
