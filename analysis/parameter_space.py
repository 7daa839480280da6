"""The twin's parameter space, declared once: what a calibration and the loop may move.

Every run-config key, its unit, default and the physical bounds the scene accepts are declared
in ``yade_scripts/twin_config.py`` (:data:`PARAMETERS`, standard library only, read by the scene
too). This module adds, for the parameters that calibrations and the loop move, what only the
analysis needs - and reads everything else from there:

* ``prior`` - the range a calibration may claim (Table 2 bounds for the contact parameters; the
  MM400 25 mL jar's for the apparatus, docs/apparatus.md says where each comes from). It lies
  inside the run config's physical bounds (checked at import);
* ``base`` - calibrated by default (``python -m analysis.calibrate`` without ``--free``).

The effects' strengths are declared by each effect's file (``analysis/effects``, the diagnose
range and strength coordinate); :func:`effect_strengths` lists them beside these.

Every other module reads :data:`CALIBRATED`, :data:`APPARATUS`, :data:`PRIORS` and the
reference point :data:`REFERENCE` (:func:`reference_parameters`) from here.
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

from yade_scripts.twin_config import PARAMETERS


@dataclass(frozen=True)
class Parameter:
    """One movable parameter of the twin.

    name : run-config key (units in the name, SI)
    role : 'contact' or 'apparatus' (twin_config's role)
    unit : twin_config's unit
    physical : (lower, upper) the run config accepts
    prior : (lower, upper) a calibration may claim
    base : calibrated by default
    description : twin_config's description
    """
    name: str
    role: str
    unit: str
    physical: tuple
    prior: tuple
    base: bool = False
    description: str = ""


#: name: (prior range, calibrated by default)
_DECLARED = {
    "restitution": ((0.1, 0.7), True),
    "static_friction": ((0.3, 0.7), True),
    "rolling_friction": ((0.1, 0.5), True),
    "amplitude_m": ((0.010, 0.016), True),
    "jar_inner_diameter_m": ((0.025, 0.032), False),
    "jar_volume_m3": ((22e-6, 28e-6), False),
    "jar_inner_length_m": ((0.036, 0.056), False),
    "jar_fillet_radius_m": ((0.002, 0.0115), False),
}


def _build():
    out = {}
    for name, (prior, base) in _DECLARED.items():
        default, lo, hi, unit, role, desc = PARAMETERS[name]
        if not (lo <= prior[0] < prior[1] <= hi):
            raise ValueError("parameter_space: the prior range %s of %s lies outside the run "
                             "config's bounds (%s, %s)" % (prior, name, lo, hi))
        out[name] = Parameter(name, role, unit, (lo, hi), tuple(prior), base, desc)
    return out


#: every movable parameter, by name
SPACE = _build()
#: parameters calibrated by default and their prior ranges
CALIBRATED = {k: p.prior for k, p in SPACE.items() if p.base}
#: apparatus parameters a calibration may free, and their prior ranges (the stroke among them)
APPARATUS = {k: p.prior for k, p in SPACE.items() if p.role == "apparatus"}
#: every parameter a calibration may free
PRIORS = {**CALIBRATED, **APPARATUS}


def parse_free(specs):
    """Calibrated parameters and bounds from ``--free`` strings ``NAME`` or ``NAME=LO:HI``.

    A name must be one of :data:`PRIORS`; a given range must lie inside the declared prior
    range (a calibration cannot claim a value outside the physical range). None or [] gives
    :data:`CALIBRATED`.

    Raises
    ------
    ValueError - unknown name, malformed or out-of-range bounds, a name given twice
    """
    if not specs:
        return dict(CALIBRATED)
    out = {}
    for spec in specs:
        name, _, rng = str(spec).partition("=")
        name = name.strip()
        if name not in PRIORS:
            raise ValueError("--free %s: not a calibratable parameter (known: %s)"
                             % (name, ", ".join(PRIORS)))
        if name in out:
            raise ValueError("--free %s given twice" % name)
        lo, hi = PRIORS[name]
        if rng:
            try:
                a, b = (float(x) for x in rng.split(":"))
            except ValueError:
                raise ValueError("--free %s: bounds must be LO:HI, got %r" % (name, rng))
            if not (math.isfinite(a) and math.isfinite(b) and a < b):
                raise ValueError("--free %s: need finite LO < HI, got %r" % (name, rng))
            if a < lo or b > hi:
                raise ValueError("--free %s: %g:%g leaves the declared range %g:%g"
                                 % (name, a, b, lo, hi))
            lo, hi = a, b
        out[name] = (lo, hi)
    return out


#: theta_ref, the reference point of every design (the base parameters of the replicated point
#: of wave 0, the baseline of the staircase, the blind datasets' neighbourhood): the Table-3
#: calibration of 2026-11 (its posterior mean, 4 significant digits). Declared here, not read
#: from results/calibration, so that a new calibration does not move every design's run ids.
REFERENCE = {"restitution": 0.3487, "static_friction": 0.4651, "rolling_friction": 0.2534,
             "amplitude_m": 0.0127}


def reference_parameters() -> dict:
    """theta_ref (:data:`REFERENCE`), a copy."""
    return dict(REFERENCE)


def effect_strengths() -> dict:
    """{effect name: (0, s_max, strength label)} of every candidate effect of the catalog
    (declared by the effects' files)."""
    from analysis.catalog import CANDIDATES, OPTIONAL_CANDIDATES
    return {c.name: (0.0, float(c.s_max), c.strength_label)
            for c in CANDIDATES + OPTIONAL_CANDIDATES}


# ------------------------------------------------------------------ points of the space

#: the powder line's coefficients a loop with yields fits beside the base parameters:
#: name -> (unit, lower, upper) (the prior a fit may claim; the paper's values are the start)
KINETICS_LINE = {"slope_pct_per_kj": ("%/kJ", 1.0, 30.0),
                 "intercept_pct": ("%", -20.0, 20.0)}


@dataclass(frozen=True)
class Coordinate:
    """One named coordinate of a point a fit moves: its unit and the bounds the fit keeps to.

    kind : 'contact' or 'apparatus' (a twin parameter, :data:`SPACE`), 'kinetics' (the powder
        line, :data:`KINETICS_LINE`), 'effect' (a candidate's strength, declared by its file)
        or 'model' (a name only a model declares, e.g. an analytic test model's)
    """
    name: str
    unit: str
    lower: float
    upper: float
    kind: str

    def __post_init__(self):
        if not (math.isfinite(self.lower) and math.isfinite(self.upper)
                and self.lower < self.upper):
            raise ValueError("%s: bounds must be finite with lower < upper, got %r"
                             % (self.name, (self.lower, self.upper)))


def _strength_unit(label: str) -> str:
    """The unit of a strength label 'param [unit]' (a linear strength); '-' otherwise."""
    return label[label.rindex("[") + 1:-1] if label.endswith("]") and "[" in label else "-"


def declared_unit(name: str, strengths=None) -> tuple:
    """(unit, kind) the project declares for ``name``: :data:`SPACE`, :data:`KINETICS_LINE`,
    an effect's strength (``strengths``: :func:`effect_strengths`, read when not given);
    ('-', 'model') for a name none declares."""
    if name in SPACE:
        return SPACE[name].unit, SPACE[name].role
    if name in KINETICS_LINE:
        return KINETICS_LINE[name][0], "kinetics"
    strengths = effect_strengths() if strengths is None else strengths
    if name in strengths:
        return _strength_unit(strengths[name][2]), "effect"
    return "-", "model"


def coordinates_of(base_params, effects=()) -> dict:
    """{name: Coordinate} of a model's fitted coordinates: its base parameters and its
    candidate effects' strengths (objects with name, lower, upper: a model's own bounds, which
    a ``--free NAME=LO:HI`` may narrow), each with the unit the project declares."""
    out, strengths = {}, effect_strengths()
    for p in list(base_params) + list(effects):
        unit, kind = declared_unit(p.name, strengths)
        out[p.name] = Coordinate(p.name, unit, float(p.lower), float(p.upper), kind)
    return out


class ParameterVector(Mapping):
    """A point of the parameter space: a finite value per named :class:`Coordinate`, in a
    fixed order. It reads as a mapping name -> float (every model's ``predict`` takes one) and
    carries each coordinate's unit and bounds; it is immutable (``|`` merges two, ``only``
    picks names).

    Raises ValueError for a name without a coordinate or a value that is not a finite number.
    """

    __slots__ = ("_values", "_coords")

    def __init__(self, values, coords):
        vals = {}
        for k, v in dict(values).items():
            if k not in coords:
                raise ValueError("parameter %r has no declaration here (known: %s)"
                                 % (k, ", ".join(coords)))
            try:
                f = float(v)
            except (TypeError, ValueError):
                raise ValueError("parameter %s: %r is not a number" % (k, v))
            if not math.isfinite(f):
                raise ValueError("parameter %s: %r is not a finite number" % (k, v))
            vals[k] = f
        self._values = vals
        self._coords = {k: coords[k] for k in vals}

    @classmethod
    def of(cls, params, names, coords):
        """The values of ``names`` read from ``params`` (a fit's Series or a mapping)."""
        return cls({k: params[k] for k in names}, coords)

    def __getitem__(self, name):
        return self._values[name]

    def __iter__(self):
        return iter(self._values)

    def __len__(self):
        return len(self._values)

    def __or__(self, other):
        """This point with ``other``'s coordinates added (and its values where both name one)."""
        coords = dict(self._coords, **other.coordinates)
        return ParameterVector(dict(self._values, **dict(other)), coords)

    @property
    def coordinates(self) -> dict:
        """{name: Coordinate} of this point's names."""
        return dict(self._coords)

    def unit(self, name) -> str:
        return self._coords[name].unit

    def bounds(self, name) -> tuple:
        c = self._coords[name]
        return c.lower, c.upper

    def only(self, names):
        """The point restricted to ``names`` (those it has), in its own order."""
        keep = set(names)
        return ParameterVector({k: v for k, v in self._values.items() if k in keep},
                               self._coords)

    def outside_bounds(self) -> list:
        """Names whose value lies outside its coordinate's bounds."""
        return [k for k, v in self._values.items()
                if not self._coords[k].lower <= v <= self._coords[k].upper]

    def to_dict(self) -> dict:
        """{name: value} (plain floats: JSON, a DataFrame row)."""
        return dict(self._values)

    def describe(self, digits=4) -> str:
        """'name value [unit], ...' (SI, as declared)."""
        return ", ".join("%s %.*g [%s]" % (k, digits, v, self._coords[k].unit)
                         for k, v in self._values.items())

    def __repr__(self):
        return "ParameterVector(%s)" % self.describe()
