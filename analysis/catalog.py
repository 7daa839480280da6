"""The diagnose catalog: every catalog effect as a candidate of the loop's diagnosis and a
strength input of its emulator (:mod:`analysis.emulated_twin`) - a candidate (:class:`Candidate`), declared by the effect files themselves (the "diagnose" entry of
each effect's DECLARATION, :func:`effects.diagnose_entries`): :data:`CANDIDATES`, :data:`DECOYS`,
:data:`OPTIONAL_CANDIDATES` and the lookup :func:`candidates`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from effects import diagnose_entries

@dataclass(frozen=True)
class Candidate:
    """One catalog effect as a diagnose candidate, declared by the effect's own file (the
    "diagnose" entry of its DECLARATION, :meth:`from_declaration`).

    name : effect module name
    kind : 'dem', 'kinetics' or 'observation'
    param : the catalog parameter the strength sets
    s_max : top of the diagnose range of the strength coordinate (the signature strength of a
        DEM effect)
    unit : unit of the strength coordinate
    coord : 'linear' (strength = param), 'inv_square' (strength = (p0 / param)^2) or
        'square' (strength = (param / p0)^2)
    p0 : reference of the non-linear coordinates
    fixed : further parameters of the effect (defaults otherwise)
    """

    name: str
    kind: str
    param: str
    s_max: float
    unit: str
    coord: str = "linear"
    p0: float = 1.0
    fixed: tuple = ()

    def param_value(self, s):
        """Catalog parameter value for strength ``s`` (> 0)."""
        if self.coord == "linear":
            return float(s)
        if self.coord == "inv_square":
            return float(self.p0 / math.sqrt(s))
        if self.coord == "square":
            return float(self.p0 * math.sqrt(s))
        raise ValueError("unknown strength coordinate %r" % self.coord)

    def strength_of(self, value):
        """Strength coordinate of a catalog parameter value."""
        if self.coord == "linear":
            return float(value)
        if self.coord == "inv_square":
            return float((self.p0 / value) ** 2)
        return float((value / self.p0) ** 2)

    def spec(self, s):
        """The effects-config entry {name: {param: value, ...}} at strength ``s`` > 0."""
        return {self.name: dict(dict(self.fixed), **{self.param: self.param_value(s)})}

    @property
    def strength_label(self):
        if self.coord == "linear":
            return "%s [%s]" % (self.param, self.unit)
        if self.coord == "inv_square":
            return "(%g %s / %s)^2" % (self.p0, self.unit, self.param)
        return "(%s / %g %s)^2" % (self.param, self.p0, self.unit)

    @classmethod
    def from_declaration(cls, name, kind, entry):
        """The candidate an effect declares: its DECLARATION's "diagnose" entry (the fields
        above; "order", "optional" and "decoy" are the catalog's, not the candidate's)."""
        fixed = entry.get("fixed") or {}
        return cls(name, kind, entry["param"], float(entry["s_max"]), entry["unit"],
                   coord=entry.get("coord", "linear"), p0=float(entry.get("p0", 1.0)),
                   fixed=tuple(dict(fixed).items()))


def _declared_candidates(optional):
    """The candidates the effect files declare (effects.diagnose_entries, in their "order"),
    the optional ones or the default catalog."""
    return tuple(Candidate.from_declaration(name, kind, entry)
                 for name, kind, entry in diagnose_entries()
                 if bool(entry.get("optional", False)) == optional)


# The diagnose catalog is declared by the effects themselves (each effect file's DECLARATION
# "diagnose" entry, ordered by its "order"). The diagnose ranges: physically plausible, and wide
# enough that the top moves v_mean by a few per cent (signature strengths; the pilot figures were
# in results/signatures/README.md, removed with the signature library - git history keeps it).
CANDIDATES = _declared_candidates(optional=False)
#: effects whose footprint is below the twin's chaos (their entry's "decoy"): never to be named
DECOYS = tuple(name for name, _, entry in diagnose_entries()
               if entry.get("decoy", False))
#: catalog entries diagnosed only when asked for (``python -m analysis.loop --with-effect``;
#: their entry's "optional"): the apparatus effects (docs/apparatus.md), whose responses the
#: committed runs do not hold
OPTIONAL_CANDIDATES = _declared_candidates(optional=True)


def candidates(kind=None):
    """The candidates of one kind ('dem', 'kinetics', 'observation') or all, by name (the optional ones
    included: this is the lookup; the default catalog is :data:`CANDIDATES`)."""
    return {c.name: c for c in CANDIDATES + OPTIONAL_CANDIDATES
            if kind is None or c.kind == kind}
