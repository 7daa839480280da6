"""The effect catalog: physics that can be switched on, one module per effect.

``load_effects({"name": {"param": value}}, side="dem")`` validates names and parameters against
each module's ``DECLARATION`` and returns the effect objects of one side ('dem' for the YADE
scene, 'kinetics' for the yield model, 'observation' for the measurement chain, None for
all). ``diagnose_entries()`` lists the effects'
diagnose entries (the candidates of analysis.catalog). Standard library only.
"""
import functools
import importlib
import math
import os

try:
    from twin_config import ConfigError
except ImportError:  # imported from the venv without yade_scripts on the path
    from analysis.config import twin_config
    ConfigError = twin_config.ConfigError

_HERE = os.path.dirname(os.path.abspath(__file__))
_NOT_EFFECTS = {"__init__", "base", "template"}


@functools.lru_cache(maxsize=1)
def _listed():
    return tuple(sorted(f[:-3] for f in os.listdir(_HERE)
                        if f.endswith(".py") and f[:-3] not in _NOT_EFFECTS))


def available():
    """Names of the effect modules in this folder (listed once a process: the likelihood's hot
    path asks for them at every prediction with an observation effect)."""
    return list(_listed())


def declaration(name):
    """The DECLARATION dict of effect ``name``."""
    if name not in available():
        raise ConfigError("unknown effect %r (catalog: %s)" % (name, ", ".join(available())))
    return importlib.import_module("effects." + name).DECLARATION


#: keys of a declaration's optional "diagnose" entry: analysis.catalog.Candidate's fields
#: (param, s_max, unit; coord, p0, fixed optional) and the entry's place in the catalog
#: ("order", "optional", "decoy")
DIAGNOSE_KEYS = {"order", "param", "s_max", "unit", "coord", "p0", "fixed", "optional", "decoy"}


def diagnose_entries():
    """(name, kind, diagnose entry) of every effect whose DECLARATION has a "diagnose" entry,
    ordered by the entries' "order" (which fixes the diagnose catalog's order: run ids, plots).

    Raises
    ------
    ConfigError - an entry that is not a dict, has unknown keys or no integer "order", or an
        "order" that two effects share
    """
    rows, seen = [], {}
    for name in available():
        d = declaration(name)
        entry = d.get("diagnose")
        if entry is None:
            continue
        if not isinstance(entry, dict):
            raise ConfigError("effect %s: \"diagnose\" must be a dict, got %r" % (name, entry))
        unknown = sorted(set(entry) - DIAGNOSE_KEYS)
        if unknown:
            raise ConfigError("effect %s: unknown diagnose key(s) %s (known: %s)"
                              % (name, ", ".join(unknown), ", ".join(sorted(DIAGNOSE_KEYS))))
        order = entry.get("order")
        if not isinstance(order, int) or isinstance(order, bool):
            raise ConfigError("effect %s: diagnose needs an integer \"order\", got %r"
                              % (name, order))
        if order in seen:
            raise ConfigError("effects %s and %s: the same diagnose order %d"
                              % (seen[order], name, order))
        seen[order] = name
        rows.append((order, name, d["kind"], entry))
    return [(name, kind, entry) for _, name, kind, entry in sorted(rows)]


def validate(name, params):
    """Complete ``params`` with defaults and check them against the declared bounds."""
    decl = declaration(name)
    if params is None:
        params = {}
    if not isinstance(params, dict):
        raise ConfigError("effect %s: parameters must be an object, got %r" % (name, params))
    known = decl["parameters"]
    unknown = sorted(set(params) - set(known))
    if unknown:
        raise ConfigError("effect %s: unknown parameter(s) %s (known: %s)"
                          % (name, ", ".join(unknown), ", ".join(sorted(known))))
    out = {}
    for p, spec in known.items():
        v = params.get(p, spec["default"])
        if not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v):
            raise ConfigError("effect %s: %s must be a finite number [%s], got %r"
                              % (name, p, spec["unit"], v))
        if not spec["lower"] <= v <= spec["upper"]:
            raise ConfigError("effect %s: %s = %g %s is outside its physical bounds [%g, %g]"
                              % (name, p, v, spec["unit"], spec["lower"], spec["upper"]))
        out[p] = float(v)
    return out


def load_effects(spec, side=None):
    """Effect objects for a config's ``effects`` entry.

    Parameters
    ----------
    spec : dict {name: {param: value}}
    side : 'dem', 'kinetics', 'observation' or None - keep only effects of this kind

    Raises
    ------
    ConfigError - unknown effect or parameter, or a value outside its bounds
    """
    out = []
    for name in sorted(spec or {}):
        params = validate(name, spec[name])
        decl = declaration(name)
        if side is not None and decl["kind"] != side:
            continue
        mod = importlib.import_module("effects." + name)
        cls = getattr(mod, "Effect", None)
        if cls is None:
            raise ConfigError("effect %s declares kind %r but has no Effect class"
                              % (name, decl["kind"]))
        out.append(cls(decl, params))
    return out


def jar_config(cfg):
    """``cfg`` (a complete run config) with the jar keys the switched-on effects change.

    An effect module may define ``jar_overrides(cfg, params) -> {jar key: value}`` (e.g.
    end_fillet): the jar is then built from the returned keys by every reader of the jar (the
    scene, the runner's fit check, the exporter). Without such effects ``cfg`` is returned.

    Raises
    ------
    ConfigError - an effect that cannot change this jar, or an impossible result
    """
    out = cfg
    for name in sorted(cfg.get("effects") or {}):
        declaration(name)                   # an unknown name: ConfigError, not ImportError
        mod = importlib.import_module("effects." + name)
        hook = getattr(mod, "jar_overrides", None)
        if hook is None:
            continue
        params = validate(name, cfg["effects"][name])
        out = dict(out, **hook(out, params))
    return out


def catalog_rows(kind=None):
    """One dict per effect (name, kind, physics, parameters, null, changes), sorted by name.

    ``parameters`` is a one-line text "p [unit] = default (lower..upper); ...".
    """
    rows = []
    for name in available():
        d = declaration(name)
        if kind is not None and d["kind"] != kind:
            continue
        params = "; ".join("%s [%s] = %g (%g..%g)" % (p, s["unit"], s["default"], s["lower"],
                                                        s["upper"])
                           for p, s in sorted(d["parameters"].items()))
        null = ", ".join("%s = %g" % (p, v) for p, v in sorted(d["null"].items()))
        rows.append({"name": name, "kind": d["kind"], "physics": d["physics"],
                     "parameters": params, "null": null, "changes": d["changes"]})
    return rows


def catalog_table(kind=None):
    """The effect catalog as a Markdown table generated from the declarations (a str)."""
    cols = ("name", "kind", "physics", "parameters", "null")
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for r in catalog_rows(kind):
        lines.append("| " + " | ".join(str(r[c]).replace("|", "\\|") for c in cols) + " |")
    return "\n".join(lines) + "\n"
