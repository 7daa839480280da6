"""The YADE scene checked against physics: restitution, energy, kinematics, collisions, failures.

Every test starts YADE (Debian's package) as a subprocess through analysis.twin.
"""
import json
import math
import os
import shutil
import subprocess

import numpy as np
import pytest

from analysis.config import MILL_SCRIPT, REPO_ROOT, twin_config
from analysis.twin import TwinRunError, load_recording, run_twin
from geometry.jar import make_jar
from geometry.stl_io import write_stl

pytestmark = pytest.mark.yade

STILL = {"protocol": "free", "amplitude_m": 0.0, "gravity_m_s2": 0.0, "ball_start": "given"}


def run(cfg, tmp_path, **kw):
    return load_recording(run_twin(cfg, runs_dir=tmp_path / "runs", **kw))


def jar_frame_bounds(rec):
    j = rec.meta["jar"]
    r = rec.config["ball_diameter_m"] / 2.0
    return j["inner_length_m"] / 2.0 - r, j["inner_diameter_m"] / 2.0 - r


def assert_ball_inside(rec):
    """The ball centre never leaves the cavity (jar frame) by more than a contact overlap.

    The Hertz overlap of the steel ball on PMMA at 4 m/s is about 0.3 mm (3 % of the 20.6 mm
    ball's radius); 5 % of the radius is allowed."""
    t = rec.trajectory
    half, rad = jar_frame_bounds(rec)
    tol = 0.05 * rec.config["ball_diameter_m"] / 2.0
    x = t["x_m"] - t["jar_x_m"]
    assert (x.abs() <= half + tol).all()
    assert (np.hypot(t["y_m"], t["z_m"]) <= rad + tol).all()


@pytest.mark.parametrize("en, v0, frame", [(0.11, 0.5, "lab"), (0.11, 1.0, "lab"),
                                           (0.11, 2.0, "lab"), (0.11, 4.0, "lab"),
                                           (0.7, 4.0, "lab"), (0.11, 2.0, "jar"),
                                           (0.7, 4.0, "jar")])
def test_restitution_on_a_static_facet_wall(en, v0, frame, tmp_path):
    """A ball thrown along the axis at the flat end cap rebounds with en (within 1 %), in both
    frames the scene can be integrated in."""
    gap = 0.0212 - 0.0103
    cfg = dict(STILL, restitution=en, ball_init_pos_m=[0.0, 0.0, 0.0],
               ball_init_vel_m_s=[v0, 0.0, 0.0], frame=frame)
    # one flight to the cap, and for en = 0.7 the chain of bounces down to 0.5 m/s
    cfg["record_s"] = gap / v0 * 1.2 + (0.3 if en == 0.7 else 0.002)
    rec = run(cfg, tmp_path)
    imp = rec.impacts[(rec.impacts["vn_in_m_s"] >= 0.45) & (rec.impacts["where"] == "end_cap")]
    expect = 1 if en == 0.11 else 6  # 4, 2.8, 1.96, 1.37, 0.96, 0.67 m/s
    assert len(imp) >= expect
    e = imp["vn_out_m_s"] / imp["vn_in_m_s"]
    assert np.all(np.abs(e / en - 1.0) < 0.01), e.tolist()
    # the energy the event dissipated is the kinetic energy lost: m/2 vn^2 (1 - e^2)
    m = rec.meta["ball_mass_kg"]
    lost = 0.5 * m * imp["vn_in_m_s"] ** 2 * (1 - e ** 2)
    assert np.allclose(imp["e_diss_j"], lost, rtol=0.02)
    assert_ball_inside(rec)


def test_kinetic_energy_is_conserved_without_dissipation(tmp_path, frame="lab"):
    """en = 1, no friction, no gravity, jar at rest: KE between contacts holds within 0.5 %."""
    cfg = dict(STILL, restitution=1.0, static_friction=0.0, rolling_friction=0.0,
               ball_init_pos_m=[0.0, 0.001, 0.0], ball_init_vel_m_s=[2.0, 0.6, 0.35],
               record_s=0.1, frame=frame)
    rec = run(cfg, tmp_path)
    t = rec.trajectory
    imp = rec.impacts
    assert len(imp) >= 5  # it really bounced off the caps and the cylinder
    assert set(imp["where"]) == {"end_cap", "cylinder"}
    free = np.ones(len(t), bool)
    for a, b in zip(imp["t_start_s"], imp["t_end_s"]):
        free &= ~((t["t_s"] >= a - 1e-6) & (t["t_s"] <= b + 1e-6))
    v2 = (t[["vx_m_s", "vy_m_s", "vz_m_s"]] ** 2).sum(axis=1)[free]
    ke = 0.5 * rec.meta["ball_mass_kg"] * v2
    ke0 = 0.5 * rec.meta["ball_mass_kg"] * (2.0 ** 2 + 0.6 ** 2 + 0.35 ** 2)
    assert np.max(np.abs(ke / ke0 - 1.0)) < 0.005
    assert_ball_inside(rec)


@pytest.mark.parametrize("frame", ["lab", "jar"])
def test_jar_follows_the_harmonic_motion(frame, tmp_path):
    """x_jar = A sin(2 pi f t) about the start position (protocol 'free': no ramp); in the jar
    frame the recording restores it from the imposed motion."""
    A, f = 0.0135, 30.0
    cfg = {"protocol": "free", "amplitude_m": A, "frequency_hz": f, "ball_start": "center",
           "record_s": 0.1, "frame": frame}
    rec = run(cfg, tmp_path)
    assert rec.meta["frame"] == frame
    t = rec.trajectory
    expect = A * np.sin(2 * np.pi * f * t["t_s"])
    assert np.max(np.abs(t["jar_x_m"] - expect)) < 1e-3 * A
    vexp = A * 2 * np.pi * f * np.cos(2 * np.pi * f * (t["t_s"] - rec.meta["dt_s"] / 2))
    assert np.max(np.abs(t["jar_vx_m_s"] - vexp)) < 2e-3 * A * 2 * np.pi * f


@pytest.mark.slow
def test_ramp_is_phase_continuous_and_collisions_are_2f_at_30_hz(tmp_path):
    """Mill protocol at 30 Hz: after the linear frequency ramp the jar is at A sin(phi(t)) with
    phi = pi f T + 2 pi f (t - T); the ball flies end to end: the count from impacts.csv is
    2 f +- 1 /s and f_col, the rate from the impact times, 2 f within 0.3 %."""
    A, f, T = 0.0135, 30.0, 0.3
    cfg = {"frequency_hz": f, "ball_diameter_m": 0.0206, "amplitude_m": A, "ramp_s": T,
           "settle_min_s": 0.2, "record_s": 1.0, "seed": 1}
    rec = run(cfg, tmp_path)
    t = rec.trajectory
    phi = np.pi * f * T + 2 * np.pi * f * (t["t_s"] - T)
    assert np.max(np.abs(t["jar_x_m"] - A * np.sin(phi))) < 2e-3 * A
    s = rec.summary
    assert rec.meta["steady"]["steady"]
    assert s["motion_mode"] == "end_to_end", s
    assert abs(s["f_col_hz"] / (2 * f) - 1) <= 0.003, s
    assert s["f_col_se_hz"] <= 0.003 * 2 * f
    # the same count straight from impacts.csv: collisions are the distinct collision ids
    ends = rec.impacts[rec.impacts["where"] == "end_cap"]
    n = ends["collision_id"].nunique()
    assert abs(n / rec.config["record_s"] - 2 * f) <= 1.0
    assert_ball_inside(rec)


@pytest.mark.parametrize("frame", ["lab", "jar"])
def test_same_config_and_seed_give_identical_trajectories(frame, tmp_path):
    cfg = {"protocol": "free", "amplitude_m": 0.0135, "frequency_hz": 25.0, "ball_start": "random",
           "seed": 7, "record_s": 0.08, "frame": frame}
    a = run_twin(cfg, runs_dir=tmp_path / "a")
    b = run_twin(cfg, runs_dir=tmp_path / "b")
    assert (a / "trajectory.csv").read_bytes() == (b / "trajectory.csv").read_bytes()
    c = run_twin(dict(cfg, seed=8), runs_dir=tmp_path / "a")
    assert (a / "trajectory.csv").read_bytes() != (c / "trajectory.csv").read_bytes()


def test_cached_run_is_not_recomputed(tmp_path):
    cfg = dict(STILL, ball_init_pos_m=[0, 0, 0], ball_init_vel_m_s=[1.0, 0, 0], record_s=0.005)
    a = run_twin(cfg, runs_dir=tmp_path)
    stamp = (a / "meta.json").stat().st_mtime_ns
    assert run_twin(cfg, runs_dir=tmp_path) == a
    assert (a / "meta.json").stat().st_mtime_ns == stamp


def yade_cli(tmp_path, cfg):
    p = tmp_path / "cfg.json"
    p.write_text(json.dumps(cfg))
    out = tmp_path / "out"
    proc = subprocess.run(["yade", "-n", "-x", str(MILL_SCRIPT), "--config", str(p), "--out",
                           str(out)], cwd=str(REPO_ROOT), capture_output=True, text=True,
                          stdin=subprocess.DEVNULL, timeout=600)
    return proc, out


def test_a_too_large_time_step_loses_the_ball_and_fails_clearly(tmp_path):
    cfg = dict(STILL, dt_s=2e-3, output_fps=100.0, ball_init_pos_m=[0, 0, 0],
               ball_init_vel_m_s=[4.0, 0, 0], record_s=0.05, restitution_compensation=False)
    proc, out = yade_cli(tmp_path, cfg)
    assert proc.returncode == 3
    assert "left the jar" in proc.stderr
    assert not out.exists()
    assert not list(tmp_path.glob(".tmp-*"))


@pytest.mark.parametrize("cfg, msg", [
    ({"frequency_hz": -25.0}, "frequency_hz"),
    ({"restitution": 1.5}, "restitution"),
    ({"ball_diameter_m": 0.030}, "larger than the jar"),
    ({"color": "red"}, "unknown config key"),
    ({"stl_path": "geometry/missing.stl"}, "cannot read STL"),
])
def test_bad_input_gives_one_error_and_no_run(tmp_path, cfg, msg):
    proc, out = yade_cli(tmp_path, cfg)
    assert proc.returncode == 2, proc.stderr[-500:]
    err = [ln for ln in proc.stderr.splitlines() if ln.startswith("mill.py")]
    assert len(err) == 1 and msg in err[0]
    assert not out.exists()


def test_leaky_or_unreadable_stl_is_refused(tmp_path):
    tri, _ = make_jar(n_circ=16)
    leaky = tmp_path / "leaky.stl"
    write_stl(str(leaky), tri[3:] * 1e3)
    proc, out = yade_cli(tmp_path, {"stl_path": str(leaky)})
    assert proc.returncode == 2 and "not closed" in proc.stderr
    junk = tmp_path / "junk.stl"
    junk.write_bytes(b"\x00\x01 not an stl")
    proc, out = yade_cli(tmp_path, {"stl_path": str(junk)})
    assert proc.returncode == 2 and "STL" in proc.stderr
    assert not out.exists()
    with pytest.raises(twin_config.ConfigError):
        run_twin({"restitution": 0.0}, runs_dir=tmp_path)


def test_run_twin_reports_yade_failure(tmp_path):
    with pytest.raises(TwinRunError, match="left the jar"):
        run_twin(dict(STILL, dt_s=2e-3, output_fps=100.0, ball_init_pos_m=[0, 0, 0],
                      ball_init_vel_m_s=[4.0, 0, 0], record_s=0.05,
                      restitution_compensation=False), runs_dir=tmp_path)


@pytest.mark.slow
def test_yade_batch_runs_a_parameter_table(tmp_path):
    """The same script under yade-batch: table columns are config keys, one run per line -
    the dict of effects and the list of a given start position as analysis.sweep's
    write_yade_batch_table writes them."""
    if shutil.which("yade-batch") is None:
        pytest.skip("yade-batch not installed")
    out1, out2 = tmp_path / "r1", tmp_path / "r2"
    table = tmp_path / "table.txt"
    # values are Python literals (yade-batch evaluates them): strings are quoted
    table.write_text(
        "description protocol amplitude_m frequency_hz ball_start ball_init_pos_m record_s seed"
        " effects out\n"
        "run25 'free' 0.0135 25.0 'random' None 0.01 1 {} 'r1'\n"
        "run30 'free' 0.0135 30.0 'given' [0.0,0.0,0.0] 0.01 2 {'air_drag':{'drag_scale':0.5}}"
        " 'r2'\n")
    proc = subprocess.run(["yade-batch", "--job-threads=1", "-j", "2", "--log",
                           str(tmp_path / "@.log"), str(table), str(MILL_SCRIPT)],
                          cwd=str(tmp_path), capture_output=True, text=True,
                          stdin=subprocess.DEVNULL, timeout=900)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    assert "FAILED" not in proc.stdout + proc.stderr, proc.stdout[-2000:]
    m1 = json.loads((out1 / "meta.json").read_text())
    m2 = json.loads((out2 / "meta.json").read_text())
    assert m1["config"]["frequency_hz"] == 25.0 and m2["config"]["frequency_hz"] == 30.0
    assert m1["config"]["effects"] == {} and m2["config"]["ball_init_pos_m"] == [0.0, 0.0, 0.0]
    assert m2["config"]["effects"] == {"air_drag": {"drag_scale": 0.5}}


def test_scene_profile_books_every_step_and_engine(tmp_path):
    """The profiler of the real scene (yade_scripts/profile_scene.py): a short free run in a
    jar at 25 Hz books every probed step to flight or contact, every engine of the scene has
    a share, the shares of a state sum to 1, and the jar's facets (motion engine + Newton)
    take most of a flight step."""
    from analysis.bench.profile import profile_case, table
    prof = profile_case({"protocol": "free", "dt_s": 5e-7, "frequency_hz": 25.0,
                         "ball_start": "random", "record_s": 0.01, "seed": 3}, tmp_path)
    assert prof["done"] and prof["error"] is None
    booked = sum(prof["state_steps"].values())
    assert prof["steps"] - 2 * prof["probe_steps"] <= booked <= prof["steps"]
    t = table("short", prof)
    fl = t[t["state"] == "flight"].set_index("engine")
    for e in ("NewtonIntegrator", "HarmonicMotionEngine", "InteractionLoop", "sampler",
              "contacts"):
        assert e in fl.index and fl.loc[e, "share"] > 0
    assert fl["share"].sum() == pytest.approx(1.0, abs=1e-9)
    assert (fl.loc["NewtonIntegrator", "share"] + fl.loc["HarmonicMotionEngine", "share"]) > 0.5
    assert (fl["calls"] >= 0).all()


def test_jar_frame_reproduces_the_lab_frame_run(tmp_path):
    """One short run at 25 Hz from the same start in both frames: the jar frame (static facets,
    the inertial force -m a_jar on the ball, the recording restored to the lab) follows the
    lab frame's trajectory to 1e-7 m and 1e-5 m/s through its first impacts (before the
    chaos separates them), with the same impacts; the lab frame's run id is the one configs
    without ``frame`` had."""
    cfg = {"protocol": "free", "dt_s": 5e-7, "frequency_hz": 25.0, "ball_start": "random",
           "record_s": 0.025, "seed": 3}
    lab = run(dict(cfg, frame="lab"), tmp_path)
    jar = run(dict(cfg, frame="jar"), tmp_path)
    assert (lab.meta["frame"], jar.meta["frame"]) == ("lab", "jar")
    assert twin_config.run_id(dict(cfg, frame="lab")) == twin_config.run_id(cfg)
    assert twin_config.run_id(dict(cfg, frame="jar")) != twin_config.run_id(cfg)
    a, b = lab.trajectory, jar.trajectory
    assert len(a) == len(b)
    assert np.max(np.abs(b["x_m"] - a["x_m"])) < 1e-7
    assert np.max(np.abs(b["vx_m_s"] - a["vx_m_s"])) < 1e-5
    assert np.max(np.abs(b["jar_x_m"] - a["jar_x_m"])) < 1e-7
    assert len(lab.impacts) == len(jar.impacts) >= 1
    assert np.allclose(jar.impacts["vn_in_m_s"], lab.impacts["vn_in_m_s"], rtol=1e-3)
    assert np.allclose(jar.impacts["x_contact_jar_m"], lab.impacts["x_contact_jar_m"],
                       atol=1e-6)


def test_effects_that_move_the_jar_keep_the_lab_frame(tmp_path):
    """'auto' runs arc motion in the lab frame and a contact effect in the jar frame; 'jar'
    with an effect that moves the jar is refused with one error naming it."""
    cfg = {"protocol": "free", "frequency_hz": 25.0, "ball_start": "center", "record_s": 0.005,
           "frame": "auto"}
    rec = run(dict(cfg, effects={"arc_motion": {"curvature_1_m": 5.0}}), tmp_path)
    assert rec.meta["frame"] == "lab"
    rec = run(dict(cfg, effects={"viscoelastic_restitution": {"k": 0.3}}), tmp_path)
    assert rec.meta["frame"] == "jar"
    with pytest.raises(TwinRunError, match="arc_motion"):
        run(dict(cfg, frame="jar", effects={"arc_motion": {"curvature_1_m": 5.0}}), tmp_path)


@pytest.mark.parametrize("frame", ["jar", "lab"])
def test_parametric_jar_sets_where_the_ball_meets_the_end(frame, tmp_path):
    """A ball thrown along the axis of a parametric jar (D 30 mm, L 60 mm) meets the end cap
    after the flight the dimensions give, (L/2 - r) / v0, and the recording names the jar."""
    v0, d = 1.0, 0.0175
    cfg = dict(STILL, ball_diameter_m=d, ball_init_pos_m=[0.0, 0.0, 0.0],
               ball_init_vel_m_s=[v0, 0.0, 0.0], record_s=0.03, frame=frame,
               jar_inner_diameter_m=0.030, jar_inner_length_m=0.060)
    rec = run(cfg, tmp_path)
    j = rec.meta["jar"]
    assert j["stl_path"] == "parametric"
    assert j["inner_length_m"] == pytest.approx(0.060, rel=1e-9)
    assert j["inner_diameter_m"] == pytest.approx(0.030, rel=1e-9)
    first = rec.impacts.sort_values("t_start_s").iloc[0]
    assert first["where"] == "end_cap"
    assert first["t_start_s"] == pytest.approx((0.030 - d / 2) / v0, abs=2e-5)
    assert_ball_inside(rec)
