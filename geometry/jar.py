"""Parametric mesh of the Retsch MM400 25 mL jar's cavity, written as an STL.

The cavity is a cylinder of inner diameter D along the x axis, closed by flat end caps joined to
the cylinder by a rounded edge (a torus fillet of radius r_f). The inner length L is solved so
that the *mesh* encloses the target volume (25.0 mL), so the polygonal approximation does not bias
the volume. Normals face the cavity.

Assumed dimensions (the paper's Figure 2 drawing is not in the text; see geometry/README.md):
D = 28.0 mm, r_f = 5.0 mm, V = 25.0 mL  ->  L = 42.8 mm (32 segments round, 508 facets).

Usage::

    python -m geometry.jar --out geometry/mm400_25ml.stl [--diameter-mm 28 --fillet-mm 5
        --volume-ml 25 --n-circ 48]
"""
import argparse
import sys

import numpy as np

try:  # run as package module or as a plain script
    from geometry.stl_io import (write_stl, signed_volume, check_jar_mesh, check_jar_size,
                                 edge_defects, read_stl, scale_for_units)
except ImportError:  # pragma: no cover
    from stl_io import (write_stl, signed_volume, check_jar_mesh, check_jar_size, edge_defects,
                        read_stl, scale_for_units)

DEFAULTS = {
    "inner_diameter_m": 0.028,
    "fillet_radius_m": 0.005,
    "volume_m3": 25.0e-6,
    "n_circ": 32,
}


def _profile(length, radius, fillet, n_fillet, n_axial):
    """Half-plane profile (x, r) of the side wall, from the left cap's rim to the right cap's rim."""
    pts = []
    xl = -length / 2.0
    for k in range(0, n_fillet + 1):  # left fillet: centre (xl+rf, R-rf), angle pi -> pi/2
        a = np.pi - 0.5 * np.pi * k / n_fillet
        pts.append((xl + fillet + fillet * np.cos(a), radius - fillet + fillet * np.sin(a)))
    x0, x1 = xl + fillet, -xl - fillet
    for k in range(1, n_axial + 1):  # straight cylinder
        pts.append((x0 + (x1 - x0) * k / n_axial, radius))
    for k in range(1, n_fillet + 1):  # right fillet: angle pi/2 -> 0
        a = 0.5 * np.pi - 0.5 * np.pi * k / n_fillet
        pts.append((x1 + fillet * np.cos(a), radius - fillet + fillet * np.sin(a)))
    return np.array(pts)


def revolve(profile, n_circ):
    """Triangles of the surface of revolution of a profile (x, r > 0) about the x axis."""
    th = 2 * np.pi * np.arange(n_circ) / n_circ
    c, s = np.cos(th), np.sin(th)
    tris = []
    for (xa, ra), (xb, rb) in zip(profile[:-1], profile[1:]):
        for j in range(n_circ):
            j2 = (j + 1) % n_circ
            pa1 = (xa, ra * c[j], ra * s[j])
            pa2 = (xa, ra * c[j2], ra * s[j2])
            pb1 = (xb, rb * c[j], rb * s[j])
            pb2 = (xb, rb * c[j2], rb * s[j2])
            tris.append((pa1, pb1, pa2))
            tris.append((pa2, pb1, pb2))
    return np.array(tris, dtype=np.float64)


def cap(x, rim_radius, n_circ):
    """Flat end cap: the disc inside the rim polygon, with no vertex on the axis.

    A large central triangle (vertices at thirds of the rim) holds the axis at least
    rim_radius/2 from any edge, so a ball arriving near the axis touches one facet only (a vertex
    on the axis, as in a fan, would put it in contact with every facet of the fan at once). The
    three rim segments left over are fanned from their first vertex.
    """
    th = 2 * np.pi * np.arange(n_circ) / n_circ
    rim = np.stack([np.full(n_circ, x), rim_radius * np.cos(th), rim_radius * np.sin(th)], axis=1)
    corners = [0, int(round(n_circ / 3.0)), int(round(2 * n_circ / 3.0))]
    tris = [(rim[corners[0]], rim[corners[1]], rim[corners[2]])]
    for k in range(3):
        i0, i1 = corners[k], corners[(k + 1) % 3] or n_circ
        for j in range(i0 + 1, i1):
            tris.append((rim[i0], rim[j], rim[(j + 1) % n_circ]))
    return np.array(tris, dtype=np.float64)


def _orient_inward(parts):
    """Join parts, flipping each cap so the mesh is consistently oriented, normals inward."""
    side = parts[0]
    out = [side]
    for c in parts[1:]:
        trial = np.concatenate(out + [c])
        if edge_defects(trial)[1]:
            c = c[:, [0, 2, 1]]
        out.append(c)
    t = np.concatenate(out)
    if signed_volume(t) > 0:
        t = t[:, [0, 2, 1]]
    return t


def jar_triangles(length_m, inner_diameter_m=DEFAULTS["inner_diameter_m"],
                  fillet_radius_m=DEFAULTS["fillet_radius_m"], n_circ=DEFAULTS["n_circ"]):
    """Mesh of the cavity with the given inner length [m].

    The fillet and cylinder resolutions follow ``n_circ`` so that one number sets the mesh
    density: n_fillet = max(2, n_circ // 16) segments per quarter-circle fillet (the fillets are
    touched only by a ball rolling into a corner: a ball on a flat end cap cannot reach a fillet
    smaller than its radius), and the straight part is cut into segments no longer than four
    circumferential facet widths (facet count matters for speed: YADE integrates and moves every
    facet every step; the fillets held 512 of 764 facets at n_fillet = n_circ // 8).

    Returns
    -------
    ndarray, shape (n, 3, 3) - vertices [m], normals facing the cavity
    """
    radius = inner_diameter_m / 2.0
    if not (0 < fillet_radius_m < radius):
        raise ValueError("fillet radius must lie in (0, D/2): %g m for D = %g m"
                         % (fillet_radius_m, inner_diameter_m))
    if length_m <= 2 * fillet_radius_m:
        raise ValueError("inner length %g m must exceed twice the fillet radius %g m"
                         % (length_m, fillet_radius_m))
    if n_circ < 8:
        raise ValueError("n_circ must be >= 8, got %d" % n_circ)
    width = 2 * np.pi * radius / n_circ
    # quarter-circle fillet: n_circ // 16 segments, more for large (domed) fillets so that no
    # segment is longer than two circumferential facet widths
    n_fillet = max(2, n_circ // 16, int(np.ceil(0.5 * np.pi * fillet_radius_m / (2 * width))))
    n_axial = max(1, int(np.ceil((length_m - 2 * fillet_radius_m) / (4 * width))))
    prof = _profile(length_m, radius, fillet_radius_m, n_fillet, n_axial)
    rim = radius - fillet_radius_m
    return _orient_inward([revolve(prof, n_circ), cap(-length_m / 2, rim, n_circ),
                           cap(length_m / 2, rim, n_circ)])


def solve_length(volume_m3=DEFAULTS["volume_m3"], inner_diameter_m=DEFAULTS["inner_diameter_m"],
                 fillet_radius_m=DEFAULTS["fillet_radius_m"], n_circ=DEFAULTS["n_circ"]):
    """Inner length [m] at which the mesh encloses ``volume_m3``."""
    def f(length):
        t = jar_triangles(length, inner_diameter_m, fillet_radius_m, n_circ)
        return -signed_volume(t) - volume_m3
    lo = 2 * fillet_radius_m * 1.0001
    hi = lo + 4 * volume_m3 / (np.pi * inner_diameter_m ** 2) * 3 + 0.01
    if f(lo) > 0:
        raise ValueError("volume %g m3 is too small for D = %g m and fillet %g m"
                         % (volume_m3, inner_diameter_m, fillet_radius_m))
    # bisection (the enclosed volume grows monotonically with the length), numpy only so that
    # the scene (YADE's Python) can build the jar itself
    f_lo = f(lo)
    while hi - lo > 1e-10:
        mid = 0.5 * (lo + hi)
        f_mid = f(mid)
        if (f_mid > 0) == (f_lo > 0):
            lo, f_lo = mid, f_mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def config_jar(cfg):
    """Triangles [m] and inner length [m] of a run config's parametric jar.

    ``cfg`` is a complete run config whose ``jar_inner_diameter_m`` is set (see
    ``yade_scripts/twin_config.py``, keys ``jar_*``): the length is ``jar_inner_length_m`` or,
    when that is null, the one at which the mesh holds ``jar_volume_m3``.
    """
    d = cfg["jar_inner_diameter_m"]
    rf = cfg["jar_fillet_radius_m"]
    length = cfg.get("jar_inner_length_m")
    if length is None:
        length = solve_length(cfg["jar_volume_m3"], d, rf)
    return jar_triangles(length, d, rf), length


def make_jar(volume_m3=DEFAULTS["volume_m3"], inner_diameter_m=DEFAULTS["inner_diameter_m"],
             fillet_radius_m=DEFAULTS["fillet_radius_m"], n_circ=DEFAULTS["n_circ"]):
    """Triangles [m] and the solved inner length [m] of the default-shaped jar."""
    length = solve_length(volume_m3, inner_diameter_m, fillet_radius_m, n_circ)
    return jar_triangles(length, inner_diameter_m, fillet_radius_m, n_circ), length


def mesh_for_config(cfg, stl_abs_path):
    """The jar a run config names: (triangles [m], measured dimensions, scale [m per unit]).

    One rule for the scene and every reader: a parametric jar (``jar_inner_diameter_m`` set) is
    generated here; otherwise the STL at ``stl_abs_path`` is read in ``cfg['stl_units']``.
    ``info['source']`` says which ('parametric' or the STL path as given).

    Raises
    ------
    geometry.stl_io.MeshError / OSError / ValueError - unreadable STL, not a closed jar, or
    impossible parametric dimensions
    """
    if cfg.get("jar_inner_diameter_m") is not None:
        tri, _ = config_jar(cfg)
        info = check_jar_mesh(tri)
        info["source"] = "parametric"
        return tri, info, 1.0
    tri = read_stl(stl_abs_path)
    scale = scale_for_units(tri, cfg["stl_units"])
    check_jar_size(tri, scale, cfg["stl_units"])
    info = check_jar_mesh(tri, scale)
    info["source"] = stl_abs_path
    return tri * scale, info, scale


#: the name in the header of every STL this command writes (how it knows its own file)
STL_NAME = "MM400 25 mL jar cavity, mm, normals inward"


def _own_stl(path) -> bool:
    try:
        with open(path, "rb") as fh:
            return fh.read(80).startswith(("binary STL: %s" % STL_NAME).encode()[:40])
    except OSError:
        return False


def check_out(out):
    """The project's file rule for ``--out`` before the mesh is built (raises
    ``analysis.atomic_dir.OutputError``): a new file, or an STL this command wrote; in the
    repository only under ``results/`` or ``geometry/``."""
    try:
        from analysis.atomic_dir import check_out_file
    except ImportError:  # pragma: no cover - run as a plain script
        import os
        sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
        from analysis.atomic_dir import check_out_file
    from analysis.config import REPO_ROOT
    return check_out_file(out, is_own=_own_stl, flag="--out", homes=[REPO_ROOT / "geometry"])


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                epilog="example: python -m geometry.jar --out "
                                "geometry/mm400_25ml.stl --diameter-mm 28 --fillet-mm 5 "
                                "--volume-ml 25")
    p.add_argument("--out", default="geometry/mm400_25ml.stl",
                   help="STL to write (in mm); an existing file is replaced only when this "
                   "command wrote it")
    p.add_argument("--diameter-mm", type=float, default=DEFAULTS["inner_diameter_m"] * 1e3,
                   help="inner diameter of the cavity [mm] (default %(default).4g)")
    p.add_argument("--fillet-mm", type=float, default=DEFAULTS["fillet_radius_m"] * 1e3,
                   help="radius of the rounded edge between cylinder and end cap [mm] "
                   "(default %(default).4g)")
    p.add_argument("--volume-ml", type=float, default=DEFAULTS["volume_m3"] * 1e6,
                   help="cavity volume the mesh encloses; the inner length is solved for it "
                   "[mL] (default %(default).4g)")
    p.add_argument("--n-circ", type=int, default=DEFAULTS["n_circ"],
                   help="segments around the circumference (sets the facet count) [segments] "
                   "(default %(default)s)")
    a = p.parse_args(argv)
    try:
        if a.diameter_mm <= 0 or a.volume_ml <= 0 or a.fillet_mm <= 0:
            raise ValueError("diameter, fillet and volume must be positive")
        out = str(check_out(a.out))
        tri, length = make_jar(a.volume_ml * 1e-6, a.diameter_mm * 1e-3, a.fillet_mm * 1e-3,
                               a.n_circ)
        write_stl(out, tri * 1e3, name=STL_NAME)
        info = check_jar_mesh(tri)
    except (ValueError, OSError) as exc:
        print("geometry.jar: error: %s" % exc, file=sys.stderr)
        return 2
    print("wrote %s: %d facets, D = %.2f mm, L = %.3f mm, fillet %.2f mm, volume %.4f mL (mm units)"
          % (a.out, len(tri), a.diameter_mm, length * 1e3, a.fillet_mm, info["volume_m3"] * 1e6))
    return 0


if __name__ == "__main__":
    sys.exit(main())
