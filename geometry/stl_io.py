"""Read, write and check triangle meshes in STL (numpy only, usable under YADE's Python).

A jar mesh for the twin must be *closed* (every edge shared by exactly two triangles that run it
in opposite directions) and *oriented inward* (normals point into the cavity, so the signed
volume computed with the right-hand rule is negative). :func:`check_jar_mesh` tests both and
returns the enclosed volume and the cavity's dimensions.
"""
import math
import os
import struct

import numpy as np


class MeshError(ValueError):
    """An STL file cannot be read, or its mesh is not a closed, inward-oriented cavity."""


def write_stl(path, triangles, name="jar"):
    """Write triangles to a binary STL, atomically (temp file, then rename).

    Parameters
    ----------
    path : str
    triangles : ndarray, shape (n, 3, 3) - vertex coordinates, in the file's length unit
    """
    tri = np.asarray(triangles, dtype=np.float64)
    if tri.ndim != 3 or tri.shape[1:] != (3, 3):
        raise MeshError("triangles must have shape (n, 3, 3), got %s" % (tri.shape,))
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(normals, axis=1, keepdims=True)
    normals = np.divide(normals, norm, out=np.zeros_like(normals), where=norm > 0)
    rec = np.zeros(len(tri), dtype=[("n", "<f4", 3), ("v", "<f4", (3, 3)), ("attr", "<u2")])
    rec["n"] = normals
    rec["v"] = tri
    tmp = path + ".tmp"
    with open(tmp, "wb") as fh:
        header = ("binary STL: %s" % name).encode()[:80].ljust(80, b" ")
        fh.write(header)
        fh.write(struct.pack("<I", len(tri)))
        fh.write(rec.tobytes())
    os.replace(tmp, path)


def read_stl(path):
    """Read a binary or ASCII STL.

    Returns
    -------
    triangles : ndarray, shape (n, 3, 3) - vertex coordinates in the file's unit

    Raises
    ------
    MeshError
        missing, unreadable, empty or malformed file.
    """
    try:
        with open(path, "rb") as fh:
            data = fh.read()
    except OSError as exc:
        raise MeshError("cannot read STL %s: %s" % (path, exc))
    if len(data) < 15:
        raise MeshError("STL %s is empty or truncated (%d bytes)" % (path, len(data)))
    if len(data) >= 84:
        n = struct.unpack("<I", data[80:84])[0]
        if 84 + 50 * n == len(data) and n > 0:
            rec = np.frombuffer(data, dtype=[("n", "<f4", 3), ("v", "<f4", (3, 3)),
                                             ("attr", "<u2")], count=n, offset=84)
            tri = rec["v"].astype(np.float64)
            if not np.all(np.isfinite(tri)):
                raise MeshError("STL %s holds non-finite vertex coordinates" % path)
            return tri
    text = data.decode("ascii", errors="replace")
    if not text.lstrip().lower().startswith("solid"):
        raise MeshError("STL %s is neither a valid binary STL (size does not match its "
                        "triangle count) nor an ASCII STL (no 'solid' header)" % path)
    verts = []
    for lineno, line in enumerate(text.splitlines(), 1):
        parts = line.split()
        if parts and parts[0].lower() == "vertex":
            try:
                verts.append([float(p) for p in parts[1:4]])
            except (ValueError, IndexError):
                raise MeshError("STL %s line %d: malformed vertex %r" % (path, lineno, line.strip()))
    if not verts or len(verts) % 3:
        raise MeshError("STL %s: found %d vertices, not a positive multiple of 3"
                        % (path, len(verts)))
    tri = np.asarray(verts, dtype=np.float64).reshape(-1, 3, 3)
    if not np.all(np.isfinite(tri)):
        raise MeshError("STL %s holds non-finite vertex coordinates" % path)
    return tri


def signed_volume(triangles):
    """Signed enclosed volume by the divergence theorem (positive for outward normals)."""
    t = np.asarray(triangles, dtype=np.float64)
    return float(np.einsum("ij,ij->i", t[:, 0], np.cross(t[:, 1], t[:, 2])).sum() / 6.0)


def edge_defects(triangles, decimals=9):
    """Count edges that are not shared by exactly one opposite-running partner.

    Returns
    -------
    (n_open, n_misoriented) : number of directed edges with no partner at all (holes) and
        number of edges run twice in the same direction (inconsistent orientation).
    """
    t = np.round(np.asarray(triangles, dtype=np.float64), decimals)
    verts, inv = np.unique(t.reshape(-1, 3), axis=0, return_inverse=True)
    f = inv.reshape(-1, 3)
    directed = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    keys = directed[:, 0].astype(np.int64) * len(verts) + directed[:, 1]
    rev = directed[:, 1].astype(np.int64) * len(verts) + directed[:, 0]
    uniq, counts = np.unique(keys, return_counts=True)
    n_mis = int((counts > 1).sum())
    has_rev = np.isin(keys, rev)
    n_open = int((~has_rev).sum())
    return n_open, n_mis


#: metres per unit of each STL unit ``stl_units`` may state
STL_UNITS_M = {"m": 1.0, "cm": 1e-2, "mm": 1e-3, "um": 1e-6}
#: a mill jar's largest inner dimension lies in this range [m]; an STL read to a jar outside it
#: is in another unit than the one it is read in (a jar of metres or of microns)
JAR_SPAN_MIN_M = 0.005
JAR_SPAN_MAX_M = 0.5


def scale_for_units(triangles, units):
    """Metres per file unit: 'm', 'cm', 'mm', 'um', or 'auto' (mm when the mesh spans more than
    1 unit, else m)."""
    if units in STL_UNITS_M:
        return STL_UNITS_M[units]
    if units == "auto":
        span = float(np.ptp(np.asarray(triangles).reshape(-1, 3), axis=0).max())
        return 1e-3 if span > 1.0 else 1.0
    raise MeshError("stl units must be 'm', 'cm', 'mm', 'um' or 'auto', got %r" % (units,))


def check_jar_size(triangles, scale, units="auto"):
    """Refuse a mesh that, read at ``scale`` metres per file unit, is no mill jar in size.

    The largest extent of the bounding box must lie in JAR_SPAN_MIN_M - JAR_SPAN_MAX_M (5 mm -
    0.5 m), whatever ``units`` (the ``stl_units`` the mesh was read in: 'auto' guesses, a unit
    states). Raises MeshError naming the size, the units and the units the numbers fit.
    """
    span_units = float(np.ptp(np.asarray(triangles, float).reshape(-1, 3), axis=0).max())
    span = span_units * scale
    if JAR_SPAN_MIN_M <= span <= JAR_SPAN_MAX_M:
        return
    fits = [u for u, f in STL_UNITS_M.items() if JAR_SPAN_MIN_M <= span_units * f <= JAR_SPAN_MAX_M]
    # likeliest first: the size nearest the middle of the range (in log)
    mid = math.sqrt(JAR_SPAN_MIN_M * JAR_SPAN_MAX_M)
    fits.sort(key=lambda u: abs(math.log(span_units * STL_UNITS_M[u] / mid)))
    how = ("stl_units 'auto' reads a mesh spanning %g units as %s" % (
        span_units, "mm" if scale == 1e-3 else "m") if units == "auto"
        else "stl_units %r" % units)
    hint = ("the numbers fit a jar in %s (%.3g mm across): set stl_units to %r"
            % (" or ".join(fits), span_units * STL_UNITS_M[fits[0]] * 1e3, fits[0]) if fits
            else "no unit (m, cm, mm, um) makes it one")
    raise MeshError("the jar is %.3g m across (%s), not the %g mm - %g m of a mill jar: %s"
                    % (span, how, JAR_SPAN_MIN_M * 1e3, JAR_SPAN_MAX_M, hint))


def check_jar_mesh(triangles, scale=1.0):
    """Check that a mesh is a closed cavity with inward normals and measure it.

    Parameters
    ----------
    triangles : ndarray, shape (n, 3, 3) - in file units
    scale : float - metres per file unit

    Returns
    -------
    dict with volume_m3, inner_length_m (extent along x), inner_diameter_m (twice the largest
    distance of a vertex from the x axis), min_radius_mid_m (smallest vertex distance from the
    axis among vertices within the middle third of the length), n_facets, centre_m (x, y, z).

    Raises
    ------
    MeshError
        the mesh has holes, inconsistent orientation, outward normals, or is not centred on the
        x axis.
    """
    t = np.asarray(triangles, dtype=np.float64) * scale
    if len(t) < 4:
        raise MeshError("mesh has %d triangles; a closed jar needs at least 4" % len(t))
    n_open, n_mis = edge_defects(t / scale)
    if n_open:
        raise MeshError("mesh is not closed: %d edges have no neighbouring triangle (a leaky "
                        "STL lets the ball escape)" % n_open)
    if n_mis:
        raise MeshError("mesh orientation is inconsistent: %d edges are run twice in the same "
                        "direction" % n_mis)
    vol = signed_volume(t)
    if vol > 0:
        raise MeshError("mesh normals face outward (signed volume %+.3e m3); the jar's normals "
                        "must face the cavity" % vol)
    v = t.reshape(-1, 3)
    lo, hi = v.min(axis=0), v.max(axis=0)
    centre = 0.5 * (lo + hi)
    length = hi[0] - lo[0]
    if abs(centre[1]) > 0.02 * length or abs(centre[2]) > 0.02 * length:
        raise MeshError("jar mesh must be centred on the x axis (its axis of motion); centre of "
                        "its bounding box is (%.4g, %.4g, %.4g) m" % tuple(centre))
    r = np.hypot(v[:, 1], v[:, 2])
    mid = np.abs(v[:, 0] - centre[0]) < length / 6.0
    return {
        "volume_m3": -vol,
        "inner_length_m": float(length),
        "inner_diameter_m": float(2 * r.max()),
        "min_radius_mid_m": float(r[mid].min()) if mid.any() else float(r.max()),
        "n_facets": int(len(t)),
        "centre_m": [float(c) for c in centre],
    }


def measure_jar(path, units="auto"):
    """Read a jar STL and measure it: :func:`check_jar_mesh` of the file at ``path``.

    Parameters
    ----------
    path : str - STL file
    units : str - 'm', 'cm', 'mm', 'um' or 'auto' (see :func:`scale_for_units`)

    Returns
    -------
    (triangles, info, scale) : triangles in file units, the dict of :func:`check_jar_mesh`
        (lengths in metres) and the metres per file unit

    Raises
    ------
    MeshError
        the file cannot be read or is not a closed, inward-oriented, axis-centred cavity, or
        not a jar's size in these units (:func:`check_jar_size`).
    """
    tri = read_stl(path)
    scale = scale_for_units(tri, units)
    check_jar_size(tri, scale, units)
    return tri, check_jar_mesh(tri, scale), scale


def ball_fit_error(ball_diameter_m, info):
    """Why a ball of this diameter cannot move in a jar, or None when it fits.

    The ball must be smaller than the cavity's narrowest diameter in the middle third of its
    length (``2 * info['min_radius_mid_m']``) and shorter than its inner length
    (``info['inner_length_m']``); ``info`` is the dict of :func:`check_jar_mesh` [m].

    Returns
    -------
    str or None - one sentence naming both sizes in mm, or None
    """
    d = float(ball_diameter_m)
    bore = 2.0 * info["min_radius_mid_m"]
    if d >= bore:
        return ("ball (%.2f mm) is %s the jar's inner diameter (%.2f mm)"
                % (d * 1e3, "larger than" if d > bore * (1 + 1e-6) else "as large as",
                   bore * 1e3))
    if d >= info["inner_length_m"]:
        return ("ball (%.2f mm) is longer than the jar's inner length (%.2f mm)"
                % (d * 1e3, info["inner_length_m"] * 1e3))
    return None
