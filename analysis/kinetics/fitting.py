"""The whole kinetics fit: the powder line and the regime boundaries from yield data.

:func:`fit_kinetics` chooses the powder samples (phase labels, or the fitted boundary), fits the
line (:mod:`analysis.kinetics.model`) and the boundaries (:mod:`analysis.kinetics.boundaries`)
and returns a :class:`KineticsFit`, which is saved and loaded as JSON (``kinetics_fit.json``).
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from analysis.kinetics.boundaries import BoundaryResult, boundaries_from_phase, find_boundaries
from analysis.kinetics.model import REGIMES, KineticsInputError, LineFitResult, fit_powder_line


@dataclass
class KineticsFit:
    """Powder line + regime boundaries.

    Attributes
    ----------
    line : LineFitResult - powder-regime line
    boundaries : BoundaryResult - primary (least-squares) boundaries used for regimes
    alternatives : list of BoundaryResult - other boundary estimates (paper method, phase labels)
    powder_selection : str - "phase" (points labelled powder) or "boundary" (E < powder_wax_j)
    complete_band_pct : tuple - 2.5 and 97.5 % quantiles of observed complete-regime yields
    source : str - where the data and energy inputs came from (e.g. SYNTHETIC ...)
    """

    line: LineFitResult
    boundaries: BoundaryResult
    alternatives: list
    powder_selection: str
    complete_band_pct: tuple
    source: str = ""

    @property
    def params(self) -> pd.Series:
        return pd.concat([self.line.params, self.boundaries.params[["powder_wax_j", "wax_complete_j"]]])

    @property
    def stderr(self) -> pd.Series:
        return pd.concat([self.line.stderr, self.boundaries.stderr])

    @property
    def residuals(self) -> np.ndarray:
        return self.line.residuals

    def to_frame(self) -> pd.DataFrame:
        line = self.line.to_frame().rename(columns={"param": "name"})
        line["kind"] = "powder_line"
        bnd = pd.concat([b.to_frame() for b in [self.boundaries] + list(self.alternatives)])
        bnd = bnd.rename(columns={"boundary": "name", "value_j": "value", "stderr_j": "stderr",
                                  "ci_lo_j": "ci_lo", "ci_hi_j": "ci_hi"})
        bnd["kind"] = "boundary_" + bnd["method"]
        return pd.concat([line, bnd], ignore_index=True)

    def to_dict(self) -> dict:
        return {"line": self.line.to_dict(), "boundaries": self.boundaries.to_dict(),
                "alternatives": [b.to_dict() for b in self.alternatives],
                "powder_selection": self.powder_selection,
                "complete_band_pct": list(self.complete_band_pct), "source": self.source}

    @classmethod
    def from_dict(cls, d: dict) -> "KineticsFit":
        return cls(line=LineFitResult.from_dict(d["line"]),
                   boundaries=BoundaryResult.from_dict(d["boundaries"]),
                   alternatives=[BoundaryResult.from_dict(b) for b in d["alternatives"]],
                   powder_selection=d["powder_selection"],
                   complete_band_pct=tuple(d["complete_band_pct"]), source=d.get("source", ""))

    def save(self, path: Path) -> None:
        path = Path(path)
        tmp = path.with_suffix(path.suffix + ".tmp")
        tmp.write_text(json.dumps(self.to_dict(), indent=1))
        tmp.replace(path)

    @classmethod
    def load(cls, path: Path) -> "KineticsFit":
        return cls.from_dict(json.loads(Path(path).read_text()))


def fit_kinetics(e_tot_j, yield_pct, phase=None, method: str = "continuous", n_boot: int = 200,
                 primary: str = "auto", random_state=0, source: str = "") -> KineticsFit:
    """Fit the powder line and the two regime boundaries.

    Parameters
    ----------
    e_tot_j, yield_pct : ndarray, shape (n,) - cumulative energy [J] and yield [%]
    phase : array of str, shape (n,), optional - recorded phase per sample; when given the
        powder line uses the samples labelled 'powder' and phase-label boundaries are computed
    method : {"continuous", "candidates"} - least-squares boundary method (the other one is
        computed too; both are kept)
    n_boot : int - bootstrap replicates for the least-squares boundaries
    primary : {"auto", "ls", "phase"} - which boundaries define the regimes used for prediction:
        "auto" = phase labels when present, else least squares
    """
    e = np.asarray(e_tot_j, dtype=float)
    x = np.asarray(yield_pct, dtype=float)
    other = "candidates" if method == "continuous" else "continuous"
    ls = find_boundaries(e, x, method=method, n_boot=n_boot, random_state=random_state)
    ls_other = find_boundaries(e, x, method=other, n_boot=n_boot, random_state=random_state)
    ph = None
    if phase is not None:
        ph = pd.Series(phase).astype("string").str.strip().str.lower().fillna("").to_numpy(str)
        if not np.isin(ph, REGIMES).any():
            ph = None
    if primary not in ("auto", "ls", "phase"):
        raise KineticsInputError(f"primary must be 'auto', 'ls' or 'phase', got {primary!r}")
    if primary == "phase" and ph is None:
        raise KineticsInputError("primary='phase' needs a phase column with labels")
    found = [ls, ls_other]
    if ph is not None:
        found.append(boundaries_from_phase(e, ph))
    use_phase_bnd = ph is not None and primary in ("auto", "phase")
    main_b = found[-1] if use_phase_bnd else ls
    alts = [b for b in found if b is not main_b]
    if ph is not None:
        powder = ph == "powder"
        complete = ph == "complete"
        selection = "phase"
    else:
        powder = e < main_b.powder_wax_j
        complete = e >= main_b.wax_complete_j
        selection = "boundary"
    line = fit_powder_line(e[powder], x[powder])
    band = (tuple(np.quantile(x[complete], [0.025, 0.975]).tolist()) if complete.any()
            else (np.nan, np.nan))
    return KineticsFit(line=line, boundaries=main_b, alternatives=alts,
                       powder_selection=selection, complete_band_pct=band, source=source)
