"""Conditions are physics, not names.

A measurement condition is what the mill did: the jar's frequency, the ball's diameter and, where a
dataset states them, the half stroke and the number of balls. Its ``condition_id`` is only a label
chosen by whoever wrote the dataset: two datasets may call the same physics by different ids, or
reuse an id for other physics. Everything that pairs a dataset's condition with twin runs goes
through this module:

* :func:`physics_table` - the physics of each condition, with the defaults filled in;
* :func:`physics_key` - one canonical text per physics (``f26_d19``, ``f26_d19_a13.1``), the key
  under which twin runs for a condition are stored: two conditions are the same physics when
  their keys are equal (0.01 Hz, 0.01 mm: below what any MM400 user sets or measures, above the
  round-off of a CSV), never by id.
"""
from __future__ import annotations

import math

import numpy as np
import pandas as pd

#: the scene holds one ball (the paper's setting); n_balls other than 1 is refused
SUPPORTED_N_BALLS = (1,)


class ConditionError(ValueError):
    """A condition the twin cannot represent (the message names the condition)."""


def physics_table(conditions: pd.DataFrame, source="conditions.csv") -> pd.DataFrame:
    """condition_id, frequency_hz, ball_diameter_mm, amplitude_mm (NaN = not stated), n_balls.

    Parameters
    ----------
    conditions : DataFrame - a dataset's conditions (condition_id, frequency_hz,
        ball_diameter_mm and optionally amplitude_mm, n_balls), in the file's row order
    source : the file the errors name (with the row, its line and the column)

    Raises
    ------
    ConditionError
        a condition with n_balls other than 1, or two conditions with the same physics
    """
    c = conditions
    out = pd.DataFrame({
        "condition_id": c["condition_id"].astype(str).to_numpy(),
        "frequency_hz": pd.to_numeric(c["frequency_hz"]).to_numpy(float),
        "ball_diameter_mm": pd.to_numeric(c["ball_diameter_mm"]).to_numpy(float),
        "amplitude_mm": (pd.to_numeric(c["amplitude_mm"], errors="coerce").to_numpy(float)
                         if "amplitude_mm" in c.columns else np.full(len(c), np.nan)),
        "n_balls": (pd.to_numeric(c["n_balls"], errors="coerce").fillna(1).to_numpy(int)
                    if "n_balls" in c.columns else np.ones(len(c), int)),
    })
    bad = np.flatnonzero(~out["n_balls"].isin(SUPPORTED_N_BALLS).to_numpy())
    if len(bad):
        r = out.iloc[bad[0]]
        raise ConditionError("%s, row %d (line %d), column 'n_balls': condition %r has "
                             "n_balls = %d; the twin's scene holds one ball (n_balls = 1)"
                             % (source, bad[0] + 1, bad[0] + 2, r["condition_id"],
                                r["n_balls"]))
    keys = [physics_key(r.frequency_hz, r.ball_diameter_mm, r.amplitude_mm, r.n_balls)
            for r in out.itertuples()]
    dup = pd.Series(keys, dtype=object).duplicated().to_numpy()
    first = keys[int(np.argmax(dup))] if dup.any() else None
    same = [i for i, k in enumerate(keys) if k == first]
    if len(same) > 1:
        raise ConditionError(
            "%s, rows %s (lines %s), columns frequency_hz, ball_diameter_mm, amplitude_mm, "
            "n_balls: conditions %s describe the same physics (%s); merge them"
            % (source, " and ".join(str(i + 1) for i in same),
               " and ".join(str(i + 2) for i in same),
               [out["condition_id"].iloc[i] for i in same], first))
    out["physics_key"] = keys
    return out


def _fmt(x):
    return ("%.2f" % float(x)).rstrip("0").rstrip(".")


def physics_key(frequency_hz, ball_diameter_mm, amplitude_mm=None, n_balls=1) -> str:
    """Canonical text of a condition's physics: ``f<Hz>_d<mm>[_a<mm>][_n<balls>]``, numbers to
    0.01 (e.g. ``physics_key(26, 19) == 'f26_d19'``, ``physics_key(22.5, 20.6, 13.1)
    == 'f22.5_d20.6_a13.1'``). The stroke appears only when stated."""
    k = "f%s_d%s" % (_fmt(frequency_hz), _fmt(ball_diameter_mm))
    if amplitude_mm is not None and not (isinstance(amplitude_mm, float) and
                                         math.isnan(amplitude_mm)):
        k += "_a%s" % _fmt(amplitude_mm)
    if int(n_balls) != 1:
        k += "_n%d" % int(n_balls)
    return k


def label(frequency_hz, ball_diameter_mm, amplitude_mm=None) -> str:
    """Plain words: '19 mm ball at 26 Hz' (', 13.1 mm stroke' when stated)."""
    s = "%g mm ball at %g Hz" % (float(ball_diameter_mm), float(frequency_hz))
    if amplitude_mm is not None and np.isfinite(amplitude_mm):
        s += ", %g mm stroke" % float(amplitude_mm)
    return s
