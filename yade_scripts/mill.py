# -*- coding: utf-8 -*-
"""The MM400 twin: one steel ball in a 25 mL jar that oscillates along its axis.

Run under YADE's own Python (Debian's ``yade`` package, 2023.02a)::

    yade -n -x yade_scripts/mill.py --config run.json --out results/runs/<run-id>

or in a yade-batch sweep with a parameter table whose columns are config keys::

    yade-batch --job-threads=1 table.txt yade_scripts/mill.py

Scene: the jar cavity as facets (from an STL, axis along x), one sphere (no clump), Table 2
materials, Hertz-Mindlin (Ip2_FrictMat_FrictMat_MindlinPhys + Law2_ScGeom_MindlinPhys_Mindlin with
includeMoment for rolling friction), HarmonicMotionEngine moving the jar along x, gravity along -z.

Protocol 'mill': the frequency ramps from 0 to f (phase-continuous, stroke fixed, as the real mill
spins up), the script then waits until the mean ball speed of consecutive windows of jar cycles
agrees (steady state), and records ``record_s``. Protocol 'free': the jar runs at f from t = 0 and
recording starts at once (tests of contact physics).

Writes into a temporary folder beside --out and renames it when complete: meta.json,
trajectory.csv, impacts.csv (see docs/reference.md, "Recording"). An existing --out is replaced only when
this project wrote it (``out_rule.py``: the mark file, or a recording of this scene); any other
non-empty folder, the repository, a source folder or an input is refused with one line and exit
code 2 before the simulation starts. Exit code 2 on bad input, 3 when the ball
leaves the jar or the run exceeds its wall-time budget; nothing is left marked complete then.

Pitfalls handled here (see docs/reference.md):
- HarmonicMotionEngine's phase uses absolute O.time: the phase offset ``fi`` is recomputed at every
  frequency update so that the jar's phase is continuous, and the engine's velocity is taken at
  mid-step, so x_jar = A sin(phi(t)) about the rest position to O(dt^2).
- Ig2_Facet_Sphere_ScGeom by default counts a facet as a sphere of radius 2r (Hertz radius 2r/3,
  stiffness sqrt(2/3) of a flat wall). facet_contact='flat' uses hertzian=True (facet radius 1e8 r,
  Hertz radius r) and rescales eta so that the rolling cap eta*Rmean*|Fn| stays RF * r * |Fn|.
- ``es`` has no separate effect in this law: only en is set.
- Facets must not collide with each other: they get their own mask bit and the collider's
  avoidSelfInteractionMask, otherwise every facet pair is an interaction checked at every step.
- NewtonIntegrator's default damping is 0.2: set to 0 (all dissipation is in the contact law).
"""
import argparse
import json
import math
import os
import random
import shutil
import subprocess
import sys
import time

# under `yade -x`, __file__ names YADE's launcher, not this script: take the script from argv
_SCRIPT = __file__ if __file__.endswith(".py") else sys.argv[0]
HERE = os.path.dirname(os.path.abspath(_SCRIPT))
ROOT = os.path.dirname(HERE)
for _p in (HERE, ROOT):
    if _p not in sys.path:
        sys.path.insert(0, _p)

import numpy as np  # noqa: E402

import twin_config  # noqa: E402
from twin_config import ConfigError  # noqa: E402
from out_rule import OutRefused, check_run_out, may_replace  # noqa: E402
from twin_modes import classify_motion, collision_rate  # noqa: E402
from geometry.stl_io import MeshError, ball_fit_error  # noqa: E402
from geometry.jar import mesh_for_config  # noqa: E402
from effects import jar_config, load_effects  # noqa: E402

from yade import O, utils  # noqa: E402
from yade.wrapper import (FrictMat, ForceResetter, InsertionSortCollider, Bo1_Sphere_Aabb,  # noqa: E402
                          Bo1_Facet_Aabb, InteractionLoop, Ig2_Facet_Sphere_ScGeom,
                          Ip2_FrictMat_FrictMat_MindlinPhys, Law2_ScGeom_MindlinPhys_Mindlin,
                          HarmonicMotionEngine, HarmonicForceEngine, NewtonIntegrator,
                          PyRunner)
from yade.minieigenHP import Vector3  # noqa: E402

JAR_MASK = 2
BALL_MASK = 3
#: NewtonIntegrator's mask in the jar frame: the ball (3 & 1) is integrated, the static facets
#: (2 & 1 = 0) are skipped - Newton's pass over the jar's facets was half of a lab-frame step
NEWTON_JAR_FRAME_MASK = 1
#: rolling_model 'constant_torque': the rolling spring is this much stiffer than 'spring'
#: (spring: the cap at |Fn| within Fn / 1e4 N rad, 0.1 rad at 1 kN; x500: 2e-4 rad, less than one
#: step's rolling at impact spin rates)
ROLLING_CDT_FACTOR = 500.0
#: YADE's Ig2_Facet_Sphere_ScGeom(hertzian=True) gives the facet this radius, in ball radii.
HERTZIAN_FACET_RADIUS_FACTOR = 1e8
TRAJ_COLUMNS = list(twin_config.TRAJECTORY_COLUMNS)
IMPACT_COLUMNS = list(twin_config.IMPACT_COLUMNS)


class RunFailure(RuntimeError):
    """The simulation itself failed (ball escaped, wall-time budget exceeded)."""


# ----------------------------------------------------------------------------------------------
# configuration and geometry
# ----------------------------------------------------------------------------------------------
def parse_args(argv):
    p = argparse.ArgumentParser(prog="mill.py", description="MM400 single-ball twin (YADE)")
    p.add_argument("--config", help="run config JSON (keys: yade_scripts/twin_config.py)")
    p.add_argument("--out", help="output folder (default results/runs/<run-id>)")
    return p.parse_args(argv)


def config_from_batch_table():
    """Config from a yade-batch parameter table (columns are config keys), or None."""
    # yade-batch sets YADE_BATCH=table:line (older YADE: PARAM_TABLE)
    if not (os.environ.get("YADE_BATCH") or os.environ.get("PARAM_TABLE")):
        return None
    scalar = {k: v[0] for k, v in twin_config.PARAMETERS.items()}
    scalar["effects"] = {}      # a column of dict literals, as analysis.sweep writes it
    scalar["out"] = ""          # output folder (relative to yade-batch's working folder)
    scalar["description"] = ""  # yade-batch's job name (log file name); not a config key
    utils.readParamsFromTable(noTableOk=True, **scalar)
    from yade.params import table
    cfg = {k: getattr(table, k) for k in scalar if k not in ("out", "description")}
    return cfg, (table.out or None)


def load_jar(cfg):
    """Read and check the jar STL; return triangles [m] and its dimensions."""
    path = twin_config.resolve_stl(cfg, ROOT)
    try:
        tri, info, scale = mesh_for_config(jar_config(cfg), path)
    except ConfigError:
        raise
    except ValueError as exc:   # an unreadable STL or impossible parametric dimensions
        what = "parametric jar" if cfg.get("jar_inner_diameter_m") is not None else "jar STL"
        raise ConfigError("%s: %s" % (what, exc))
    if info.pop("source") == "parametric":
        info["stl_path"] = "parametric"
    else:
        info["stl_path"] = os.path.relpath(path, ROOT) if path.startswith(ROOT) else path
    info["metres_per_unit"] = scale
    problem = ball_fit_error(cfg["ball_diameter_m"], info)
    if problem:
        raise ConfigError(problem)
    return tri, info


def point_triangle_distance(p, tri):
    """Distance from point p (3,) to each triangle of tri (n, 3, 3) [m]."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    ab, ac, ap = b - a, c - a, p - a
    n = np.cross(ab, ac)
    nn = np.einsum("ij,ij->i", n, n)
    # barycentric projection onto the plane
    d1 = np.einsum("ij,ij->i", ab, ap)
    d2 = np.einsum("ij,ij->i", ac, ap)
    d00 = np.einsum("ij,ij->i", ab, ab)
    d01 = np.einsum("ij,ij->i", ab, ac)
    d11 = np.einsum("ij,ij->i", ac, ac)
    den = d00 * d11 - d01 * d01
    v = (d11 * d1 - d01 * d2) / den
    w = (d00 * d2 - d01 * d1) / den
    inside = (v >= 0) & (w >= 0) & (v + w <= 1)
    plane = np.abs(np.einsum("ij,j->i", n, p) - np.einsum("ij,ij->i", n, a)) / np.sqrt(nn)

    def seg(x0, x1):
        e = x1 - x0
        t = np.clip(np.einsum("ij,ij->i", p - x0, e) / np.einsum("ij,ij->i", e, e), 0, 1)
        q = x0 + t[:, None] * e
        return np.linalg.norm(p - q, axis=1)

    edge = np.minimum(np.minimum(seg(a, b), seg(b, c)), seg(c, a))
    return np.where(inside, plane, edge)


def start_state(cfg, tri, info):
    """Initial ball position and velocity (jar frame = lab frame at t = 0)."""
    r = cfg["ball_diameter_m"] / 2.0
    if cfg["ball_start"] == "given":
        pos = np.array(cfg["ball_init_pos_m"])
        vel = np.array(cfg["ball_init_vel_m_s"] or [0.0, 0.0, 0.0])
        if point_triangle_distance(pos, tri).min() < r:
            raise ConfigError("ball_init_pos_m %s overlaps the jar wall" % list(pos))
        return pos, vel
    if cfg["ball_start"] == "center":
        return np.zeros(3), np.zeros(3)
    rng = random.Random(cfg["seed"])
    half = info["inner_length_m"] / 2.0
    rad = info["inner_diameter_m"] / 2.0
    for _ in range(10000):
        pos = np.array([rng.uniform(-half, half), rng.uniform(-rad, rad), rng.uniform(-rad, rad)])
        if math.hypot(pos[1], pos[2]) > rad:
            continue
        if point_triangle_distance(pos, tri).min() > r * 1.001 + 1e-5:
            return pos, np.zeros(3)
    raise ConfigError("found no start position for the ball inside the jar")


def hertz_contact_time(cfg, v_m_s):
    """Hertz contact duration [s] of the ball on a flat wall at impact speed v (elastic)."""
    r = cfg["ball_diameter_m"] / 2.0
    m = cfg["ball_density_kg_m3"] * 4.0 / 3.0 * math.pi * r ** 3
    e_star = 1.0 / ((1 - cfg["ball_poisson"] ** 2) / cfg["ball_young_pa"]
                    + (1 - cfg["wall_poisson"] ** 2) / cfg["wall_young_pa"])
    return 2.87 * (m * m / (r * e_star ** 2 * max(v_m_s, 1e-3))) ** 0.2


def simulated_restitution(cfg, en_yade, v_m_s=2.0, n_phases=4):
    """Restitution YADE produces for a normal ball-facet impact at this dt (a scratch scene).

    The result depends at O(dt) on where inside a time step the contact begins, so it is averaged
    over ``n_phases`` evenly spaced onset phases.
    """
    return sum(_one_impact(cfg, en_yade, v_m_s, 2.0 + k / float(n_phases))
               for k in range(n_phases)) / n_phases


def _one_impact(cfg, en_yade, v_m_s, gap_steps):
    r = cfg["ball_diameter_m"] / 2.0
    O.reset()
    wall = O.materials.append(FrictMat(young=cfg["wall_young_pa"], poisson=cfg["wall_poisson"],
                                       density=cfg["wall_density_kg_m3"], frictionAngle=0.0))
    ball = O.materials.append(FrictMat(young=cfg["ball_young_pa"], poisson=cfg["ball_poisson"],
                                       density=cfg["ball_density_kg_m3"], frictionAngle=0.0))
    L = 4 * r
    O.bodies.append(utils.facet([Vector3(0, -L, -L), Vector3(0, L, -L), Vector3(0, 0, L)],
                                material=wall, fixed=True))
    gap = gap_steps * v_m_s * cfg["dt_s"]
    b = O.bodies.append(utils.sphere(Vector3(-r - gap, 0, 0), r, material=ball))
    O.bodies[b].state.vel = Vector3(v_m_s, 0, 0)
    O.engines = [ForceResetter(),
                 InsertionSortCollider([Bo1_Sphere_Aabb(), Bo1_Facet_Aabb()]),
                 InteractionLoop([Ig2_Facet_Sphere_ScGeom(hertzian=cfg["facet_contact"] == "flat")],
                                 [Ip2_FrictMat_FrictMat_MindlinPhys(en=en_yade)],
                                 [Law2_ScGeom_MindlinPhys_Mindlin()]),
                 NewtonIntegrator(gravity=Vector3(0, 0, 0), damping=0.0)]
    O.dt = cfg["dt_s"]
    n = int(3 * hertz_contact_time(cfg, v_m_s) / cfg["dt_s"]) + 10
    for _ in range(20):
        O.run(n, True)
        if len([i for i in O.interactions if i.isReal]) == 0 and O.bodies[b].state.vel[0] < 0:
            break
    return -O.bodies[b].state.vel[0] / v_m_s


def compensated_restitution(cfg):
    """YADE's en that makes the simulated restitution equal the configured one at this dt.

    The leapfrog integration of the Hertz contact with Tsuji-type damping loses restitution at
    first order in dt (at C_R = 0.11: -0.35 % at 1e-6 s, -1.6 % at 2e-6 s). A few secant steps on
    a scratch one-impact scene (2 m/s, the twin's typical impact speed) remove that bias; the
    remaining spread over 0.5-4 m/s is a fraction of a percent (tests/test_twin_physics.py).
    """
    target = cfg["restitution"]
    if target >= 1.0:
        return 1.0, 1.0
    x0, e0 = target, simulated_restitution(cfg, target)
    x1 = min(1.0, target * target / max(e0, 1e-9))
    for _ in range(6):
        e1 = simulated_restitution(cfg, x1)
        if abs(e1 - target) < 1e-5 * target or x1 >= 1.0 or e1 == e0:
            break
        x0, e0, x1 = x1, e1, min(1.0, x1 + (target - e1) * (x1 - x0) / (e1 - e0))
    return x1, e1


# ----------------------------------------------------------------------------------------------
# the scene
# ----------------------------------------------------------------------------------------------
class Twin(object):
    """Builds the scene, drives the protocol from PyRunners, holds the records."""

    def __init__(self, cfg, tri, info, effects=()):
        self.cfg = cfg
        self.effects = list(effects)
        self.info = info
        self.r = cfg["ball_diameter_m"] / 2.0
        self.f_target = cfg["frequency_hz"] if cfg["amplitude_m"] > 0 else 0.0
        self.A = cfg["amplitude_m"]
        for e in self.effects:     # an effect may change the stroke the drive delivers
            self.A = e.amplitude(cfg, self.A)
        self.dt = cfg["dt_s"]
        self.wall_start = time.time()
        self.rows = []
        self.impacts = []
        self.events = {}
        self.phase = "ramp" if cfg["protocol"] == "mill" and cfg["ramp_s"] > 0 else "settle"
        if cfg["protocol"] == "free":
            self.phase = "record"
        self.record_start = 0.0 if self.phase == "record" else None
        self.wall_record_start = self.wall_start
        self.full_since = 0.0 if self.phase != "ramp" else None
        self.windows = []          # (t_end, mean speed) of settle windows
        self.win_speeds = []
        self.win_t0 = None
        self.steady = None
        self.cyl_contact_time = 0.0
        self.error = None
        self.done = False
        self.frame = resolve_frame(cfg, self.effects)
        self._build(tri)
        for e in self.effects:  # effects may add engines or change the motion (effects/)
            e.setup(self)

    # -- scene --
    def _build(self, tri):
        cfg = self.cfg
        if cfg["restitution_compensation"]:
            self.en_yade, self.en_check = compensated_restitution(cfg)
        else:
            self.en_yade, self.en_check = cfg["restitution"], None
        O.reset()
        fa = math.atan(cfg["static_friction"])
        wall = O.materials.append(FrictMat(young=cfg["wall_young_pa"], poisson=cfg["wall_poisson"],
                                           density=cfg["wall_density_kg_m3"], frictionAngle=fa,
                                           label="wall"))
        ball = O.materials.append(FrictMat(young=cfg["ball_young_pa"], poisson=cfg["ball_poisson"],
                                           density=cfg["ball_density_kg_m3"], frictionAngle=fa,
                                           label="ball"))
        facets = []
        for t in tri:
            fb = utils.facet([Vector3(*t[0]), Vector3(*t[1]), Vector3(*t[2])], material=wall,
                             fixed=True, wire=True)
            fb.mask = JAR_MASK
            facets.append(fb)
        self.jar_ids = O.bodies.append(facets)
        pos, vel = start_state(cfg, tri, self.info)
        sb = utils.sphere(Vector3(*pos), self.r, material=ball)
        sb.mask = BALL_MASK
        self.ball_id = O.bodies.append(sb)
        b = O.bodies[self.ball_id]
        b.state.vel = Vector3(*vel)
        self.mass = b.state.mass
        self.jar_x0 = O.bodies[self.jar_ids[0]].state.pos[0]

        flat = cfg["facet_contact"] == "flat"
        if flat:
            rmean = 0.5 * (HERTZIAN_FACET_RADIUS_FACTOR + 1.0) * self.r
        else:
            rmean = 0.5 * (2.0 + 1.0) * self.r
        eta = cfg["rolling_friction"] * self.r / rmean  # cap = eta * Rmean * |Fn| = RF r |Fn|
        # rolling stiffness: the elastic rolling angle at the cap stays below 1e-2 rad up to
        # |Fn| = 100 N, so the rolling moment behaves as a constant-torque (EDEM-like) model
        krot = cfg["rolling_friction"] * self.r * 100.0 / 1e-2 if cfg["rolling_friction"] > 0 else 0.0
        if cfg["rolling_model"] == "constant_torque":
            # EDEM's directional constant torque: the cap at |Fn| = 1 kN within 2e-4 rad, so
            # the capped torque acts from the first steps of an impact (ROLLING_CDT_FACTOR)
            krot *= ROLLING_CDT_FACTOR
        self.law = Law2_ScGeom_MindlinPhys_Mindlin(includeMoment=cfg["rolling_friction"] > 0)
        if self.frame == "lab":
            self.motion = HarmonicMotionEngine(ids=self.jar_ids, A=Vector3(self.A, 0, 0),
                                               f=Vector3(0, 0, 0), fi=Vector3(0, 0, 0))
            drive = self.motion
        else:
            # jar frame: the facets stay put; the ball feels -m a_jar(t) (set_frequency)
            self.motion = None
            self.inertial = HarmonicForceEngine(ids=[self.ball_id], A=Vector3(0, 0, 0),
                                                f=Vector3(0, 0, 0), fi=Vector3(0, 0, 0))
            drive = self.inertial
        self.phi0 = 0.0            # phase at t_phi0
        self.t_phi0 = 0.0
        self.f_now = 0.0
        n_sample = max(1, int(round(1.0 / (cfg["output_fps"] * self.dt))))
        self.sample_period = n_sample * self.dt
        t_c = hertz_contact_time(cfg, 5.0)
        self.k_free = max(1, int(min(20e-6, t_c / 8.0) / self.dt))
        self.k_contact = max(1, int(4e-6 / self.dt))
        self.sampler = PyRunner(iterPeriod=n_sample, command="TWIN.on_sample()", label="sampler")
        self.monitor = PyRunner(iterPeriod=self.k_free, command="TWIN.on_contact_check()",
                                label="contacts")
        O.engines = [
            ForceResetter(),
            # verletDist: YADE's default (half the smallest radius, 5 mm here) makes the ball's
            # box reach every facet of the cylinder; 0.5 mm keeps ~10x fewer candidate pairs
            InsertionSortCollider([Bo1_Sphere_Aabb(), Bo1_Facet_Aabb()],
                                  avoidSelfInteractionMask=JAR_MASK, verletDist=5e-4),
            InteractionLoop([Ig2_Facet_Sphere_ScGeom(hertzian=flat)],
                            [Ip2_FrictMat_FrictMat_MindlinPhys(en=self.en_yade, eta=eta,
                                                               krot=krot)],
                            [self.law]),
            drive,
            NewtonIntegrator(gravity=Vector3(0, 0, -cfg["gravity_m_s2"]), damping=0.0,
                             mask=NEWTON_JAR_FRAME_MASK if self.frame == "jar" else 0),
            self.sampler,
            self.monitor,
        ]
        O.dt = self.dt
        self.set_frequency(self.f_target if self.phase != "ramp" else 0.0)
        self.t_c = t_c

    # -- jar motion --
    def jar_x(self):
        """Jar displacement from its rest position along x [m], in the lab, after the step
        (lab frame: the facets' integrated motion; jar frame: the imposed A sin phi)."""
        if self.frame == "lab":
            return O.bodies[self.jar_ids[0]].state.pos[0] - self.jar_x0
        return self.A * math.sin(self.phase_at(O.time + self.dt))

    def jar_v(self):
        """Jar velocity along x [m/s] in the lab over the step (lab frame: the facets'; jar
        frame: the imposed A w cos phi at mid-step, as the lab frame's engine sets it)."""
        if self.frame == "lab":
            return O.bodies[self.jar_ids[0]].state.vel[0]
        return self.A * 2 * math.pi * self.f_now * math.cos(self.phase_at(O.time + 0.5 * self.dt))

    def sim_jar_x(self):
        """Jar displacement in the frame the scene is integrated in (0 in the jar frame)."""
        return self.jar_x() if self.frame == "lab" else 0.0

    def phase_at(self, t):
        return self.phi0 + 2 * math.pi * self.f_now * (t - self.t_phi0)

    def set_frequency(self, f):
        """Change the engine's frequency keeping the jar's phase continuous (O.time-safe)."""
        t = O.time
        phi = self.phase_at(t)
        w_old = 2 * math.pi * self.f_now
        self.phi0, self.t_phi0, self.f_now = phi, t, f
        w = 2 * math.pi * f
        if self.frame == "lab":
            # engine velocity -A w sin(w t + fi) must equal A w cos(phi(t + dt/2)) (mid-step)
            fi = phi + w * (0.5 * self.dt - t) - 0.5 * math.pi
            self.motion.f = Vector3(f, 0, 0)
            self.motion.fi = Vector3(fi, 0, 0)
        else:
            # the lab frame's jar velocity jumps by A (w - w_old) cos phi at a change of
            # frequency: the ball's velocity relative to the jar jumps the other way
            ball = O.bodies[self.ball_id].state
            kick = self.A * (w - w_old) * math.cos(phi + w * 0.5 * self.dt)
            ball.vel = ball.vel - Vector3(kick, 0, 0)
            # -m a_jar = m A w^2 sin(phi(t)) at the engine's time t: A_F sin(2 pi f t + fi)
            self.inertial.A = Vector3(self.mass * self.A * w * w, 0, 0)
            self.inertial.f = Vector3(f, 0, 0)
            self.inertial.fi = Vector3(phi - w * t, 0, 0)
        for e in self.effects:
            e.on_frequency(self, f, phi, t)

    # -- per-sample work: trajectory, protocol, escape check --
    def on_sample(self):
        t = O.time
        for e in self.effects:
            e.on_sample(self, t)
        s = O.bodies[self.ball_id].state
        jar_x = self.jar_x()
        jar_v = self.jar_v()
        p, v, w = s.pos, s.vel, s.angVel
        rel = (p[0] - self.sim_jar_x(), p[1], p[2])
        if self.frame == "jar":  # the recording is in the lab frame
            p = Vector3(p[0] + jar_x, p[1], p[2])
            v = Vector3(v[0] + jar_v, v[1], v[2])
        half = self.info["inner_length_m"] / 2.0
        rad = self.info["inner_diameter_m"] / 2.0
        tol = 0.25 * self.r
        if abs(rel[0]) > half + tol or math.hypot(rel[1], rel[2]) > rad + tol or not all(
                math.isfinite(x) for x in (p[0], p[1], p[2], v[0], v[1], v[2])):
            self.fail("the ball left the jar at t = %.5f s (jar-frame position %.4g, %.4g, %.4g m):"
                      " the time step is too large for the contact stiffness or the STL leaks"
                      % (t, rel[0], rel[1], rel[2]))
            return
        if time.time() - self.wall_start > self.cfg["max_wall_s"]:
            self.fail("wall-time budget max_wall_s = %g s exceeded at t = %.4f s"
                      % (self.cfg["max_wall_s"], t))
            return
        speed = math.sqrt(v[0] ** 2 + v[1] ** 2 + v[2] ** 2)
        cfg = self.cfg
        if self.phase == "ramp":
            # the frequency set now holds until the next sample: take it at the interval's
            # midpoint, so the phase integral of the linear ramp is exact (no lag of pi f dt)
            frac = min(1.0, (t + 0.5 * self.sample_period) / cfg["ramp_s"])
            self.set_frequency(self.f_target * frac)
            if frac >= 1.0:
                self.phase = "settle"
                self.full_since = t
        elif self.phase == "settle":
            self.settle_step(t, speed)
        if self.phase == "record":
            self.rows.append((t, p[0], p[1], p[2], v[0], v[1], v[2], w[0], w[1], w[2], jar_x, jar_v))
            if t - self.record_start >= cfg["record_s"] - 0.5 * self.sample_period:
                self.done = True
                O.pause()

    def settle_step(self, t, speed):
        cfg = self.cfg
        if self.win_t0 is None:
            self.win_t0 = t
        self.win_speeds.append(speed)
        cycle = 1.0 / self.f_target if self.f_target > 0 else 0.02
        if t - self.win_t0 < cfg["steady_window_cycles"] * cycle:
            return
        mean = sum(self.win_speeds) / len(self.win_speeds)
        self.windows.append((t, mean))
        self.win_speeds, self.win_t0 = [], t
        waited = t - self.full_since
        steady = False
        if len(self.windows) >= 2 and waited >= cfg["settle_min_s"]:
            m0, m1 = self.windows[-2][1], self.windows[-1][1]
            steady = abs(m1 - m0) <= cfg["steady_tol"] * max(m1, 0.1)
        if steady or waited >= cfg["settle_max_s"]:
            self.steady = {"steady": bool(steady), "t_steady_s": t, "settle_s": waited,
                           "window_means_m_s": [round(m, 5) for _, m in self.windows]}
            self.phase = "record"
            self.record_start = t
            self.wall_record_start = time.time()
            # impacts that began before the record are not counted
            self.impacts = []

    # -- contact events --
    def jar_acceleration(self, t):
        """Jar acceleration along x [m/s2] (harmonic motion at the current frequency)."""
        w = 2 * math.pi * self.f_now
        return -self.A * w * w * math.sin(self.phase_at(t))

    @staticmethod
    def region_of(n_out):
        """Which surface a contact normal (ball centre -> contact point) belongs to."""
        if n_out[0] >= 0.5:
            return "end+"
        if n_out[0] <= -0.5:
            return "end-"
        return "cylinder"

    def on_contact_check(self):
        """Detect ball-wall contact events and measure them.

        A contact event is an uninterrupted contact with one surface: the +x end cap, the -x end
        cap or the cylinder (a ball rolling on the cylinder that then hits an end makes two
        events). Runs every ``k_free`` steps while no event is young and every ``k_contact`` steps
        while one is. The energy an event dissipates comes from the jar-frame energy balance,
        which needs only smooth quantities: E_diss = KE_rel(before) - KE_rel(after) + integral of
        m (g - a_jar) . v_rel dt (KE_rel includes spin; the wall is at rest in the jar frame, so
        the contacts' power is minus their dissipation once their elastic energy is back to 0).
        Concurrent events (rolling on the cylinder while hitting an end) each get the whole
        balance over their own interval.
        """
        t = O.time
        intrs = [i for i in O.interactions.withBody(self.ball_id) if i.isReal]
        s = O.bodies[self.ball_id].state
        vrel = s.vel - O.bodies[self.jar_ids[0]].state.vel
        if not intrs and not self.events:  # in flight: remember the state, nothing else
            self.prev_state = (t, vrel, s.angVel, s.inertia)
            return
        now = self.flight_state((t, vrel, s.angVel, s.inertia))
        prev = self.flight_state(self.prev_state) or now
        for ev in self.events.values():
            ev["w_ext"] += 0.5 * (ev["g_last"] + now["g"]) * (t - ev["t_last"])
            ev["g_last"], ev["t_last"] = now["g"], t
        if len(intrs) > 1 or self.suppressed:
            self.merge_contacts(intrs)
        by_region = {}
        for i in intrs:
            cp = i.geom.contactPoint
            n = cp - s.pos
            n = n / max(n.norm(), 1e-300)
            by_region.setdefault(self.region_of(n), []).append((i, n, cp))
        for region, items in by_region.items():
            fsum = Vector3(0, 0, 0)
            for i, n, cp in items:
                fn = i.phys.normalForce
                fsum += fn if i.id2 == self.ball_id else -fn
            fmag = fsum.norm()
            i0, n0, cp0 = items[0]
            ev = self.events.get(region)
            if ev is None:
                vn = prev["vrel"].dot(n0)
                pen = max(i.geom.penetrationDepth for i, _, _ in items)
                t0 = t - (pen / vn if vn > 1e-9 else t - prev["t"])
                t0 = min(t, max(t0, prev["t"]))
                ev = self.events[region] = {
                    "t_start": t0, "vn_in": vn, "vt_in": (prev["vrel"] - n0 * vn).norm(),
                    "n_out": n0, "fn_peak": 0.0, "n_facets": 0, "x_contact": 0.0,
                    "ke0": prev["ke"], "w_ext": 0.5 * (prev["g"] + now["g"]) * (t - prev["t"]),
                    "g_last": now["g"], "t_last": t, "region": region}
                for e in self.effects:
                    e.on_event_start(self, region, [i for i, _, _ in items], vn)
            ev["n_facets"] = max(ev["n_facets"], len(items))
            if self.effects:  # every interaction of the event, also facets reached later in it
                seen = ev.setdefault("seen", set())
                for i, _, _ in items:
                    key = (i.id1, i.id2)
                    if key not in seen:
                        seen.add(key)
                        for e in self.effects:
                            e.on_interaction_start(self, region, i, ev["vn_in"])
            if fmag > ev["fn_peak"]:
                ev["fn_peak"] = fmag
                ev["n_out"] = n0
                ev["x_contact"] = cp0[0] - self.sim_jar_x()
        for region in [r for r in self.events if r not in by_region]:
            ev = self.events.pop(region)
            if self.phase == "record":
                if region == "cylinder":
                    self.cyl_contact_time += t - ev["t_start"]
                self.impacts.append([len(self.impacts), ev["t_start"], t, ev["vn_in"], ev["vt_in"],
                                     -vrel.dot(ev["n_out"]), ev["fn_peak"],
                                     ev["ke0"] - now["ke"] + ev["w_ext"],
                                     "cylinder" if region == "cylinder" else "end_cap",
                                     ev["x_contact"], ev["n_facets"], -1])
        young = any(t - ev["t_start"] < 1e-3 for ev in self.events.values())
        self.monitor.iterPeriod = self.k_contact if young else self.k_free
        self.prev_state = (t, vrel, s.angVel, s.inertia)

    def flight_state(self, prev):
        """Energy and external power of a remembered flight state (or None)."""
        if prev is None:
            return None
        t, vrel, w, inertia = prev
        ke = 0.5 * self.mass * vrel.squaredNorm() + 0.5 * (inertia[0] * w[0] ** 2
                                                             + inertia[1] * w[1] ** 2
                                                             + inertia[2] * w[2] ** 2)
        g = self.mass * (-self.cfg["gravity_m_s2"] * vrel[2] - self.jar_acceleration(t) * vrel[0])
        return {"t": t, "vrel": vrel, "ke": ke, "g": g}

    prev_state = None
    suppressed = False
    #: contacts whose normals are closer than this (cosine) are one contact with the surface
    MERGE_COS = math.cos(math.radians(30.0))

    def merge_contacts(self, intrs):
        """One contact per surface: a ball touching a flat or gently curved wall near a facet
        edge overlaps two or more facets (face + edge contacts) and would feel the sum of their
        Hertz forces. Among contacts with normals within 30 degrees, only the deepest keeps its
        stiffness; the others get kno = kso = kr = 0 (no force) until they become the deepest.
        """
        ordered = sorted(intrs, key=lambda i: -i.geom.penetrationDepth)
        kept = []
        any_off = False
        for i in ordered:
            n = i.geom.normal
            ph = i.phys
            if any(n.dot(k.geom.normal) > self.MERGE_COS for k in kept):
                if ph.kno != 0.0:
                    if self.k_ref is None:
                        self.k_ref = (ph.kno, ph.kso, ph.kr)
                    ph.kno, ph.kso, ph.kr = 0.0, 0.0, 0.0
                    ph.shearElastic = Vector3(0, 0, 0)
                    ph.momentBend = Vector3(0, 0, 0)
                any_off = True
            else:
                if ph.kno == 0.0 and self.k_ref is not None:
                    ph.kno, ph.kso, ph.kr = self.k_ref
                elif self.k_ref is None:
                    self.k_ref = (ph.kno, ph.kso, ph.kr)
                kept.append(i)
        self.suppressed = any_off

    k_ref = None

    def fail(self, msg):
        self.error = msg
        O.pause()


# ----------------------------------------------------------------------------------------------
# recording
# ----------------------------------------------------------------------------------------------
def git_commit():
    try:
        out = subprocess.run(["git", "-C", ROOT, "rev-parse", "HEAD"], capture_output=True,
                             text=True, timeout=10)
        return out.stdout.strip() or None
    except (OSError, subprocess.SubprocessError):
        return None


def yade_version():
    import yade.config
    return getattr(yade.config, "version", "unknown")


def resolve_frame(cfg, effects):
    """'lab' or 'jar' for a config's ``frame`` and its effects ('auto': the jar frame unless
    an effect needs the lab frame). ConfigError for 'jar' with such an effect."""
    lab_only = [e.name for e in effects if getattr(e, "needs_lab_frame", False)]
    frame = cfg.get("frame", "lab")
    if frame == "auto":
        return "lab" if lab_only else "jar"
    if frame == "jar" and lab_only:
        raise ConfigError("frame 'jar' cannot run effect(s) %s: they move the jar itself (use "
                          "frame 'lab' or 'auto')" % ", ".join(lab_only))
    return frame


def group_collisions(impacts, frequency_hz):
    """Group end-cap contacts into collisions; set each impact row's collision_id.

    A ball with C_R = 0.11 leaving an end cap slowly is often caught again by the same cap a few
    milliseconds later (a re-contact at a fraction of a m/s). Such re-contacts are part of one
    collision: consecutive end-cap contacts at the same end, less than a quarter jar cycle apart,
    form one collision. Cylinder contacts get collision_id -1.

    Returns
    -------
    list of (t_start_s, side) per collision; side is +1 or -1 (the end hit, jar frame)
    """
    gap = 0.25 / frequency_hz if frequency_hz > 0 else 0.01
    impacts.sort(key=lambda row: row[1])  # events are appended when they end
    for k, row in enumerate(impacts):
        row[0] = k
    groups = []
    last_end = None  # (side, t_end)
    for row in impacts:
        if row[8] != "end_cap":
            row[11] = -1
            continue
        side = 1 if row[9] > 0 else -1
        if last_end is not None and last_end[0] == side and row[1] - last_end[1] < gap:
            row[11] = len(groups) - 1
        else:
            groups.append((row[1], side))
            row[11] = len(groups) - 1
        last_end = (side, row[2])
    return groups


def summarize(twin):
    cfg = twin.cfg
    traj = np.array(twin.rows, dtype=float).reshape(-1, len(TRAJ_COLUMNS))
    v = traj[:, 4:7]
    speed = np.linalg.norm(v, axis=1)
    vrel = v.copy()
    vrel[:, 0] -= traj[:, 11]
    duration = cfg["record_s"]
    groups = group_collisions(twin.impacts, cfg["frequency_hz"])
    end_times = np.array([g[0] for g in groups])
    end_sides = np.array([g[1] for g in groups])
    v_mean = float(speed.mean()) if len(speed) else float("nan")
    cyl_frac = twin.cyl_contact_time / duration if duration > 0 else 0.0
    f_col, f_col_se = collision_rate(end_times, duration)
    mode, stats = classify_motion(v_mean, max(cfg["frequency_hz"], 1e-12), end_times, end_sides,
                                  duration, cyl_frac)
    return {
        "v_mean_m_s": v_mean,
        "v_mean_jar_m_s": float(np.linalg.norm(vrel, axis=1).mean()) if len(speed) else None,
        "vx_abs_mean_m_s": float(np.abs(v[:, 0]).mean()) if len(speed) else None,
        "e_kin_j": 0.5 * twin.mass * v_mean ** 2,
        "f_col_hz": f_col,
        "f_col_se_hz": f_col_se,
        "n_impacts": len(twin.impacts),
        "n_end_impacts": sum(1 for row in twin.impacts if row[8] == "end_cap"),
        "n_collisions": len(groups),
        "motion_mode": mode,
        "motion_stats": stats,
    }


def write_outputs(twin, out_dir, wall_s, steps):
    parent = os.path.dirname(os.path.abspath(out_dir)) or "."
    os.makedirs(parent, exist_ok=True)
    tmp = os.path.join(parent, ".tmp-%s-%d" % (os.path.basename(out_dir), os.getpid()))
    if os.path.exists(tmp):
        shutil.rmtree(tmp)
    os.makedirs(tmp)
    try:
        meta = _write_files(twin, tmp, wall_s, steps)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    if os.path.lexists(out_dir):
        # checked before the run (main); checked again here, as the folder may have changed
        # meanwhile: the old folder is moved away first and removed only once the new one is in
        if not (os.path.isdir(out_dir) and not os.path.islink(out_dir)
                and may_replace(out_dir)):
            shutil.rmtree(tmp, ignore_errors=True)
            raise OutRefused("--out %s was changed during the run and now holds files this "
                             "project did not write; the recording is not written" % out_dir)
        old = os.path.join(parent, ".old-%s-%d" % (os.path.basename(out_dir), os.getpid()))
        os.rename(out_dir, old)
        os.rename(tmp, out_dir)
        shutil.rmtree(old, ignore_errors=True)
    else:
        os.rename(tmp, out_dir)
    return meta


def _write_files(twin, tmp, wall_s, steps):
    cfg = twin.cfg
    summary = summarize(twin)  # also numbers the collisions in twin.impacts
    with open(os.path.join(tmp, "trajectory.csv"), "w") as fh:
        fh.write(",".join(TRAJ_COLUMNS) + "\n")
        for row in twin.rows:
            fh.write(",".join("%.9g" % x for x in row) + "\n")
    with open(os.path.join(tmp, "impacts.csv"), "w") as fh:
        fh.write(",".join(IMPACT_COLUMNS) + "\n")
        for row in twin.impacts:
            fh.write("%d,%.9g,%.9g,%.6g,%.6g,%.6g,%.6g,%.6g,%s,%.6g,%d,%d\n" % tuple(row))
    meta = {
        "config": cfg,
        "run_id": twin_config.run_id(cfg, ROOT),
        "yade_version": yade_version(),
        "python_version": sys.version.split()[0],
        "dt_s": twin.dt,
        "steps": int(steps),
        "sim_time_s": O.time,
        "wall_s": wall_s,
        "steps_per_s": steps / wall_s if wall_s > 0 else None,
        "wall_record_s": time.time() - twin.wall_record_start,
        "git_commit": git_commit(),
        "seed": cfg["seed"],
        "record_start_s": twin.record_start,
        "output_fps_actual": 1.0 / twin.sample_period,
        "ball_mass_kg": twin.mass,
        "jar": {k: twin.info[k] for k in ("inner_length_m", "inner_diameter_m", "volume_m3",
                                          "n_facets", "stl_path")},
        "contact_sampling_s": {"free": twin.k_free * twin.dt, "in_contact": twin.k_contact * twin.dt},
        "hertz_contact_time_5m_s_s": twin.t_c,
        "en_yade": twin.en_yade,
        "restitution_scratch_check": twin.en_check,
        "protocol": cfg["protocol"],
        "frame": twin.frame,
        "effects": [e.describe() for e in twin.effects],
        "steady": twin.steady,
        "summary": summary,
    }
    with open(os.path.join(tmp, "meta.json"), "w") as fh:
        json.dump(meta, fh, indent=1, sort_keys=True)
    return meta


def step_until_done(twin, n_max):
    """Run at most ``n_max`` steps until the record is complete or the run failed.

    The steps are driven from this thread (``O.step``) rather than by ``O.run``: the
    PyRunners (sampler, contact monitor) then run in the thread that holds Python, and the
    hand-over of the interpreter between YADE's simulation thread and this one - about
    30-50 us per call, most of a contact check - is saved. The engines, and so the results,
    are the same step for step."""
    step = O.step
    end = O.iter + n_max
    while not twin.done and twin.error is None and O.iter < end:
        step()


def build_twin(cfg):
    """The scene of a complete config, registered as TWIN (the PyRunners' name for it), and
    the most steps its protocol may take."""
    tri, info = load_jar(cfg)
    effects = load_effects(cfg["effects"], side="dem")  # ConfigError on unknown names/params
    twin = Twin(cfg, tri, info, effects)
    globals()["TWIN"] = twin
    import __main__
    __main__.TWIN = twin
    t_max = (cfg["ramp_s"] + cfg["settle_max_s"] + cfg["record_s"] + 1.0
             if cfg["protocol"] == "mill" else cfg["record_s"] + 1.0)
    return twin, int(t_max / cfg["dt_s"]) + 10


def run(cfg, out_dir):
    twin, n_max = build_twin(cfg)
    wall0 = time.time()
    it0 = O.iter
    step_until_done(twin, n_max)
    wall = time.time() - wall0
    if twin.error:
        raise RunFailure(twin.error)
    if not twin.done:
        raise RunFailure("the run ended at t = %.4f s before its record was complete" % O.time)
    return write_outputs(twin, out_dir, wall, O.iter - it0)


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    try:
        batch = config_from_batch_table()
        if batch is not None:
            user, out = batch
            cfg = twin_config.complete_config(user)
        else:
            a = parse_args(argv)
            if not a.config:
                raise ConfigError("--config run.json is required (outside yade-batch)")
            cfg = twin_config.load_config(a.config)
            out = a.out
        load_effects(cfg["effects"])    # unknown effects or parameters: before any output
        if not out:
            out = os.path.join(ROOT, "results", "runs", twin_config.run_id(cfg, ROOT))
        out = os.path.abspath(out)
        # the output rule (out_rule.py), before any simulation: never replace what was not
        # written by this project, nor an input of the run
        inputs = [] if batch is not None else [a.config]
        if not twin_config.parametric_jar(cfg):
            inputs.append(twin_config.resolve_stl(cfg, ROOT))
        out = check_run_out(out, ROOT, inputs)
        meta = run(cfg, out)
    except (ConfigError, MeshError, OutRefused) as exc:
        sys.stderr.write("mill.py: error: %s\n" % exc)
        return 2
    except RunFailure as exc:
        sys.stderr.write("mill.py: run failed: %s\n" % exc)
        return 3
    s = meta["summary"]
    print("mill.py: wrote %s: v_mean %.3f m/s, f_col %.1f /s, mode %s, %d steps in %.1f s "
          "(%.0f steps/s)" % (out, s["v_mean_m_s"], s["f_col_hz"], s["motion_mode"],
                              meta["steps"], meta["wall_s"], meta["steps_per_s"] or 0))
    return 0


if __name__ == "__main__":
    rc = main()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(rc)
