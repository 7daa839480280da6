"""Run configuration of the mill twin: every parameter declared once.

Standard library only: this module is imported both by the YADE scene (YADE's own Python) and
by ``analysis/`` (the project's venv). A run config is a flat JSON object whose keys are the names
in :data:`PARAMETERS` (units in the names, SI values) plus ``effects`` (a dict of switched-on
effects and their strengths, see ``analysis/effects``). Unknown keys are an error.

The run id is a hash of the complete config (defaults filled in), of the STL file's bytes and of
:data:`SUMMARY_VERSION`, so equal configs share one cached recording and a recording summarised
by an older scene is not taken for a new one.
"""
import hashlib
import json
import math
import os
import re

#: Seed paper's camera frame rate (Chronos 1.4, 2134 frames/s).
CAMERA_FPS = 2134.0

#: The recording's schema (docs/reference.md, "Recording"), declared once for the scene that
#: writes it and every reader: trajectory.csv's columns (lab frame) ...
TRAJECTORY_COLUMNS = ("t_s", "x_m", "y_m", "z_m", "vx_m_s", "vy_m_s", "vz_m_s",
                      "wx_rad_s", "wy_rad_s", "wz_rad_s", "jar_x_m", "jar_vx_m_s")
#: ... and impacts.csv's (one row per ball-wall contact event)
IMPACT_COLUMNS = ("event_id", "t_start_s", "t_end_s", "vn_in_m_s", "vt_in_m_s", "vn_out_m_s",
                  "fn_peak_n", "e_diss_j", "where", "x_contact_jar_m", "n_facets",
                  "collision_id")

# name: (default, lower, upper, unit, role, description)
# role: 'operating' (what the user sets on the mill), 'material' (Table 2 constants),
# 'contact' (calibrated), 'apparatus' (uncertain dimensions of the rig), 'numerical', 'protocol'.
PARAMETERS = {
    "frequency_hz": (25.0, 0.0, 60.0, "Hz", "operating", "jar oscillation frequency f"),
    "ball_diameter_m": (0.0206, 1e-3, 0.05, "m", "operating", "steel ball diameter"),
    "amplitude_m": (0.0135, 0.0, 0.05, "m", "apparatus",
                    "half stroke A of the jar along its axis (x_jar = A sin 2 pi f t); "
                    "not in the paper, inferred from Table 3 speeds, range 0.010-0.016 m"),
    "ball_density_kg_m3": (7800.0, 1.0, 30000.0, "kg/m3", "material", "ball density (Table 2)"),
    "ball_young_pa": (210e9, 1e6, 1e12, "Pa", "material", "ball Young modulus (Table 2)"),
    "ball_poisson": (0.3, 0.0, 0.5, "-", "material", "ball Poisson ratio (Table 2)"),
    "wall_density_kg_m3": (1180.0, 1.0, 30000.0, "kg/m3", "material", "PMMA density (Table 2)"),
    "wall_young_pa": (3.3e9, 1e6, 1e12, "Pa", "material", "PMMA Young modulus (Table 2)"),
    "wall_poisson": (0.4, 0.0, 0.5, "-", "material", "PMMA Poisson ratio (Table 2)"),
    "restitution": (0.11, 0.0, 1.0, "-", "contact",
                    "ball-wall coefficient of restitution C_R (Table 2, bounds 0.1-0.7); "
                    "must lie in (0, 1]"),
    "static_friction": (0.7, 0.0, 2.0, "-", "contact",
                        "ball-wall static friction SF (Table 2, bounds 0.3-0.7)"),
    "rolling_friction": (0.5, 0.0, 2.0, "-", "contact",
                         "ball-wall rolling friction RF (Table 2, bounds 0.1-0.5), used as "
                         "YADE's eta: rolling moment capped at RF * R * |Fn|"),
    "rolling_model": ("spring", None, None, "-", "contact",
                      "rolling resistance: 'spring' (YADE's elastic-plastic rolling spring of "
                      "stiffness RF r 100 N / 0.01 rad, capped at RF r |Fn|: the cap holds at "
                      "rest and in rolling, but in a 0.2 ms wall impact the moment builds up to "
                      "about half of it, by estimate); 'constant_torque' (EDEM's directional "
                      "constant torque, RF r |Fn| against the rolling at every contact step: "
                      "the same cap with a rolling stiffness 500x higher, reached within a step "
                      "or two of any impact)"),
    "gravity_m_s2": (9.81, 0.0, 100.0, "m/s2", "numerical", "gravity, along -z (across the motion)"),
    "dt_s": (3e-6, 1e-8, 1e-2, "s", "numerical",
             "time step (default from results/studies/timestep_convergence.csv)"),
    "ramp_s": (0.3, 0.0, 10.0, "s", "protocol",
               "spin-up: frequency ramps linearly from 0 to f over this time (phase-continuous)"),
    "settle_min_s": (0.2, 0.0, 30.0, "s", "protocol",
                     "shortest time at full frequency before steady state may be declared"),
    "settle_max_s": (3.0, 0.0, 60.0, "s", "protocol",
                     "longest time at full frequency waited for a steady state; then the run "
                     "records anyway and meta.json says steady=false"),
    "steady_window_cycles": (10, 2, 1000, "-", "protocol",
                             "jar cycles per window compared in the steady-state test"),
    "steady_tol": (0.03, 1e-4, 1.0, "-", "protocol",
                   "steady when two consecutive windows' mean speeds differ by less than this "
                   "fraction"),
    "record_s": (0.5, 1e-4, 60.0, "s", "protocol", "recorded time after steady state (paper: 0.5 s)"),
    "output_fps": (CAMERA_FPS, 1.0, 1e6, "1/s", "protocol", "trajectory.csv sample rate"),
    "ball_start": ("random", None, None, "-", "protocol",
                   "'random' (seeded position in the jar, at rest), 'center' (at rest on the "
                   "axis), or 'given' (ball_init_pos_m / ball_init_vel_m_s)"),
    "ball_init_pos_m": (None, None, None, "m", "protocol", "[x, y, z] in the jar frame, for 'given'"),
    "ball_init_vel_m_s": (None, None, None, "m/s", "protocol", "[vx, vy, vz], for 'given'"),
    "protocol": ("mill", None, None, "-", "protocol",
                 "'mill': ramp, wait for steady state, record; 'free': jar at full f from t=0, "
                 "record from t=0 (for tests of contact physics)"),
    "stl_path": ("geometry/mm400_25ml.stl", None, None, "-", "apparatus",
                 "jar mesh, closed, axis along x, centred at the origin; relative paths are "
                 "taken from the repository root"),
    "jar_inner_diameter_m": (None, 0.012, 0.08, "m", "apparatus",
                             "inner diameter D of a parametric jar (a cylinder along x closed by "
                             "flat ends joined to it by a fillet; geometry/jar.py); null: the jar "
                             "is the STL of stl_path. Default jar: D = 28 mm (assumed, see "
                             "geometry/README.md)"),
    "jar_inner_length_m": (None, 0.012, 0.2, "m", "apparatus",
                           "inner length L of the parametric jar, end face to end face; null: "
                           "solved so that the mesh holds jar_volume_m3"),
    "jar_volume_m3": (25e-6, 1e-6, 1e-3, "m3", "apparatus",
                      "cavity volume of the parametric jar when jar_inner_length_m is null "
                      "(MM400 25 mL jar: 25e-6)"),
    "jar_fillet_radius_m": (0.005, 1e-4, 0.04, "m", "apparatus",
                            "radius of the rounded edge between the parametric jar's cylinder "
                            "and its flat ends; must stay below D/2 - 1 mm (a flat pole disc "
                            "remains); close to D/2 the ends are domed (hemispherical)"),
    "stl_units": ("auto", None, None, "-", "apparatus",
                  "'m', 'cm', 'mm', 'um' or 'auto' (mm when the mesh is larger than 1 unit); a "
                  "jar read to less than 5 mm or more than 0.5 m across is refused "
                  "(geometry/stl_io.py, check_jar_size)"),
    "facet_contact": ("flat", None, None, "-", "numerical",
                      "'flat': Hertz radius of a ball on a facet is the ball radius (a flat "
                      "wall), YADE's Ig2_Facet_Sphere_ScGeom(hertzian=True); 'yade_default': "
                      "facet counted as a sphere of radius 2r (R_eff = 2r/3)"),
    "restitution_compensation": (True, None, None, "-", "numerical",
                                 "adjust YADE's en so that a single impact at this dt gives the "
                                 "configured restitution (removes the integrator's O(dt) loss)"),
    "seed": (0, 0, 2**31 - 1, "-", "numerical", "seed of the ball's random start position"),
    "max_wall_s": (1800.0, 1.0, 1e6, "s", "numerical", "a run longer than this is aborted"),
    "frame": ("lab", None, None, "-", "numerical",
              "frame the scene is integrated in: 'lab' (the jar's facets moved by the harmonic "
              "motion), 'jar' (static facets, the inertial force -m a_jar(t) on the ball, "
              "recordings restored to the lab frame; only for effects that keep the jar rigid "
              "and translating), 'auto' ('jar' where the effects allow it, else 'lab'). The "
              "default 'lab' leaves the run id of older configs unchanged"),
}

#: keys left out of the run id's hash at these values (added after runs were cached under
#: ids that did not hold them)
HASH_NEUTRAL = {"frame": "lab", "rolling_model": "spring", "jar_inner_diameter_m": None, "jar_inner_length_m": None,
                "jar_volume_m3": 25e-6, "jar_fillet_radius_m": 0.005}

#: keys of the parametric jar (used when jar_inner_diameter_m is set; geometry/jar.py)
JAR_KEYS = ("jar_inner_diameter_m", "jar_inner_length_m", "jar_volume_m3", "jar_fillet_radius_m")

#: the smallest flat disc left at the end faces' centre [m]: the fillet may reach D/2 - this
PARAMETRIC_POLE_DISC_M = 1e-3

#: Keys holding a choice from a fixed set.
CHOICES = {
    "ball_start": ("random", "center", "given"),
    "protocol": ("mill", "free"),
    "stl_units": ("auto", "m", "cm", "mm", "um"),
    "facet_contact": ("flat", "yade_default"),
    "frame": ("lab", "jar", "auto"),
    "rolling_model": ("spring", "constant_torque"),
}



class ConfigError(ValueError):
    """A run config names an unknown key or holds an impossible value."""


def default_config():
    """Return a complete config dict holding every default (a fresh copy)."""
    cfg = {k: v[0] for k, v in PARAMETERS.items()}
    cfg["effects"] = {}
    return cfg


def complete_config(user):
    """Fill defaults into ``user`` and validate; return the complete config.

    Raises
    ------
    ConfigError
        unknown key, wrong type, NaN, value outside its bounds, or an impossible combination.
    """
    if not isinstance(user, dict):
        raise ConfigError("run config must be a JSON object, got %s" % type(user).__name__)
    unknown = sorted(set(user) - set(PARAMETERS) - {"effects"})
    if unknown:
        raise ConfigError("unknown config key(s): %s (known: %s)"
                          % (", ".join(unknown), ", ".join(sorted(PARAMETERS))))
    cfg = default_config()
    cfg.update(user)
    for key, (default, lo, hi, unit, role, desc) in PARAMETERS.items():
        val = cfg[key]
        if key in CHOICES:
            if val not in CHOICES[key]:
                raise ConfigError("%s must be one of %s, got %r" % (key, CHOICES[key], val))
            continue
        if key in ("ball_init_pos_m", "ball_init_vel_m_s"):
            if val is not None:
                if (not isinstance(val, (list, tuple)) or len(val) != 3
                        or not all(_is_finite_number(x) for x in val)):
                    raise ConfigError("%s must be a list of 3 finite numbers [%s], got %r"
                                      % (key, unit, val))
                cfg[key] = [float(x) for x in val]
            continue
        if key == "restitution_compensation":
            if not isinstance(val, bool):
                raise ConfigError("restitution_compensation must be true or false, got %r" % (val,))
            continue
        if key in ("jar_inner_diameter_m", "jar_inner_length_m") and val is None:
            continue
        if key == "stl_path":
            if not isinstance(val, str) or not val:
                raise ConfigError("stl_path must be a non-empty string")
            continue
        if not _is_finite_number(val):
            raise ConfigError("%s must be a finite number [%s], got %r" % (key, unit, val))
        if key in ("seed", "steady_window_cycles"):
            if int(val) != val:
                raise ConfigError("%s must be an integer, got %r" % (key, val))
            val = int(val)
        else:
            val = float(val)
        if lo is not None and val < lo:
            raise ConfigError("%s = %g %s is below its lower bound %g (%s)" % (key, val, unit, lo, desc))
        if hi is not None and val > hi:
            raise ConfigError("%s = %g %s is above its upper bound %g (%s)" % (key, val, unit, hi, desc))
        cfg[key] = val
    if cfg["restitution"] <= 0.0:
        raise ConfigError("restitution must lie in (0, 1], got %g" % cfg["restitution"])
    if cfg["frequency_hz"] <= 0.0 and cfg["amplitude_m"] > 0.0:
        raise ConfigError("frequency_hz must be positive, got %g" % cfg["frequency_hz"])
    if cfg["ball_start"] == "given" and cfg["ball_init_pos_m"] is None:
        raise ConfigError("ball_start='given' needs ball_init_pos_m")
    if not isinstance(cfg["effects"], dict):
        raise ConfigError("effects must be an object {name: {param: value}}")
    if cfg["jar_inner_diameter_m"] is None:
        if cfg["jar_inner_length_m"] is not None:
            raise ConfigError("jar_inner_length_m needs jar_inner_diameter_m (a parametric jar); "
                              "without it the jar is the STL of stl_path")
    else:
        rad = 0.5 * cfg["jar_inner_diameter_m"]
        if cfg["jar_fillet_radius_m"] > rad - PARAMETRIC_POLE_DISC_M:
            raise ConfigError("jar_fillet_radius_m = %g m must stay below D/2 - %g m = %g m"
                              % (cfg["jar_fillet_radius_m"], PARAMETRIC_POLE_DISC_M,
                                 rad - PARAMETRIC_POLE_DISC_M))
        length = cfg["jar_inner_length_m"]
        if length is not None and length <= 2.0 * cfg["jar_fillet_radius_m"]:
            raise ConfigError("jar_inner_length_m = %g m must exceed twice the fillet radius "
                              "(%g m)" % (length, 2.0 * cfg["jar_fillet_radius_m"]))
        if cfg["ball_diameter_m"] >= cfg["jar_inner_diameter_m"]:
            raise ConfigError("ball_diameter_m = %g m does not fit the jar's inner diameter %g m"
                              % (cfg["ball_diameter_m"], cfg["jar_inner_diameter_m"]))
    if cfg["output_fps"] * cfg["dt_s"] > 1.0:
        raise ConfigError("output_fps = %g is faster than one sample per step (dt_s = %g)"
                          % (cfg["output_fps"], cfg["dt_s"]))
    return cfg


def _is_finite_number(x):
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def repo_root():
    """Repository root (the folder holding yade_scripts/)."""
    return os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def parametric_jar(cfg):
    """The parametric jar's dimensions {key: value} of a complete config, or None (the STL)."""
    if cfg.get("jar_inner_diameter_m") is None:
        return None
    return {k: cfg[k] for k in JAR_KEYS}


def resolve_stl(cfg, root=None):
    """Absolute path of the config's STL (relative paths are from the repository root)."""
    p = cfg["stl_path"]
    if not os.path.isabs(p):
        p = os.path.join(root or repo_root(), p)
    return p


#: Version of the summary the scene writes (meta.json). Part of the run id: 2 = f_col from the
#: impact times (``twin_modes.collision_rate``); 1 (not hashed) = impacts / record length.
SUMMARY_VERSION = 2


def run_id(cfg, root=None):
    """Hash of the complete config, of the STL bytes and of the summary version: 16 hex
    characters."""
    full = complete_config(cfg)
    for k, v in HASH_NEUTRAL.items():
        if full.get(k) == v:
            del full[k]
    parametric = full.get("jar_inner_diameter_m") is not None
    if parametric:   # the mesh is the config's own; the STL named beside it is not used
        del full["stl_path"], full["stl_units"]
    h = hashlib.sha256()
    h.update(json.dumps(full, sort_keys=True, separators=(",", ":")).encode())
    h.update(b"summary%d" % SUMMARY_VERSION)
    stl = None if parametric else resolve_stl(full, root)
    if not parametric and os.path.isfile(stl):
        with open(stl, "rb") as fh:
            h.update(hashlib.sha256(fh.read()).digest())
    return h.hexdigest()[:16]


class DuplicateKeyError(ValueError):
    """A JSON object holds one key twice (json would keep the last silently)."""


def strict_json_loads(text):
    """``json.loads`` of ``text`` (a leading UTF-8 byte-order mark ignored), refusing a key that
    appears twice in one object.

    The one JSON reader of every input file (run configs, dataset.json, video.json, film
    sidecars): the standard library keeps the last of two equal keys without a word.

    Raises
    ------
    DuplicateKeyError - the key repeated; its message names the key and the lines it is on
    ValueError (json.JSONDecodeError) - malformed JSON
    """
    if text.startswith("\ufeff"):
        text = text[1:]

    def pairs(items):
        out = {}
        for key, value in items:
            if key in out:
                pat = re.compile(r'"%s"\s*:' % re.escape(json.dumps(key)[1:-1]))
                lines = [text.count("\n", 0, m.start()) + 1 for m in pat.finditer(text)]
                where = (" (lines %s)" % ", ".join(str(n) for n in lines)) if lines else ""
                raise DuplicateKeyError("key %r appears twice in one object%s; each key may "
                                        "appear once (JSON readers would keep the last "
                                        "silently)" % (key, where))
            out[key] = value
        return out

    return json.loads(text, object_pairs_hook=pairs)


def load_config(path):
    """Read a JSON run config and complete it. Raises ConfigError naming the file."""
    try:
        with open(path, encoding="utf-8") as fh:
            user = strict_json_loads(fh.read())
    except OSError as exc:
        raise ConfigError("cannot read run config %s: %s" % (path, exc))
    except DuplicateKeyError as exc:
        raise ConfigError("run config %s: %s" % (path, exc))
    except ValueError as exc:
        raise ConfigError("run config %s is not valid JSON: %s" % (path, exc))
    try:
        return complete_config(user)
    except ConfigError as exc:
        raise ConfigError("%s: %s" % (path, exc))
