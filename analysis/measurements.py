"""Measurement datasets: load, validate and write ``data/measurements/<name>/``.

A dataset is what a user brings to compare the twin with (docs/dataset_format.md):

==========================  =====================================================  ========
file                        columns                                                needed
==========================  =====================================================  ========
dataset.json                name, description, source, velocity_frame (lab|jar)    yes
                            [synthetic: true for generated data, marked SYNTHETIC
                            on every figure and page made from it]
conditions.csv              condition_id, frequency_hz, ball_diameter_mm           yes
                            [amplitude_mm, n_balls, fill_g]
summary.csv                 condition_id, v_mean_m_s, v_mean_sd_m_s, f_col_hz,      yes
                            f_col_sd_hz (sd cells may be empty)
tracks/<condition_id>.csv   t_s, x_m, y_m (camera plane, x along the jar axis)     no
                            [jar_x_m: the jar's x in the same frames, for the
                            impact observables of analysis.flights]
videos/<condition_id>.*     + videos/video.json: fps, ball_diameter_px or m_per_px  no
                            [exposure_s, smoothing_window_frames,
                            smoothing_polyorder, scale_method: the observation
                            chain, :func:`observation_pins`]
yields.csv                  condition_id, time_min, yield_pct                      no
                            [yield_sd_pct, phase: powder | wax | complete]
==========================  =====================================================  ========

Units sit in the column names. Unknown columns are kept and ignored. Any violation of the
contract (missing required column, a column carrying the wrong unit such as ``v_mean_mm_s`` or
``frequency_rpm``, an empty or non-numeric or NaN cell in a required column, a negative
frequency, a duplicate or unknown ``condition_id``, a yield outside [0, 100] %, a zero or
negative sd, a value implausible for its unit - :data:`PLAUSIBLE` and the track bounds
``TRACK_*`` / ``JAR_AMPLITUDE_*``, the likely unit slip named) raises ONE :class:`DatasetError`
that names the file, the row and the column. A track's lost frame (a gap) is a row with its t_s
and empty (or NaN) x_m and y_m. CSV and JSON files may start with a UTF-8 byte-order mark; a
JSON key given twice is refused. A frequency outside the twin's tested range
(``FREQUENCY_TESTED_MIN_HZ`` - ``FREQUENCY_TESTED_MAX_HZ``) is accepted with a warning
(:func:`input_warnings`). yields.csv rows may come in
any order and a ``phase`` cell is kept as read; the yield-data tools (:mod:`analysis.yield_data`)
are stricter (times non-decreasing within a condition, phase one of powder / wax / complete).

This module is the one parser of the dataset files: :mod:`analysis.yield_data` reads
conditions.csv and yields.csv through :func:`read_table`, :func:`validate_conditions_table` and
:func:`validate_yields_table`, and only presents the result (its own row numbering, phase
labels normalised, pandas column types).

Row numbers in messages count data rows from 1; the file line is ``row + 1`` (line 1 is the
header).

Default measurement uncertainty
-------------------------------
Empty sd cells are reported by :attr:`Dataset.missing_sd` and replaced in
:func:`measurement_table` by documented defaults (parameters of that function):

* ``v_rel_sd = 0.015``: 1.5 % of the measured mean speed. Single-ball tracking at 2134 fps with the
  ball diameter as length scale gives a scale error of about 1 % (one pixel on ~70 px) plus
  frame-to-frame scatter; 1.5 % is a deliberately modest figure.
* ``f_col_sd_hz = 1.0``: one collision per second (the count over a 0.5 s record is an integer
  divided by the record length, +-2 /s; 1 /s is its standard uncertainty for a uniform rounding).
* ``yield_sd_pct = 2.0``: two percentage points for yields (where yields.csv has no
  ``yield_sd_pct`` column or an empty cell in it), applied by :func:`yield_table`.
"""
from __future__ import annotations

import argparse
import csv
import difflib
import json
import math
import shutil
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from analysis.atomic_dir import output_dir

#: default relative sd of the measured mean speed when v_mean_sd_m_s is empty
DEFAULT_V_REL_SD = 0.015
#: default sd of the measured collision frequency [1/s] when f_col_sd_hz is empty
DEFAULT_F_COL_SD_HZ = 1.0
#: default sd of a measured yield [percentage points]
DEFAULT_YIELD_SD_PCT = 2.0

#: observables of summary.csv: observable name -> sd column
SUMMARY_OBSERVABLES = {"v_mean_m_s": "v_mean_sd_m_s", "f_col_hz": "f_col_sd_hz"}

VELOCITY_FRAMES = ("lab", "jar")

#: labels of the optional yields.csv column ``phase`` (case and surrounding blanks ignored)
PHASES = ("powder", "wax", "complete")
#: phase cells that mean "no label" (empty, or a usual spelling of a missing value)
_NO_LABEL = {"", "na", "n/a", "nan", "null", "none", "<na>", "#n/a"}

# unit suffix tokens recognised when looking for a column that carries the wrong unit
_UNIT_TOKENS = {
    "m", "mm", "cm", "um", "km", "in", "inch", "px", "m_s", "mm_s", "cm_s", "km_h", "m_min",
    "mm_min", "hz", "khz", "rpm", "rps", "1_s", "per_s", "rad_s", "s", "ms", "us", "min", "h",
    "hr", "pct", "percent", "frac", "fraction", "g", "kg", "mg", "n", "j", "kj",
}

# required and optional columns: name -> (kind, rule); kind 'float', 'int', 'str'
# rules: 'pos' (> 0), 'nonneg' (>= 0), 'any' (finite), 'pct' (0..100), 'posint' (1, 2, ...),
# 'id' (non-empty text), 'phase' (one of PHASES or no label; kept as read), 'mode' (one of
# the twin's motion modes, yade_scripts.twin_modes.MOTION_MODES, or empty: not stated)
_CONDITIONS_REQUIRED = {"condition_id": "id", "frequency_hz": "pos", "ball_diameter_mm": "pos"}
_CONDITIONS_OPTIONAL = {"amplitude_mm": "pos", "n_balls": "posint", "fill_g": "nonneg",
                        "motion_mode": "mode"}
# 'sd': > 0 (a standard deviation: negative is impossible, 0 claims an exact measurement)
_SUMMARY_REQUIRED = {"condition_id": "id", "v_mean_m_s": "nonneg", "f_col_hz": "nonneg"}
_SUMMARY_SD = {"v_mean_sd_m_s": "sd", "f_col_sd_hz": "sd"}  # required columns, empty cells ok
# a track's positions may be empty (or NaN) on a frame the ball was not found: a gap; t_s may not
_TRACK_REQUIRED = {"t_s": "any"}
_TRACK_POSITIONS = {"x_m": "any", "y_m": "any"}
#: optional: the jar's displacement along x in the same frames (a marker on the jar), which
#: analysis.flights needs for the impact observables
_TRACK_OPTIONAL = {"jar_x_m": "any"}
_YIELDS_REQUIRED = {"condition_id": "id", "time_min": "nonneg", "yield_pct": "pct"}
_YIELDS_OPTIONAL = {"yield_sd_pct": "sd", "phase": "phase"}
#: every column of the conditions.csv and yields.csv contracts (required, then optional)
CONDITIONS_COLUMNS = tuple(_CONDITIONS_REQUIRED) + tuple(_CONDITIONS_OPTIONAL)
YIELDS_COLUMNS = tuple(_YIELDS_REQUIRED) + tuple(_YIELDS_OPTIONAL)

_RULE_TEXT = {"pos": "must be > 0", "nonneg": "must be >= 0", "posint": "must be a positive integer",
              "pct": "is outside [0, 100] %", "any": "must be finite",
              "sd": "must be >= 0 (a standard deviation is never negative)"}
#: the refusal of a zero sd (rule 'sd')
_ZERO_SD_TEXT = ("sd 0 claims an exact measurement (infinite weight in chi2): give the measured "
                 "sd, or leave the cell empty for the documented default")
#: cells of a track's position columns that mark a lost frame (a gap), besides an empty cell
_GAP_CELLS = {"nan", "NaN", "NAN"}


class DatasetError(ValueError):
    """A measurement dataset violates the contract. The message names file, row and column."""


@dataclass
class Dataset:
    """A validated measurement dataset.

    Attributes
    ----------
    name, description, source : str
        from dataset.json
    velocity_frame : {'lab', 'jar'}
        frame in which v_mean_m_s (and tracks) are given
    conditions : DataFrame, shape (n_conditions, >= 3)
        condition_id, frequency_hz, ball_diameter_mm [, amplitude_mm, n_balls, fill_g, ...];
        unknown columns kept as they were read (strings)
    summary : DataFrame, shape (n_summary, >= 5)
        condition_id, v_mean_m_s, v_mean_sd_m_s, f_col_hz, f_col_sd_hz (NaN where empty)
    tracks : dict[str, DataFrame]
        condition_id -> t_s, x_m, y_m (camera plane)
    video : dict or None
        videos/video.json (fps, ball_diameter_px or m_per_px; optional exposure_s,
        smoothing_window_frames, smoothing_polyorder, scale_method)
    video_files : dict[str, Path]
        condition_id -> video file
    yields : DataFrame or None
        condition_id, time_min, yield_pct [, phase, yield_sd_pct]
    meta : dict
        the whole dataset.json
    path : Path or None
        folder the dataset was read from
    """

    name: str
    description: str
    source: str
    velocity_frame: str
    conditions: pd.DataFrame
    summary: pd.DataFrame
    tracks: dict = field(default_factory=dict)
    video: dict | None = None
    video_files: dict = field(default_factory=dict)
    yields: pd.DataFrame | None = None
    meta: dict = field(default_factory=dict)
    path: Path | None = None

    @property
    def condition_ids(self) -> list:
        """Condition ids in file order."""
        return list(self.conditions["condition_id"])

    @property
    def missing_sd(self) -> dict:
        """sd columns with empty cells: {sd column: [condition_id, ...]} (only non-empty lists)."""
        out = {}
        for col in _SUMMARY_SD:
            ids = list(self.summary.loc[self.summary[col].isna(), "condition_id"])
            if ids:
                out[col] = ids
        return out

    @property
    def synthetic(self) -> bool:
        """True when dataset.json says ``"synthetic": true`` (generated data, not measured)."""
        return self.meta.get("synthetic", False) is True

    @property
    def observation_chain(self) -> dict:
        """What videos/video.json states about how the films were observed: ``fps`` and those
        of :data:`VIDEO_CHAIN_KEYS` it holds ({} without a video.json); the observation
        effects these pin: :func:`observation_pins`."""
        if self.video is None:
            return {}
        return {k: self.video[k] for k in ("fps",) + VIDEO_CHAIN_KEYS if k in self.video}

    @property
    def warnings(self) -> list:
        """Inputs accepted but outside what the twin is tested on, one line each
        (:func:`input_warnings`: a frequency outside the tested range)."""
        return input_warnings(self)

    def condition_label(self, condition_id) -> str:
        """Plain-words label, e.g. '20.6 mm ball at 22.5 Hz'."""
        row = self.conditions.set_index("condition_id").loc[condition_id]
        return "%g mm ball at %g Hz" % (row["ball_diameter_mm"], row["frequency_hz"])


# --------------------------------------------------------------------------- validation helpers

def _where(fname, row=None, col=None):
    parts = [str(fname)]
    if row is not None:
        parts.append("row %d (line %d)" % (row, row + 1))
    if col is not None:
        parts.append("column %r" % col)
    return ", ".join(parts)


def _base_and_unit(col):
    """Split 'v_mean_mm_s' -> ('v_mean', 'mm_s') when the tail is a unit token, else None."""
    parts = col.split("_")
    for k in range(1, len(parts)):
        tail = "_".join(parts[k:])
        if tail in _UNIT_TOKENS:
            return "_".join(parts[:k]), tail
    return None


def _check_columns(df, fname, required):
    """Raise DatasetError if a required column is missing (naming a wrong-unit lookalike)."""
    cols = list(df.columns)
    for req in required:
        if req in cols:
            continue
        split = _base_and_unit(req)
        if split is not None:
            base, unit = split
            for c in cols:
                other = _base_and_unit(c)
                if c == base:
                    raise DatasetError("%s: column %r carries no unit; the contract needs %r [%s]"
                                       % (fname, c, req, unit.replace("_", "/")))
                if other is not None and other[0] == base and other[1] != unit:
                    raise DatasetError(
                        "%s: column %r has the wrong unit (%s); the contract needs %r [%s] - "
                        "convert the values and rename the column"
                        % (fname, c, other[1].replace("_", "/"), req, unit.replace("_", "/")))
        raise DatasetError("%s: required column %r is missing (columns found: %s)"
                           % (fname, req, ", ".join(cols) or "none"))
    dup = [c for c in cols if cols.count(c) > 1]
    if dup:
        raise DatasetError("%s: column %r appears more than once" % (fname, dup[0]))


def _parse_number(text, fname, row, col, rule, allow_empty):
    s = "" if text is None else str(text).strip()
    if s == "" or (isinstance(text, float) and math.isnan(text)):
        if allow_empty:
            return float("nan")
        raise DatasetError("%s: empty cell (a number is required)" % _where(fname, row, col))
    try:
        val = float(s)
    except ValueError:
        raise DatasetError("%s: %r is not a number" % (_where(fname, row, col), s)) from None
    if not math.isfinite(val):
        raise DatasetError("%s: value is %s (a finite number is required)"
                           % (_where(fname, row, col), s))
    if rule == "sd" and val == 0:
        raise DatasetError("%s: %s" % (_where(fname, row, col), _ZERO_SD_TEXT))
    bad = ((rule == "pos" and val <= 0) or (rule in ("nonneg", "sd") and val < 0)
           or (rule == "pct" and not 0.0 <= val <= 100.0)
           or (rule == "posint" and (val < 1 or val != int(val))))
    if bad:
        what = "value "
        for noun in ("frequency", "time"):
            if col.startswith(noun) and val < 0:
                what = "negative %s " % noun
        raise DatasetError("%s: %s%g %s" % (_where(fname, row, col), what, val, _RULE_TEXT[rule]))
    return val


def phase_label(cell):
    """The phase label of a yields.csv ``phase`` cell: one of :data:`PHASES` (case and blanks
    ignored), or None for an empty cell or a missing-value spelling (NA, nan, ...).

    Raises
    ------
    ValueError : any other text
    """
    if cell is None or (isinstance(cell, float) and math.isnan(cell)) or cell is pd.NA:
        return None
    s = str(cell).strip().lower()
    if s in _NO_LABEL:
        return None
    if s not in PHASES:
        raise ValueError(cell)
    return s


def _validate_table(df, fname, required, optional=None, empty_ok=None, known_ids=None,
                    unique_ids=False):
    """Validate a table read as strings; return a copy with numeric columns converted.

    Parameters
    ----------
    df : DataFrame of str
    fname : str, file name used in messages
    required : dict column -> rule; optional : dict column -> rule (empty cells allowed)
    empty_ok : dict column -> rule; required columns whose cells may be empty
    known_ids : set or None; condition ids that must contain every row's condition_id
    unique_ids : bool; condition_id must not repeat
    """
    optional = optional or {}
    empty_ok = empty_ok or {}
    _check_columns(df, fname, list(required) + list(empty_ok))
    if len(df) == 0:
        raise DatasetError("%s: no data rows" % fname)
    out = df.copy()
    seen = {}
    for col, rule in list(required.items()) + list(empty_ok.items()) + list(optional.items()):
        if col not in df.columns:
            continue
        allow_empty = col in empty_ok or col in optional
        if rule == "id":
            vals = []
            for i, v in enumerate(df[col], start=1):
                s = "" if v is None else str(v).strip()
                if s == "":
                    raise DatasetError("%s: empty condition_id" % _where(fname, i, col))
                if unique_ids:
                    if s in seen:
                        raise DatasetError(
                            "%s: duplicate condition_id %r, first at row %d (line %d)"
                            % (_where(fname, i, col), s, seen[s], seen[s] + 1))
                    seen[s] = i
                if known_ids is not None and s not in known_ids:
                    raise DatasetError("%s: unknown condition_id %r (not in conditions.csv)"
                                       % (_where(fname, i, col), s))
                vals.append(s)
            out[col] = vals
            continue
        if rule == "text":
            continue                       # kept as read, unchecked
        if rule == "mode":
            from yade_scripts.twin_modes import MOTION_MODES
            vals = ["" if pd.isna(v) else str(v).strip() for v in df[col]]
            for i, v in enumerate(vals, start=1):
                if v and v not in MOTION_MODES:
                    raise DatasetError("%s: motion mode %r is not one of %s (or empty: not "
                                       "stated)" % (_where(fname, i, col), v,
                                                    ", ".join(MOTION_MODES)))
            out[col] = vals
            continue
        if rule == "phase":
            for i, v in enumerate(df[col], start=1):
                try:
                    phase_label(v)
                except ValueError:
                    raise DatasetError("%s: phase %r is not one of %s (or empty)"
                                       % (_where(fname, i, col), str(v).strip(), ", ".join(PHASES))
                                       ) from None
            continue                       # kept as read
        vals = [_parse_number(v, fname, i, col, rule, allow_empty)
                for i, v in enumerate(df[col], start=1)]
        out[col] = np.asarray(vals, dtype=float)
        if rule == "posint" and not np.isnan(out[col]).any():
            out[col] = out[col].astype(int)
    return out


def read_table(path, fname=None):
    """Read a dataset CSV as strings; every row must have as many fields as the header.

    Parameters
    ----------
    path : str or Path
    fname : str, optional - the name used in messages (default: ``path``)

    Returns
    -------
    DataFrame of str (empty cells are ''), header names stripped

    Raises
    ------
    DatasetError : file missing, not text, or a row with the wrong number of fields
    """
    fname = str(path) if fname is None else fname
    try:
        # utf-8-sig: a byte-order mark (a spreadsheet's "CSV UTF-8") is not part of the header
        with open(path, newline="", encoding="utf-8-sig") as fh:
            rows = list(csv.reader(fh, skipinitialspace=True))
    except FileNotFoundError:
        raise DatasetError("%s: file is missing" % fname) from None
    except IsADirectoryError:
        raise DatasetError("%s: is a folder, not a file" % fname) from None
    except (UnicodeDecodeError, csv.Error) as exc:
        raise DatasetError("%s: malformed CSV (%s)" % (fname, exc)) from None
    rows = [r for r in rows if r]          # blank lines
    if not rows:
        raise DatasetError("%s: malformed CSV (empty file, no header)" % fname)
    header = [h.strip() for h in rows[0]]
    if len(header) == 1:
        sep = [c for c in ";\t|" if c in header[0]]
        if sep:         # a spreadsheet's regional "CSV": the whole header is one field
            raise DatasetError("%s: malformed CSV (the header is one field separated by %r; "
                               "write the file with commas as separators and points as decimal "
                               "marks)" % (fname, sep[0]))
    for i, r in enumerate(rows[1:], start=1):
        if len(r) != len(header):
            raise DatasetError("%s: malformed CSV (%d fields, the header has %d)"
                               % (_where(fname, i), len(r), len(header)))
    return pd.DataFrame(rows[1:], columns=header, dtype=str)


def read_json(path, fname=None):
    """The object in a JSON file (dataset.json, videos/video.json); DatasetError naming ``fname``
    (default ``path``) when the file is missing or malformed, or an object holds a key twice. A
    UTF-8 byte-order mark is ignored."""
    from analysis.config import twin_config
    fname = str(path) if fname is None else fname
    try:
        with open(path, encoding="utf-8") as fh:
            return twin_config.strict_json_loads(fh.read())
    except FileNotFoundError:
        raise DatasetError("%s: file is missing" % fname) from None
    except IsADirectoryError:
        raise DatasetError("%s: is a folder, not a file" % fname) from None
    except twin_config.DuplicateKeyError as exc:
        raise DatasetError("%s: %s" % (fname, exc)) from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise DatasetError("%s: malformed JSON (%s)" % (fname, exc)) from None


#: the keys of dataset.json the project reads (docs/dataset_format.md); an unknown key that is
#: a near miss of one of them is refused (a misspelt ``synthetic`` would drop the SYNTHETIC mark)
DATASET_KEYS = ("name", "description", "source", "velocity_frame", "synthetic")


def _validate_meta(meta, fname="dataset.json"):
    if not isinstance(meta, dict):
        raise DatasetError("%s: must hold a JSON object" % fname)
    for key in ("name", "description", "source", "velocity_frame"):
        if key not in meta:
            raise DatasetError("%s: required key %r is missing" % (fname, key))
        if not isinstance(meta[key], str):
            raise DatasetError("%s: key %r must be a string" % (fname, key))
    if meta["velocity_frame"] not in VELOCITY_FRAMES:
        raise DatasetError("%s: velocity_frame must be 'lab' or 'jar', got %r"
                           % (fname, meta["velocity_frame"]))
    for key in meta:
        near = difflib.get_close_matches(key, DATASET_KEYS, n=1, cutoff=0.8)
        if key not in DATASET_KEYS and near:
            raise DatasetError("%s: unknown key %r - did you mean %r? (other unknown keys are "
                               "kept and ignored)" % (fname, key, near[0]))
    if "synthetic" in meta and not isinstance(meta["synthetic"], bool):
        raise DatasetError("%s: key 'synthetic' must be true or false, got %r"
                           % (fname, meta["synthetic"]))


def _gap_cells(df, col):
    """Boolean array: the cells of ``col`` that mark a lost frame (empty, or NaN written out)."""
    return np.array([("" if v is None else str(v).strip()) in _GAP_CELLS | {""}
                     for v in df[col]], dtype=bool)


def _validate_track(df, fname):
    """A track table: t_s filled and strictly increasing at a uniform frame spacing; x_m, y_m
    filled, or both empty (or NaN) on a lost frame (a gap); the numbers plausible in seconds and
    metres (:func:`check_track_units`)."""
    _check_columns(df, fname, list(_TRACK_REQUIRED) + list(_TRACK_POSITIONS))
    gaps = {c: _gap_cells(df, c) for c in _TRACK_POSITIONS}
    half = np.flatnonzero(gaps["x_m"] != gaps["y_m"])
    if half.size:
        i = int(half[0])
        col, other = ("x_m", "y_m") if gaps["x_m"][i] else ("y_m", "x_m")
        raise DatasetError("%s: empty while %s is not; a lost frame (a gap) leaves both x_m and "
                           "y_m empty" % (_where(fname, i + 1, col), other))
    filled = df.copy()
    for c, g in gaps.items():               # validate the filled cells; gaps become NaN below
        filled.loc[g, c] = "0"
    jar_gap = _gap_cells(df, "jar_x_m") if "jar_x_m" in df.columns else None
    if jar_gap is not None:
        filled.loc[jar_gap, "jar_x_m"] = "0"
    out = _validate_table(filled, fname, dict(_TRACK_REQUIRED, **_TRACK_POSITIONS),
                          optional=_TRACK_OPTIONAL)
    for c, g in gaps.items():
        out[c] = np.where(g, np.nan, out[c].to_numpy(float))
    if jar_gap is not None:
        out["jar_x_m"] = np.where(jar_gap, np.nan, out["jar_x_m"].to_numpy(float))
    t = out["t_s"].to_numpy()
    bad = np.nonzero(np.diff(t) <= 0)[0]
    if bad.size:
        raise DatasetError("%s: t_s must increase strictly (it does not after row %d)"
                           % (_where(fname, int(bad[0]) + 2, "t_s"), int(bad[0]) + 1))
    n_pos = int((~gaps["x_m"]).sum())
    if n_pos < TRACK_MIN_FRAMES:
        raise DatasetError("%s: %d frames with a position; a track needs at least %d"
                           % (fname, n_pos, TRACK_MIN_FRAMES))
    frac = 1.0 - n_pos / len(out)
    if frac > TRACK_MAX_GAP_FRACTION:
        raise DatasetError("%s: %.1f %% of the frames are gaps (empty x_m, y_m; at most %g %%): "
                           "the track cannot give v_mean or f_col"
                           % (fname, 100 * frac, 100 * TRACK_MAX_GAP_FRACTION))
    if len(t) >= 3:
        dt = np.diff(t)
        step = float(np.median(dt))
        off = np.abs(dt / step - 1.0)
        if off.max() > TRACK_SPACING_TOL:
            i = int(np.argmax(off))
            raise DatasetError("%s: frames not uniformly spaced (%g s after row %d, the median "
                               "spacing is %g s): a missing frame is a row with its t_s and "
                               "empty x_m, y_m (a gap), not a skipped row"
                               % (_where(fname, i + 2, "t_s"), dt[i], i + 1, step))
    check_track_units(t, out["x_m"], out["y_m"],
                      out["jar_x_m"] if "jar_x_m" in out.columns else None, fname)
    return out


#: the optional keys of videos/video.json that state the observation chain (how the dataset's
#: speeds and collision counts were measured from its films); docs/dataset_format.md
VIDEO_CHAIN_KEYS = ("exposure_s", "smoothing_window_frames", "smoothing_polyorder",
                    "scale_method")
#: the scale methods video.json may state: the ball's own (blurred) apparent diameter, or a
#: calibration target (a ruler, the jar's known length) in the jar's axial plane
SCALE_METHODS = ("apparent_diameter", "calibration_target")


def _validate_video(meta, fname="videos/video.json"):
    if not isinstance(meta, dict):
        raise DatasetError("%s: must hold a JSON object" % fname)
    if "fps" not in meta:
        raise DatasetError("%s: required key 'fps' is missing" % fname)
    if "ball_diameter_px" not in meta and "m_per_px" not in meta:
        raise DatasetError("%s: needs 'ball_diameter_px' or 'm_per_px'" % fname)
    for key in ("fps", "ball_diameter_px", "m_per_px"):
        if key in meta:
            v = meta[key]
            if (not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v)
                    or v <= 0):
                raise DatasetError("%s: %r must be a positive number, got %r" % (fname, key, v))
    # the observation chain (optional; unknown keys are kept and ignored, as in every file)
    if "exposure_s" in meta:
        v = meta["exposure_s"]
        if (not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v)
                or v < 0):
            raise DatasetError("%s: 'exposure_s' must be a number >= 0 [s], got %r"
                               % (fname, v))
        if v > (1.0 + 1e-9) / meta["fps"]:
            raise DatasetError("%s: 'exposure_s' = %g s is longer than the frame interval "
                               "1 / fps = %g s (an exposure in microseconds written as "
                               "seconds?)" % (fname, v, 1.0 / meta["fps"]))
    for key, lowest in (("smoothing_window_frames", 1), ("smoothing_polyorder", 0)):
        if key in meta:
            v = meta[key]
            if not isinstance(v, int) or isinstance(v, bool) or v < lowest:
                raise DatasetError("%s: %r must be a whole number >= %d, got %r"
                                   % (fname, key, lowest, v))
    if "smoothing_polyorder" in meta:
        if "smoothing_window_frames" not in meta:
            raise DatasetError("%s: 'smoothing_polyorder' needs 'smoothing_window_frames' "
                               "(the window it was fitted over)" % fname)
        if meta["smoothing_polyorder"] >= meta["smoothing_window_frames"]:
            raise DatasetError("%s: 'smoothing_polyorder' (%d) must be less than "
                               "'smoothing_window_frames' (%d)"
                               % (fname, meta["smoothing_polyorder"],
                                  meta["smoothing_window_frames"]))
    if "scale_method" in meta and meta["scale_method"] not in SCALE_METHODS:
        raise DatasetError("%s: 'scale_method' must be one of %s, got %r"
                           % (fname, ", ".join(repr(m) for m in SCALE_METHODS),
                              meta["scale_method"]))


#: the moving-average equivalent of a Savitzky-Golay window of w frames, polyorder 2, as a
#: fraction of w / fps (effects/smoothing_window.py: measured on 40 twin recordings, ~7 %)
SAVGOL_TAU_FRACTION = 0.3


def observation_pins(video) -> dict:
    """What a video.json states about the observation chain, as the observation effects it
    pins: {effect name: {parameter: value}} (docs/dataset_format.md, "The observation chain").

    - ``smoothing_window_frames`` 1 (the speeds are raw frame-to-frame chords): frame_rate at
      the frame interval 1 / fps and ``exposure_s`` (0 unstated), smoothing_window at 0;
    - ``smoothing_window_frames`` w > 1 with ``smoothing_polyorder``: smoothing_window's
      window_s = w / fps for polyorder 0 or 1 (a Savitzky-Golay filter of order 0 or 1 is the
      moving average), ~ :data:`SAVGOL_TAU_FRACTION` w / fps for 2 or 3 (the same filter;
      measured for 2, ~7 %), and frame_rate at 0: smoothing the chords widens the same
      corner (two boxes of widths tau >= dt lose tau / 2 + dt^2 / (6 tau): the chord's share
      is within the window's uncertainty); a higher polyorder, or none stated, pins neither;
    - no smoothing key: neither (they have one form, v (1 - f_col x / 2): diagnose one);
    - ``scale_method`` ``calibration_target``: apparent_scale at 0 (no apparent diameter);
      ``apparent_diameter`` pins nothing (the blur stays free).

    None or {} gives {}. The loop applies these to every prediction and does not diagnose
    them (:func:`analysis.loop.pinned_observation`).
    """
    if not video:
        return {}
    fps = float(video["fps"])
    out = {}
    w = video.get("smoothing_window_frames")
    if w == 1:
        out["frame_rate"] = {"frame_interval_s": 1.0 / fps,
                             "exposure_s": float(video.get("exposure_s", 0.0))}
        out["smoothing_window"] = {"window_s": 0.0}
    elif w is not None and video.get("smoothing_polyorder") in (0, 1, 2, 3):
        frac = 1.0 if video["smoothing_polyorder"] < 2 else SAVGOL_TAU_FRACTION
        out["frame_rate"] = {"frame_interval_s": 0.0, "exposure_s": 0.0}
        out["smoothing_window"] = {"window_s": frac * w / fps}
    if video.get("scale_method") == "calibration_target":
        out["apparent_scale"] = {"blur_fraction": 0.0}
    return out


# --------------------------------------------------------------------------- plausibility
# Physical bounds on every input value, declared once (units in the names) and read by every
# check: a value outside them is almost always a unit slip, refused with the likely slip named.

def _twin_bound(key, which):
    """Lower (1) or upper (2) bound of a run-config key (yade_scripts/twin_config.py)."""
    from analysis.config import twin_config
    return float(twin_config.PARAMETERS[key][which])


#: the frequency range the twin is tested in [Hz]: a condition outside it is accepted with a
#: warning (:func:`input_warnings`, printed by ``python -m analysis.measurements``)
FREQUENCY_TESTED_MIN_HZ = 3.0
FREQUENCY_TESTED_MAX_HZ = 35.0
#: above this a frequency is refused: the twin's run-config bound (60 Hz)
FREQUENCY_MAX_HZ = _twin_bound("frequency_hz", 2)
#: a milling ball's diameter [mm]: the twin's run-config bounds on ball_diameter_m (1-50 mm)
BALL_DIAMETER_MIN_MM = 1e3 * _twin_bound("ball_diameter_m", 1)
BALL_DIAMETER_MAX_MM = 1e3 * _twin_bound("ball_diameter_m", 2)
#: a mixer mill's half stroke [mm]: below 1 mm the jar barely moves (a value in metres?); the
#: upper bound is the twin's run-config bound on amplitude_m (50 mm)
AMPLITUDE_MIN_MM = 1.0
AMPLITUDE_MAX_MM = 1e3 * _twin_bound("amplitude_m", 2)
#: a ball in a mixer mill moves at about a metre per second [m/s]
V_MEAN_MIN_M_S = 0.01
V_MEAN_MAX_M_S = 20.0
#: end-wall collisions per second [1/s]
F_COL_MAX_HZ = 1000.0
#: ball positions of a track span less than this [m] (a jar a few cm long plus twice its stroke)
TRACK_EXTENT_MAX_M = 0.5
#: a track's mean frame-to-frame speed [m/s] (the bound on v_mean)
TRACK_SPEED_MAX_M_S = V_MEAN_MAX_M_S
#: the half peak-to-peak of a track's jar_x_m [m]: the stated stroke's bounds
JAR_AMPLITUDE_MIN_M = AMPLITUDE_MIN_MM / 1e3
JAR_AMPLITUDE_MAX_M = AMPLITUDE_MAX_MM / 1e3
#: a track's frame rate, 1 / median spacing of t_s [1/s] (a high-speed camera: 100-1e6)
TRACK_FPS_MIN = 100.0
TRACK_FPS_MAX = 1e6
#: frames of a track must be this uniformly spaced (|dt fps - 1|), as the observation operator
#: requires; a missing frame is a row with empty positions (a gap), not a skipped row
TRACK_SPACING_TOL = 0.05
#: at most this fraction of a track's frames may be gaps (the observation operator's limit)
TRACK_MAX_GAP_FRACTION = 0.2
#: fewest frames with a position a track must hold (the observation operator's minimum)
TRACK_MIN_FRAMES = 8

#: column -> (lowest plausible, highest plausible, hint below, hint above); ``None``: no bound.
#: Hints are formatted with v (the value), x1000 (v * 1000) and d1000 (v / 1000).
PLAUSIBLE = {
    "frequency_hz": (None, FREQUENCY_MAX_HZ, None,
                     "a mixer mill runs at 3-35 Hz; rpm or cycles per minute?"),
    "ball_diameter_mm": (BALL_DIAMETER_MIN_MM, BALL_DIAMETER_MAX_MM,
                         "metres in the mm column ({v:g} m = {x1000:g} mm)?",
                         "a milling ball is a few mm to a few cm; um?"),
    "amplitude_mm": (AMPLITUDE_MIN_MM, AMPLITUDE_MAX_MM,
                     "metres in the mm column ({v:g} m = {x1000:g} mm)?",
                     "a half stroke of a few mm to a few cm; um?"),
    "v_mean_m_s": (V_MEAN_MIN_M_S, V_MEAN_MAX_M_S,
                   "the ball moves with the jar at about 1 m/s; km/s, or a missing value "
                   "written as 0?", "a ball in a mixer mill moves at a few m/s; mm/s or cm/s?"),
    "v_mean_sd_m_s": (None, V_MEAN_MAX_M_S, None, "mm/s or cm/s?"),
    "f_col_hz": (None, F_COL_MAX_HZ, None, "collisions per second; per minute?"),
    "f_col_sd_hz": (None, F_COL_MAX_HZ, None, "collisions per second; per minute?"),
}


def _hint(text, v):
    return text.format(v=v, x1000=v * 1e3, d1000=v / 1e3)


def _check_plausible(df, fname):
    """One DatasetError naming file, row and column for a value implausible for its unit."""
    for col, (lo, hi, hint_lo, hint_hi) in PLAUSIBLE.items():
        if col not in df.columns:
            continue
        v = pd.to_numeric(df[col], errors="coerce").to_numpy(float)
        for bound, bad, word, hint in ((lo, lambda a, b: a < b, "less", hint_lo),
                                       (hi, lambda a, b: a > b, "more", hint_hi)):
            if bound is None:
                continue
            idx = np.flatnonzero(np.isfinite(v) & bad(v, bound))
            if len(idx):
                i = int(idx[0])
                raise DatasetError("%s: %g is implausible for %s (%s than %g): %s"
                                   % (_where(fname, i + 1, col), v[i], col, word, bound,
                                      _hint(hint, v[i])))


def input_warnings(dataset) -> list:
    """Lines on inputs accepted but outside what the twin is tested on (frequencies outside
    FREQUENCY_TESTED_MIN_HZ - FREQUENCY_TESTED_MAX_HZ); each names file, row and column."""
    out = []
    cond = dataset.conditions
    where = "conditions.csv" if dataset.path is None else str(Path(dataset.path)
                                                              / "conditions.csv")
    for i, (cid, f) in enumerate(zip(cond["condition_id"], cond["frequency_hz"]), start=1):
        if not FREQUENCY_TESTED_MIN_HZ <= float(f) <= FREQUENCY_TESTED_MAX_HZ:
            out.append("%s: condition %r at %g Hz is outside the twin's tested range %g-%g Hz; "
                       "its comparison is an extrapolation"
                       % (_where(where, i, "frequency_hz"), cid, float(f),
                          FREQUENCY_TESTED_MIN_HZ, FREQUENCY_TESTED_MAX_HZ))
    return out


def check_track_units(t_s, x_m, y_m, jar_x_m=None, fname="track"):
    """Refuse a track whose numbers are implausible in seconds and metres (a unit slip).

    Checks the frame rate (1 / median spacing of ``t_s``: TRACK_FPS_MIN - TRACK_FPS_MAX), the
    span of the ball's positions (TRACK_EXTENT_MAX_M), its mean frame-to-frame speed
    (TRACK_SPEED_MAX_M_S) and the jar's half peak-to-peak (JAR_AMPLITUDE_MIN_M -
    JAR_AMPLITUDE_MAX_M). NaN positions are gaps and left out. Raises :class:`DatasetError`
    naming ``fname``, the column and the likely slip.
    """
    t = np.asarray(t_s, float)
    x = np.asarray(x_m, float)
    y = np.asarray(y_m, float)
    if len(t) >= 2:
        dt = float(np.median(np.diff(t)))
        fps = 1.0 / dt if dt > 0 else float("inf")
        if fps < TRACK_FPS_MIN:
            raise DatasetError("%s: frame rate %g frames/s (1 / median spacing of t_s) is below "
                               "%g: t_s in ms? (a high-speed camera takes thousands per second)"
                               % (_where(fname, None, "t_s"), fps, TRACK_FPS_MIN))
        if fps > TRACK_FPS_MAX:
            raise DatasetError("%s: frame rate %g frames/s (1 / median spacing of t_s) is above "
                               "%g: t_s in us or frame numbers divided wrongly?"
                               % (_where(fname, None, "t_s"), fps, TRACK_FPS_MAX))
    for col, a in (("x_m", x), ("y_m", y)):
        fin = a[np.isfinite(a)]
        if len(fin) and np.ptp(fin) > TRACK_EXTENT_MAX_M:
            raise DatasetError("%s: the ball's positions span %g m (more than %g m; a jar is a "
                               "few cm long): in mm? (%g mm)"
                               % (_where(fname, None, col), np.ptp(fin), TRACK_EXTENT_MAX_M,
                                  np.ptp(fin)))
    ok = np.isfinite(x) & np.isfinite(y)
    both = ok[1:] & ok[:-1]
    if both.any():
        sp = np.hypot(np.diff(x), np.diff(y))[both] / np.diff(t)[both]
        v = float(np.mean(sp))
        if v > TRACK_SPEED_MAX_M_S:
            raise DatasetError("%s: the ball's mean speed along the track is %g m/s (more than "
                               "%g m/s): positions in mm or cm, or t_s in ms?"
                               % (_where(fname, None, "x_m"), v, TRACK_SPEED_MAX_M_S))
    if jar_x_m is not None:
        jx = np.asarray(jar_x_m, float)
        fin = jx[np.isfinite(jx)]
        if len(fin):
            amp = 0.5 * float(np.ptp(fin))
            if amp > JAR_AMPLITUDE_MAX_M:
                raise DatasetError("%s: the jar moves +-%g m (more than %g m, a half stroke of "
                                   "a few mm to a few cm): jar_x in mm? (%g mm)"
                                   % (_where(fname, None, "jar_x_m"), amp, JAR_AMPLITUDE_MAX_M,
                                      amp))
            if amp < JAR_AMPLITUDE_MIN_M:
                raise DatasetError("%s: the jar moves +-%g m (less than %g m): jar_x in km, or "
                                   "the marker lost?" % (_where(fname, None, "jar_x_m"), amp,
                                                         JAR_AMPLITUDE_MIN_M))


def validate_conditions_table(df, fname="conditions.csv") -> pd.DataFrame:
    """Validate a conditions table (the contract of conditions.csv); return a normalised copy.

    Parameters
    ----------
    df : DataFrame - cells as strings (as read by :func:`read_table`) or numbers
    fname : str - the file name used in messages

    Returns
    -------
    DataFrame, shape (n_conditions, >= 3) - condition_id (str), frequency_hz and
    ball_diameter_mm (float) [, amplitude_mm, fill_g (float), n_balls (int)]; other columns as
    strings. Raises :class:`DatasetError`.
    """
    cond = _validate_table(_as_str(df), fname, _CONDITIONS_REQUIRED, _CONDITIONS_OPTIONAL,
                           unique_ids=True)
    _check_plausible(cond, fname)
    return cond


def validate_yields_table(df, condition_ids, fname="yields.csv", strict=False) -> pd.DataFrame:
    """Validate a yields table (the contract of yields.csv) against the known condition ids;
    return a normalised copy.

    Parameters
    ----------
    df : DataFrame - cells as strings (as read by :func:`read_table`) or numbers
    condition_ids : iterable of str - the ids of conditions.csv
    fname : str - the file name used in messages

    Returns
    -------
    DataFrame, shape (n_samples, >= 3) - condition_id (str), time_min, yield_pct [,
    yield_sd_pct] (float, NaN for an empty sd); phase and other columns as strings. Raises
    :class:`DatasetError` on the cell rules; with ``strict`` (the yield-data tools,
    :mod:`analysis.yield_data`) also on times that decrease within a condition (equal times are
    replicates) and on phase labels other than :data:`PHASES`. The dataset contract
    (:func:`load_dataset`) is not strict: rows in any order, the phase kept as read.
    """
    optional = _YIELDS_OPTIONAL if strict else dict(_YIELDS_OPTIONAL, phase="text")
    out = _validate_table(_as_str(df), fname, _YIELDS_REQUIRED, optional,
                          known_ids=set(condition_ids))
    if not strict:
        return out
    for cid, grp in out.groupby("condition_id", sort=False):
        tt = grp["time_min"].to_numpy()
        dec = np.flatnonzero(np.diff(tt) < 0)
        if dec.size:
            row = int(grp.index[dec[0] + 1]) + 1
            raise DatasetError("%s: times out of order for condition %r (%g then %g)"
                               % (_where(fname, row, "time_min"), cid, tt[dec[0]],
                                  tt[dec[0] + 1]))
    return out


def validate(dataset: Dataset) -> Dataset:
    """Validate an in-memory :class:`Dataset` against the contract; return a normalised copy.

    Used by :func:`write_dataset` (generators build a Dataset from frames) and by
    :func:`load_dataset`. Raises :class:`DatasetError`.
    """
    meta = dict(dataset.meta)
    meta.update(name=dataset.name, description=dataset.description, source=dataset.source,
                velocity_frame=dataset.velocity_frame)
    _validate_meta(meta)
    cond = validate_conditions_table(dataset.conditions)
    ids = set(cond["condition_id"])
    summ = _validate_table(_as_str(dataset.summary), "summary.csv", _SUMMARY_REQUIRED,
                           empty_ok=_SUMMARY_SD, known_ids=ids, unique_ids=True)
    _check_plausible(summ, "summary.csv")
    tracks = {}
    for cid, tr in dataset.tracks.items():
        fname = "tracks/%s.csv" % cid
        if cid not in ids:
            raise DatasetError("%s: unknown condition_id %r (not in conditions.csv)" % (fname, cid))
        tracks[cid] = _validate_track(_as_str(tr), fname)
    if dataset.video is not None:
        _validate_video(dataset.video)
    for cid in dataset.video_files:
        if cid not in ids:
            raise DatasetError("videos/%s: unknown condition_id %r (not in conditions.csv)"
                               % (Path(dataset.video_files[cid]).name, cid))
    if dataset.video_files and dataset.video is None:
        raise DatasetError("videos/video.json: file is missing (videos need fps and a scale)")
    yields = None
    if dataset.yields is not None:
        yields = validate_yields_table(dataset.yields, ids)
    # the file's name alone: load_dataset prefixes the folder to every message
    _check_each_condition_measured(cond, summ, tracks, dataset.video_files, yields,
                                   "conditions.csv")
    return Dataset(name=meta["name"], description=meta["description"], source=meta["source"],
                   velocity_frame=meta["velocity_frame"], conditions=cond, summary=summ,
                   tracks=tracks, video=dataset.video, video_files=dict(dataset.video_files),
                   yields=yields, meta=meta, path=dataset.path)


def _check_each_condition_measured(cond, summ, tracks, video_files, yields, fname):
    """Every condition is measured somewhere (a summary row, a track, a film or a yield): a
    condition with nothing would only cost twin runs."""
    seen = set(summ["condition_id"]) | set(tracks) | set(video_files)
    if yields is not None:
        seen |= set(yields["condition_id"])
    for i, cid in enumerate(cond["condition_id"], start=1):
        if cid not in seen:
            raise DatasetError("%s: condition %r has no measurement (no row in summary.csv, no "
                               "track, film or yield); measure it or drop the row"
                               % (_where(fname, i, "condition_id"), cid))


def _as_str(df):
    """Frame of strings (NaN -> ''), the form read from disk, so both paths validate alike."""
    out = pd.DataFrame(index=range(len(df)))
    for j in range(df.shape[1]):           # by position: a repeated column name stays visible
        vals = []
        for v in df.iloc[:, j].tolist():
            if v is None or (isinstance(v, float) and math.isnan(v)):
                vals.append("")
            elif isinstance(v, float):
                vals.append(repr(v))
            else:
                vals.append(str(v))
        out[j] = vals
    out.columns = list(df.columns)
    return out


# --------------------------------------------------------------------------- load / write

def load_dataset(path) -> Dataset:
    """Read and validate a dataset folder ``data/measurements/<name>/``.

    Parameters
    ----------
    path : str or Path
        the dataset folder

    Returns
    -------
    Dataset

    Raises
    ------
    DatasetError
        the first contract violation found, naming the file, row and column.
    """
    path = Path(path)
    if path.is_file():
        raise DatasetError("%s: is a file; give the dataset's folder" % path)
    if not path.is_dir():
        raise DatasetError("%s: dataset folder not found" % path)
    for sub in ("tracks", "videos"):
        if (path / sub).exists() and not (path / sub).is_dir():
            raise DatasetError("%s: is a file; a dataset's %s/ is a folder" % (path / sub, sub))
    meta = read_json(path / "dataset.json")
    _validate_meta(meta, str(path / "dataset.json"))
    raw = {"conditions": read_table(path / "conditions.csv", str(path / "conditions.csv")),
           "summary": read_table(path / "summary.csv", str(path / "summary.csv"))}
    tracks = {}
    if (path / "tracks").is_dir():
        for f in sorted((path / "tracks").glob("*.csv")):
            tracks[f.stem] = read_table(f, str(f))
    video, video_files = None, {}
    vdir = path / "videos"
    if vdir.is_dir():
        if (vdir / "video.json").exists():
            video = read_json(vdir / "video.json")
        for f in sorted(vdir.iterdir()):
            if f.name != "video.json" and f.is_file():
                if f.stem in video_files:
                    raise DatasetError("%s: two videos for condition %r" % (f, f.stem))
                video_files[f.stem] = f
    yields = None
    if (path / "yields.csv").exists():
        yields = read_table(path / "yields.csv", str(path / "yields.csv"))
    ds = Dataset(name=meta["name"], description=meta["description"], source=meta["source"],
                 velocity_frame=meta["velocity_frame"], conditions=raw["conditions"],
                 summary=raw["summary"], tracks=tracks, video=video, video_files=video_files,
                 yields=yields, meta=meta, path=path)
    try:
        return validate(ds)
    except DatasetError as exc:
        # prefix the folder so the message names the full file path
        raise DatasetError("%s/%s" % (path, exc)) from None


def write_dataset(dataset: Dataset, path, overwrite: bool = False) -> Path:
    """Validate and write ``dataset`` to the folder ``path`` atomically.

    Everything is written to a temporary sibling folder which is renamed to ``path`` when
    complete, so a reader never sees half a dataset.

    Parameters
    ----------
    dataset : Dataset
        frames may hold numbers or strings; NaN in sd columns is written as an empty cell
    path : str or Path
        target folder
    overwrite : bool
        replace an existing folder (else FileExistsError)

    Returns
    -------
    Path : the written folder
    """
    path = Path(path)
    ds = validate(dataset)
    if path.exists() and not overwrite:
        raise FileExistsError("%s exists (pass overwrite=True to replace it)" % path)
    with output_dir(path, area="datasets") as tmp:
        with open(tmp / "dataset.json", "w") as fh:
            json.dump(ds.meta, fh, indent=2)
            fh.write("\n")
        ds.conditions.to_csv(tmp / "conditions.csv", index=False)
        ds.summary.to_csv(tmp / "summary.csv", index=False, na_rep="")
        if ds.tracks:
            (tmp / "tracks").mkdir()
            for cid, tr in ds.tracks.items():
                tr.to_csv(tmp / "tracks" / ("%s.csv" % cid), index=False)
        if ds.video is not None or ds.video_files:
            (tmp / "videos").mkdir()
            with open(tmp / "videos" / "video.json", "w") as fh:
                json.dump(ds.video, fh, indent=2)
            for cid, f in ds.video_files.items():
                shutil.copy2(f, tmp / "videos" / ("%s%s" % (cid, Path(f).suffix)))
        if ds.yields is not None:
            ds.yields.to_csv(tmp / "yields.csv", index=False, na_rep="")
    return path


def summary_wide(dataset: Dataset, source=None) -> pd.DataFrame:
    """One row per condition: conditions.csv joined with summary.csv (calibration, the demo).

    Returns
    -------
    DataFrame, shape (n_conditions, ...) - condition_id, frequency_hz, ball_diameter_mm,
    ball_diameter_m, the optional condition columns, v_mean_m_s, v_mean_sd_m_s (NaN if not
    given), f_col_hz, f_col_sd_hz, and any other summary column (numeric where every filled cell
    is a number, e.g. the paper's ``v_mean_dem_paper_m_s``); ``attrs`` 'velocity_frame' and
    'name'. ``source`` (e.g. the dataset's folder) names it in errors (default its name).

    Raises
    ------
    DatasetError - a condition without a summary row
    """
    cond = dataset.conditions.copy()
    for c in ("frequency_hz", "ball_diameter_mm"):
        cond[c] = pd.to_numeric(cond[c]).astype(float)
    summ = dataset.summary.copy()
    for c in summ.columns:          # unknown columns come as strings; keep numbers numeric
        if c != "condition_id":
            num = pd.to_numeric(summ[c], errors="coerce")
            if num.notna().sum() == summ[c].replace("", np.nan).notna().sum():
                summ[c] = num.astype(float)
    missing = sorted(set(cond["condition_id"]) - set(summ["condition_id"]))
    if missing:
        raise DatasetError("%s: no summary.csv row for condition(s) %s"
                           % (source or dataset.name, ", ".join(missing)))
    summ = summ.drop(columns=[c for c in summ.columns if c in cond.columns
                              and c != "condition_id"])
    df = cond.merge(summ, on="condition_id", how="left")
    df["ball_diameter_m"] = df["ball_diameter_mm"] / 1000.0
    df.attrs["velocity_frame"] = dataset.velocity_frame
    df.attrs["name"] = dataset.name
    return df


def measurement_table(dataset: Dataset, v_rel_sd: float = DEFAULT_V_REL_SD,
                      f_col_sd_hz: float = DEFAULT_F_COL_SD_HZ) -> pd.DataFrame:
    """Long table of the summary observables with their standard uncertainties.

    Parameters
    ----------
    dataset : Dataset
    v_rel_sd : float
        sd used where v_mean_sd_m_s is empty, as a fraction of v_mean_m_s (default 0.015)
    f_col_sd_hz : float
        sd used where f_col_sd_hz is empty [1/s] (default 1.0)

    Returns
    -------
    DataFrame, shape (n_summary * 2, 5)
        condition_id, observable ('v_mean_m_s' | 'f_col_hz'), value, sd, sd_default (bool)
    """
    rows = []
    for _, r in dataset.summary.iterrows():
        for obs, sdcol in SUMMARY_OBSERVABLES.items():
            sd = r[sdcol]
            default = not np.isfinite(sd)
            if default:
                sd = v_rel_sd * r[obs] if obs == "v_mean_m_s" else f_col_sd_hz
            rows.append((r["condition_id"], obs, float(r[obs]), float(sd), bool(default)))
    return pd.DataFrame(rows, columns=["condition_id", "observable", "value", "sd", "sd_default"])


def yield_table(dataset: Dataset, yield_sd_pct: float = DEFAULT_YIELD_SD_PCT) -> pd.DataFrame:
    """The yields of a dataset with their standard uncertainties.

    Parameters
    ----------
    dataset : Dataset
    yield_sd_pct : float
        sd used where yields.csv has no yield_sd_pct column or an empty cell in it [percentage
        points] (default 2.0)

    Returns
    -------
    DataFrame, shape (n_yields, 5)
        condition_id, time_min, value (yield_pct), sd, sd_default (bool), in file order; no rows
        when the dataset has no yields.csv
    """
    cols = ["condition_id", "time_min", "value", "sd", "sd_default"]
    y = dataset.yields
    if y is None:
        return pd.DataFrame(columns=cols)
    sd = (y["yield_sd_pct"].to_numpy(float) if "yield_sd_pct" in y.columns
          else np.full(len(y), np.nan))
    default = ~np.isfinite(sd)
    return pd.DataFrame({"condition_id": y["condition_id"].to_numpy(),
                         "time_min": y["time_min"].to_numpy(float),
                         "value": y["yield_pct"].to_numpy(float),
                         "sd": np.where(default, yield_sd_pct, sd), "sd_default": default},
                        columns=cols)


def yield_times_of(dataset: Dataset) -> dict:
    """condition_id -> yield times [min] of a Dataset, in file order (empty without yields)."""
    if dataset.yields is None:
        return {}
    return {cid: list(g["time_min"].astype(float))
            for cid, g in dataset.yields.groupby("condition_id", sort=False)}


def conditions_file(ds) -> str:
    """The dataset's conditions.csv as its errors name it (with the folder when it has one)."""
    return "conditions.csv" if ds.path is None else str(Path(ds.path) / "conditions.csv")


def main(argv=None):
    """``python -m analysis.measurements DIR``: validate a dataset and print what it holds."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                 epilog="example: python -m analysis.measurements "
                                 "data/measurements/paper_table3")
    ap.add_argument("dataset", help="dataset folder data/measurements/<name>/")
    args = ap.parse_args(argv)
    from analysis.conditions import ConditionError, physics_table
    from analysis.tracking.errors import VideoReadError
    try:
        ds = load_dataset(args.dataset)
        physics_table(ds.conditions, conditions_file(ds))   # one ball, distinct physics
        from analysis.videos import check_films
        check_films(ds)                                     # each film opens and decodes
    except (DatasetError, ConditionError, VideoReadError) as exc:
        print("analysis.measurements: error: %s" % exc, file=sys.stderr)
        return 2
    for line in input_warnings(ds):
        print("analysis.measurements: warning: %s" % line, file=sys.stderr)
    print("%s: %d conditions, %d summary rows, %d tracks, %d videos, yields: %s, frame: %s"
          % (ds.name, len(ds.conditions), len(ds.summary), len(ds.tracks), len(ds.video_files),
             "no" if ds.yields is None else "%d rows" % len(ds.yields), ds.velocity_frame))
    for col, ids in ds.missing_sd.items():
        print("  %s empty for %d condition(s): default uncertainty used" % (col, len(ids)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
