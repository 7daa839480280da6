"""The jar mesh: volume, closure, orientation, units, bad files (no YADE needed)."""
import numpy as np
import pytest
import trimesh

from analysis.config import DEFAULT_STL, twin_config
from geometry.jar import jar_triangles, make_jar, main as jar_main
from geometry.stl_io import (MeshError, check_jar_mesh, edge_defects, read_stl, scale_for_units,
                             signed_volume, write_stl)


def test_committed_stl_is_25_ml_closed_and_inward():
    tri = read_stl(str(DEFAULT_STL))
    info = check_jar_mesh(tri, scale_for_units(tri, "auto"))
    assert abs(info["volume_m3"] * 1e6 - 25.0) <= 0.3
    assert edge_defects(tri) == (0, 0)
    # an independent check with trimesh: watertight, consistent winding, and a negative signed
    # volume (normals point into the cavity)
    m = trimesh.load(str(DEFAULT_STL))
    assert m.is_watertight and m.is_winding_consistent
    assert m.volume < 0
    assert abs(-m.volume * 1e-3 - 25.0) <= 0.3


def test_every_normal_points_into_the_cavity():
    tri, length = make_jar(n_circ=24)
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    c = tri.mean(axis=1)
    # the cavity is convex: the centre lies on the inner side of every facet's plane
    assert np.all(np.einsum("ij,ij->i", n, -c) > 0)


@pytest.mark.parametrize("n_circ", [16, 32, 48])
def test_volume_is_solved_at_every_resolution(n_circ):
    tri, length = make_jar(n_circ=n_circ)
    assert abs(-signed_volume(tri) - 25.0e-6) < 1e-9
    assert 0.040 < length < 0.046


def test_axis_point_is_inside_one_cap_facet_only():
    """No vertex on the axis: a ball arriving along the axis touches one facet, not a fan."""
    tri, length = make_jar()
    v = tri.reshape(-1, 3)
    assert np.hypot(v[:, 1], v[:, 2]).min() > 1e-3


def test_units_mm_and_m_give_the_same_jar(tmp_path):
    tri, _ = make_jar(n_circ=16)
    write_stl(str(tmp_path / "mm.stl"), tri * 1e3)
    write_stl(str(tmp_path / "m.stl"), tri)
    a = read_stl(str(tmp_path / "mm.stl"))
    b = read_stl(str(tmp_path / "m.stl"))
    ia = check_jar_mesh(a, scale_for_units(a, "auto"))
    ib = check_jar_mesh(b, scale_for_units(b, "auto"))
    assert ia["volume_m3"] == pytest.approx(ib["volume_m3"], rel=1e-5)
    assert ia["inner_diameter_m"] == pytest.approx(0.028, rel=1e-5)


def test_ascii_stl_is_read(tmp_path):
    tri, _ = make_jar(n_circ=8)
    lines = ["solid jar"]
    for t in tri:
        lines += ["facet normal 0 0 0", "outer loop"]
        lines += ["vertex %.9g %.9g %.9g" % tuple(p) for p in t]
        lines += ["endloop", "endfacet"]
    lines.append("endsolid jar")
    p = tmp_path / "a.stl"
    p.write_text("\n".join(lines))
    assert np.allclose(read_stl(str(p)), tri, atol=1e-9)


def test_leaky_mesh_is_refused(tmp_path):
    tri, _ = make_jar(n_circ=16)
    with pytest.raises(MeshError, match="not closed"):
        check_jar_mesh(tri[5:])


def test_outward_mesh_is_refused():
    tri, _ = make_jar(n_circ=16)
    with pytest.raises(MeshError, match="outward"):
        check_jar_mesh(tri[:, [0, 2, 1]])


@pytest.mark.parametrize("content", [b"", b"garbage that is no stl at all", b"solid x\nvertex 1 2\n"])
def test_unreadable_stl_is_one_clear_error(tmp_path, content):
    p = tmp_path / "bad.stl"
    p.write_bytes(content)
    with pytest.raises(MeshError):
        read_stl(str(p))


def test_missing_stl_is_one_clear_error(tmp_path):
    with pytest.raises(MeshError, match="cannot read"):
        read_stl(str(tmp_path / "nope.stl"))


def test_generator_cli_refuses_impossible_dimensions(tmp_path, capsys):
    out = tmp_path / "j.stl"
    assert jar_main(["--out", str(out), "--diameter-mm", "-3"]) == 2
    assert not out.exists()
    assert "error" in capsys.readouterr().err


def test_run_id_follows_config_and_stl_bytes(tmp_path):
    cfg = twin_config.complete_config({})
    assert twin_config.run_id(cfg) == twin_config.run_id(dict(cfg))
    assert twin_config.run_id(cfg) != twin_config.run_id(dict(cfg, frequency_hz=26.0))
    tri, _ = make_jar(n_circ=16)
    p = tmp_path / "j.stl"
    write_stl(str(p), tri)
    c2 = dict(cfg, stl_path=str(p))
    rid = twin_config.run_id(c2)
    write_stl(str(p), tri * 1.01)
    assert twin_config.run_id(c2) != rid


@pytest.mark.parametrize("bad, msg", [
    ({"frequency_hz": -5.0}, "frequency_hz"),
    ({"restitution": 0.0}, "restitution"),
    ({"restitution": 1.2}, "restitution"),
    ({"ball_diameter_m": float("nan")}, "finite"),
    ({"bogus_key": 1}, "unknown config key"),
    ({"protocol": "fast"}, "protocol"),
    ({"dt_s": 1e-3, "output_fps": 2134}, "output_fps"),
])
def test_bad_config_is_one_clear_error(bad, msg):
    with pytest.raises(twin_config.ConfigError, match=msg):
        twin_config.complete_config(bad)


# -- the parametric jar (run config keys jar_*) ------------------------------------------------
def test_parametric_jar_at_the_defaults_is_the_committed_stl():
    from geometry.jar import mesh_for_config
    cfg = twin_config.complete_config({"jar_inner_diameter_m": 0.028})
    tri, info, scale = mesh_for_config(cfg, None)
    stl = read_stl(str(DEFAULT_STL)) * 1e-3
    assert tri.shape == stl.shape and scale == 1.0 and info["source"] == "parametric"
    a = np.sort(tri.reshape(-1, 9), axis=0)
    b = np.sort(stl.reshape(-1, 9), axis=0)
    assert np.abs(a - b).max() < 1e-6          # float32 STL in mm
    assert info["volume_m3"] == pytest.approx(25e-6, rel=1e-6)


@pytest.mark.parametrize("dims", [
    {"jar_inner_diameter_m": 0.024},
    {"jar_inner_diameter_m": 0.032, "jar_volume_m3": 30e-6},
    {"jar_inner_diameter_m": 0.028, "jar_inner_length_m": 0.055},
    {"jar_inner_diameter_m": 0.028, "jar_fillet_radius_m": 0.0125},   # domed ends
])
def test_parametric_jar_is_closed_inward_and_has_its_dimensions(dims):
    from geometry.jar import mesh_for_config
    cfg = twin_config.complete_config(dict(dims, ball_diameter_m=0.0175))
    tri, info, _ = mesh_for_config(cfg, None)
    assert edge_defects(tri) == (0, 0) and signed_volume(tri) < 0
    assert info["inner_diameter_m"] == pytest.approx(cfg["jar_inner_diameter_m"], rel=1e-9)
    if cfg["jar_inner_length_m"] is not None:
        assert info["inner_length_m"] == pytest.approx(cfg["jar_inner_length_m"], rel=1e-9)
    else:
        assert info["volume_m3"] == pytest.approx(cfg["jar_volume_m3"], rel=1e-6)
    # a domed end is a longer jar than a flat one of the same volume
    if dims.get("jar_fillet_radius_m", 0) > 0.01:
        flat = mesh_for_config(twin_config.complete_config({"jar_inner_diameter_m": 0.028}),
                               None)[1]
        assert info["inner_length_m"] > flat["inner_length_m"] + 1e-3


@pytest.mark.parametrize("bad, msg", [
    ({"jar_inner_length_m": 0.05}, "needs jar_inner_diameter_m"),
    ({"jar_inner_diameter_m": 0.028, "jar_fillet_radius_m": 0.0135}, "below D/2"),
    ({"jar_inner_diameter_m": 0.028, "jar_inner_length_m": 0.009}, "below its lower bound"),
    ({"jar_inner_diameter_m": 0.028, "jar_inner_length_m": 0.012,
      "jar_fillet_radius_m": 0.008}, "twice the fillet"),
    ({"jar_inner_diameter_m": 0.02, "ball_diameter_m": 0.0206}, "does not fit"),
    ({"jar_inner_diameter_m": float("nan")}, "finite"),
])
def test_impossible_parametric_jar_is_one_clear_error(bad, msg):
    with pytest.raises(twin_config.ConfigError, match=msg):
        twin_config.complete_config(bad)


def test_parametric_jar_run_id_ignores_the_stl_and_keeps_old_ids(tmp_path):
    base = twin_config.complete_config({})
    # the jar keys at their defaults leave the id of an STL-jar config unchanged
    assert twin_config.run_id(base) == twin_config.run_id(
        {k: v for k, v in base.items() if k not in twin_config.JAR_KEYS})
    par = {"jar_inner_diameter_m": 0.028}
    other_stl = tmp_path / "j.stl"
    write_stl(str(other_stl), make_jar(n_circ=16)[0])
    assert twin_config.run_id(par) == twin_config.run_id(dict(par, stl_path=str(other_stl)))
    assert twin_config.run_id(par) != twin_config.run_id(base)
    assert twin_config.run_id(par) != twin_config.run_id({"jar_inner_diameter_m": 0.029})
