"""Run configs of the twin at a dataset's conditions: the one builder of "conditions x base
parameters x seeds (x effects)".

Every place that runs the twin at the conditions of a table (the loop's design, the calibration,
the demo, the hidden datasets, the studies) builds its configs here, so
that the same physics gives the same config and so the same run id (``twin_config.run_id``
hashes the complete config: a float that differs in its last bit is another run).

A config is assembled in this order, each layer overriding the ones before it:

1. ``base_config`` - keys fixed in every run (record_s, dt_s, the jar, the frame, ...);
2. ``theta`` - the base parameters (restitution, static_friction, ...); numbers as ``float``;
3. the condition - ``frequency_hz``, ``ball_diameter_m``, ``seed`` and, with
   ``stated_stroke``, the condition's own half stroke ``amplitude_m`` where it states one;
4. ``effects`` - set when given and not empty (an empty one leaves ``base_config``'s).

The arithmetic is part of the contract (the run cache and the committed tables are keyed by
run id):

* ``frequency_hz = float(frequency_hz)``, ``seed = int(seed)``;
* ``ball_diameter_m = float(ball_diameter_mm) * 1e-3`` from a table in millimetres (the
  default, ``diameter_column="ball_diameter_mm"``), or ``float(ball_diameter_m)`` from a table
  already in metres (``diameter_column="ball_diameter_m"``: :mod:`analysis.calibrate`, whose
  measurement table holds ``ball_diameter_mm / 1000.0``). The two differ in the last bit for
  some diameters (18 mm: 0.018 against 0.018000000000000002), so each caller keeps its own;
* ``amplitude_m = float(amplitude_mm) * 1e-3`` where the condition's ``amplitude_mm`` is
  finite and ``stated_stroke`` is true.
"""
from __future__ import annotations

import numbers
from typing import NamedTuple

import numpy as np
import pandas as pd

#: the condition's ball diameter in millimetres (a dataset's conditions.csv) ...
DIAMETER_MM = "ball_diameter_mm"
#: ... or in metres (a run-config-like table)
DIAMETER_M = "ball_diameter_m"


class ConditionRun(NamedTuple):
    """One run of a grid: the condition's id (None when the table has none), the seed and the
    run config."""
    condition_id: object
    seed: int
    config: dict


def _fields(condition):
    """A condition row as something with ``get`` and ``[]``: a mapping, a pandas Series, or a
    named tuple of ``DataFrame.itertuples``."""
    if hasattr(condition, "_asdict"):
        return condition._asdict()
    return condition


def _as_float(value):
    """Numbers (Python or numpy scalars, 0-d numeric arrays; not bool) as float; anything else
    unchanged (it meets twin_config's own checks)."""
    if isinstance(value, (bool, np.bool_)):
        return value
    if isinstance(value, numbers.Real) or (isinstance(value, np.ndarray) and value.ndim == 0
                                           and value.dtype.kind in "fiu"):
        return float(value)
    return value


def condition_diameter_m(condition, diameter_column=DIAMETER_MM) -> float:
    """The condition's ball diameter [m]: ``float(ball_diameter_mm) * 1e-3`` or, with
    ``diameter_column="ball_diameter_m"``, ``float(ball_diameter_m)``."""
    c = _fields(condition)
    if diameter_column == DIAMETER_MM:
        return float(c[DIAMETER_MM]) * 1e-3
    if diameter_column == DIAMETER_M:
        return float(c[DIAMETER_M])
    raise ValueError("diameter_column must be %r or %r, got %r"
                     % (DIAMETER_MM, DIAMETER_M, diameter_column))


def stated_amplitude_m(condition):
    """The half stroke the condition states [m] (``float(amplitude_mm) * 1e-3``), or None
    when it states none (no ``amplitude_mm``, None or NaN)."""
    a = _fields(condition).get("amplitude_mm", np.nan)
    if a is not None and np.isfinite(a):
        return float(a) * 1e-3
    return None


def condition_config(condition, theta=None, seed=0, base_config=None, effects=None, *,
                     stated_stroke=True, diameter_column=DIAMETER_MM) -> dict:
    """Run config of one condition.

    Parameters
    ----------
    condition : mapping, Series or itertuples row - frequency_hz and the ball diameter
        (``diameter_column``) [, amplitude_mm]
    theta : dict, optional - base parameters (numbers stored as float)
    seed : int - start-position seed
    base_config : dict, optional - keys fixed in every run (under theta and the condition)
    effects : dict {effect: {param: value}}, optional - set when not empty
    stated_stroke : bool - the condition's finite ``amplitude_mm`` sets ``amplitude_m`` (over
        theta's); False: the stroke is theta's or base_config's whatever the condition states
    diameter_column : 'ball_diameter_mm' (default) or 'ball_diameter_m' - see the module text

    Returns
    -------
    dict - a user run config (``twin_config.complete_config`` fills the defaults)
    """
    c = _fields(condition)
    cfg = dict(base_config or {})
    cfg.update({k: _as_float(v) for k, v in (theta or {}).items()})
    cfg.update(frequency_hz=float(c["frequency_hz"]),
               ball_diameter_m=condition_diameter_m(c, diameter_column), seed=int(seed))
    if stated_stroke:
        a = stated_amplitude_m(c)
        if a is not None:
            cfg["amplitude_m"] = a
    if effects:
        cfg["effects"] = effects
    return cfg


def _rows(conditions):
    if isinstance(conditions, pd.DataFrame):
        return conditions.to_dict("records")
    return list(conditions)


def condition_runs(conditions, seeds=(0,), theta=None, base_config=None, effects=None, *,
                   stated_stroke=True, diameter_column=DIAMETER_MM) -> list:
    """:func:`condition_config` at every condition x seed, conditions outer, seeds inner.

    Parameters
    ----------
    conditions : DataFrame or iterable of condition rows (see :func:`condition_config`)
    seeds : iterable of int - the seeds of every condition (e.g. ``range(seed0, seed0 + n)``)
    theta, base_config, effects, stated_stroke, diameter_column : as in
        :func:`condition_config`, the same for every run

    Returns
    -------
    list of :class:`ConditionRun` (condition_id, seed, config)
    """
    if isinstance(seeds, numbers.Integral):
        raise TypeError("seeds must be an iterable of seeds (e.g. range(%d)), got the number %d"
                        % (seeds, seeds))
    seeds = [int(s) for s in seeds]
    out = []
    for row in _rows(conditions):
        c = _fields(row)
        for s in seeds:
            out.append(ConditionRun(c.get("condition_id"), s, condition_config(
                c, theta, s, base_config, effects, stated_stroke=stated_stroke,
                diameter_column=diameter_column)))
    return out


def condition_configs(conditions, seeds=(0,), theta=None, base_config=None, effects=None, *,
                      stated_stroke=True, diameter_column=DIAMETER_MM) -> list:
    """The configs of :func:`condition_runs` (list of dict, conditions outer, seeds inner)."""
    return [r.config for r in condition_runs(conditions, seeds, theta, base_config, effects,
                                             stated_stroke=stated_stroke,
                                             diameter_column=diameter_column)]
