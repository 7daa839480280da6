"""The yield-dataset loader: a validating view over :mod:`analysis.measurements`.

A measurement dataset ``data/measurements/<name>/`` holds ``dataset.json``, ``conditions.csv``
(condition_id, frequency_hz, ball_diameter_mm, ...) and ``yields.csv`` (condition_id, time_min,
yield_pct, optional yield_sd_pct and phase). :func:`load_yield_dataset` reads them; any problem
raises :class:`YieldDataError` naming the file, row (1-based line number in the file, header =
line 1) and column.

The contract of conditions.csv and yields.csv (columns, units, numeric rules) is declared once,
in :mod:`analysis.measurements`, which reads and validates both files; the yield tools are
stricter (times non-decreasing within a condition, phase one of powder / wax / complete). This
module only presents the result: its row numbers are file lines, phase labels are lower case or
NA, columns outside the contract get pandas' CSV types, and dataset.json needs only ``name`` (no
summary.csv is needed). It depends on measurements only, so the kinetics stage and the synthetic
generator (:mod:`analysis.yield_data`, which re-exports these names) both read yields through it.
"""
from __future__ import annotations

import io
import re
from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from analysis import config
from analysis import measurements

SYNTHETIC_DATASET_NAME = "synthetic_yields_paper"
SYNTHETIC_DATASET_DIR = config.MEASUREMENTS_DIR / SYNTHETIC_DATASET_NAME
PHASES = measurements.PHASES


class YieldDataError(measurements.DatasetError):
    """Malformed yield dataset; the message names file, row (the file line) and column.

    A :class:`analysis.measurements.DatasetError` (so a ValueError) raised by the shared contract
    and restated with this module's row numbers."""


@dataclass
class YieldDataset:
    """A loaded yield dataset.

    Attributes
    ----------
    name : str
    meta : dict - dataset.json
    conditions : DataFrame - condition_id, frequency_hz, ball_diameter_mm, ...
    yields : DataFrame - condition_id, time_min, yield_pct, phase (lower case or NA), ...
    path : Path
    """

    name: str
    meta: dict
    conditions: pd.DataFrame
    yields: pd.DataFrame
    path: Path | None = None

    @property
    def synthetic(self) -> bool:
        return bool(self.meta.get("synthetic", False))


# --------------------------------------------------------------------------------------------
# loader
# --------------------------------------------------------------------------------------------
_ROW_LINE = re.compile(r"\brow (\d+) \(line (\d+)\)")


def _file_lines(message: str) -> str:
    """``message`` of the shared contract with this module's row numbers: 'row 5 (line 6)' (data
    row and file line) becomes 'row 6' (the file line)."""
    return _ROW_LINE.sub(lambda m: "row " + m.group(2), message)


def _shared(fn, *args, **kwargs):
    """``fn(*args, **kwargs)`` of :mod:`analysis.measurements`; its DatasetError as a
    YieldDataError."""
    try:
        return fn(*args, **kwargs)
    except YieldDataError:
        raise
    except measurements.DatasetError as exc:
        raise YieldDataError(_file_lines(str(exc))) from None


def _pandas_types(table: pd.DataFrame, contract) -> pd.DataFrame:
    """``table`` with its columns outside the contract (read as text) typed as
    ``pandas.read_csv`` types them (numbers, NaN for empty cells): the types this module has
    always given them (e.g. the generator's e_tot_j_true)."""
    extra = [c for c in table.columns if c not in contract]
    if not extra:
        return table
    typed = pd.read_csv(io.StringIO(table[extra].to_csv(index=False)))
    out = table.copy()
    for col in extra:
        out[col] = typed[col].to_numpy()
    return out


def _view(checked: pd.DataFrame, given: pd.DataFrame, contract) -> pd.DataFrame:
    """``given`` with the contract's columns replaced by the validated ``checked`` ones."""
    out = given.copy()
    for col in contract:
        if col in checked.columns:
            out[col] = checked[col].to_numpy()
    return out


def validate_conditions(df: pd.DataFrame, path: Path) -> pd.DataFrame:
    """Check a conditions table; returns a cleaned copy (numeric columns as float).

    The contract is :func:`analysis.measurements.validate_conditions_table` (required
    condition_id, frequency_hz, ball_diameter_mm; optional amplitude_mm, n_balls, fill_g; units;
    positive and plausible values; unique ids). Columns outside it are returned as given.
    Raises :class:`YieldDataError`.
    """
    checked = _shared(measurements.validate_conditions_table, df, str(path))
    return _view(checked, df, measurements.CONDITIONS_COLUMNS)


def validate_yields(df: pd.DataFrame, path: Path, condition_ids) -> pd.DataFrame:
    """Check a yields table against the known condition ids; returns a cleaned copy.

    Errors (:func:`analysis.measurements.validate_yields_table`): missing column or wrong unit,
    empty / NaN / non-numeric cell, negative time, times decreasing within a condition (equal
    times = replicates are allowed), yield < 0 or > 100 %, negative yield_sd_pct, unknown
    condition, phase not one of powder / wax / complete. The phase column is returned lower
    case, NA where empty; other columns outside the contract as given.
    """
    checked = _shared(measurements.validate_yields_table, df, condition_ids, str(path),
                      strict=True)
    out = _view(checked, df, measurements.YIELDS_COLUMNS)
    if "phase" in out.columns:
        out["phase"] = pd.Series([measurements.phase_label(v) for v in checked["phase"]],
                                 index=out.index, dtype="string")
    return out


def load_yield_dataset(path) -> YieldDataset:
    """Load and validate ``<path>/dataset.json``, ``conditions.csv`` and ``yields.csv``.

    The files are read and checked by :mod:`analysis.measurements` (the one declaration of the
    dataset contract); this returns that view of them (see the module doc).

    Raises
    ------
    YieldDataError on any malformed input (message names file, row, column).
    """
    path = Path(path)
    if not path.is_dir():
        raise YieldDataError(f"{path}: dataset folder not found")
    meta = _shared(measurements.read_json, path / "dataset.json")
    if not isinstance(meta, dict) or "name" not in meta:
        raise YieldDataError(f"{path / 'dataset.json'}: missing field 'name'")
    cond = validate_conditions(_shared(measurements.read_table, path / "conditions.csv"),
                               path / "conditions.csv")
    yields = validate_yields(_shared(measurements.read_table, path / "yields.csv"),
                             path / "yields.csv", cond["condition_id"])
    return YieldDataset(name=str(meta["name"]), meta=meta,
                        conditions=_pandas_types(cond, measurements.CONDITIONS_COLUMNS),
                        yields=_pandas_types(yields, measurements.YIELDS_COLUMNS), path=path)
