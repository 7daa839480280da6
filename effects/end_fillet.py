"""The jar's end edges rounded more than the twin's jar: a larger fillet between cylinder and ends.

A ball lying on the cylinder's bottom sits (D - d)/2 off the axis and meets the end on the
rounded edge when the fillet radius r_f is large enough: the impact normal tilts away from the
axis, the ball arrives obliquely (tangential approach 0.7-1.3 m/s at r_f = 10 mm against
0.05-0.1 m/s at 5 mm in the paper's conditions) and the end impacts throw the two ball sizes
differently (results/apparatus/README.md: r_f 10 mm makes the 17.5 mm ball 4 % faster than the
20.6 mm one and its v/f fall 3 % from 22.5 to 30 Hz). Strength: the extra fillet radius
``extra_fillet_m`` added to the jar's own; 0 is the base jar.

It changes the geometry before the scene is built (``jar_overrides``, applied by every reader of
the jar: the scene, the runner's fit check, the exporter), so it needs a jar whose fillet is
known: a parametric jar (run config ``jar_inner_diameter_m`` set) or the default STL (the
parametric jar of geometry/jar.py's defaults, to 4e-10 m). The fillet must stay below D/2 - 1 mm.
"""
from effects import ConfigError, base

DECLARATION = {
    "name": "end_fillet",
    "kind": "dem",
    "physics": "the jar's end fillet r_f larger by extra_fillet_m (oblique end impacts of a ball "
               "lying off the axis)",
    "parameters": {
        "extra_fillet_m": {"default": 0.003, "lower": 0.0, "upper": 0.008, "unit": "m",
                           "description": "added to the jar's fillet radius"},
    },
    "null": {"extra_fillet_m": 0.0},
    # an apparatus effect (docs/apparatus.md): diagnosed only when asked for
    # (python -m analysis.loop --with-effect end_fillet)
    "diagnose": {"order": 110, "param": "extra_fillet_m", "s_max": 0.006, "unit": "m",
                 "optional": True},
    "references": ["results/apparatus/README.md (this project's screen of the jar shape)"],
    "changes": "the jar mesh: a parametric jar with the fillet radius increased (the default STL "
               "is replaced by its parametric equivalent); no engine",
}

#: the committed default STL and the parametric jar it was made from (geometry/jar.py DEFAULTS)
DEFAULT_STL = "geometry/mm400_25ml.stl"


def jar_overrides(cfg, params):
    """Run-config jar keys of ``cfg`` (complete) with the fillet enlarged by the effect."""
    extra = float(params["extra_fillet_m"])
    if cfg.get("jar_inner_diameter_m") is None:
        if cfg.get("stl_path") != DEFAULT_STL:
            raise ConfigError("effect end_fillet needs a parametric jar (jar_inner_diameter_m) "
                              "or the default STL; the jar %r has no known fillet"
                              % cfg.get("stl_path"))
        from geometry.jar import DEFAULTS
        out = {"jar_inner_diameter_m": DEFAULTS["inner_diameter_m"],
               "jar_inner_length_m": None, "jar_volume_m3": DEFAULTS["volume_m3"],
               "jar_fillet_radius_m": DEFAULTS["fillet_radius_m"]}
    else:
        out = {k: cfg[k] for k in ("jar_inner_diameter_m", "jar_inner_length_m",
                                   "jar_volume_m3", "jar_fillet_radius_m")}
    out["jar_fillet_radius_m"] = out["jar_fillet_radius_m"] + extra
    limit = 0.5 * out["jar_inner_diameter_m"] - 1e-3
    if out["jar_fillet_radius_m"] > limit:
        raise ConfigError("effect end_fillet: fillet %.4g m + %.4g m exceeds D/2 - 1 mm = %.4g m"
                          % (out["jar_fillet_radius_m"] - extra, extra, limit))
    return out


class Effect(base.Effect):
    """Geometry only: nothing to do once the scene is built."""
