"""A FAKE mill twin: an analytic toy with the twin's interface, for tests and benchmarks.

This is not physics to be trusted. It maps the calibrated parameters (restitution,
static_friction, rolling_friction, amplitude_m) and the operating conditions (frequency_hz,
ball_diameter_m) to a mean ball speed and a collision frequency through a smooth, nonlinear,
made-up formula whose scale is near the paper's Table 3 (2.1 m/s at 25 Hz, 20.6 mm), plus
seeded "replicate noise" (1.5 % on the speed, 0.5 Hz on f_col) standing in for the chaos of
the real DEM twin. It exists so the sweep, emulator, calibration and sensitivity machinery can
be tested quickly without YADE.

Two faces:

* :func:`run_fake_twin` has the signature of ``analysis.twin.run_twin`` and writes a run folder
  ``<runs_dir>/<run-id>/meta.json`` (atomically, temp folder then rename) whose
  ``summary`` carries ``v_mean_m_s``, ``v_mean_jar_m_s``, ``f_col_hz``, ``n_impacts`` and
  ``motion_mode`` ("fake"). Options (``delay_s``, ``cpu_s``, ``exec_log``,
  ``fail_above_restitution``) make it slow, CPU-bound, countable or failing.
* :func:`fake_flights` gives a run's made-up impact observables (those of
  :mod:`analysis.flights`; the FAKE twin writes no trajectory to read them from), so a ``--fake``
  loop runs on datasets with jar tracks too (``analysis.twin_runs.run_flights`` asks it).
* :func:`simulate_fake` maps a list of configs straight to a table (no files), the
  ``simulate(configs) -> table`` callable used by ``analysis.calibrate`` and
  ``analysis.sensitivity``.
"""
from __future__ import annotations

import hashlib
import json
import os
import shutil
import time
import uuid
from pathlib import Path

import numpy as np
import pandas as pd

from analysis.config import RUNS_DIR, twin_config

#: replicate noise of the fake twin: relative sd of v_mean and absolute sd of f_col [Hz]
FAKE_V_REL_SD = 0.015
FAKE_FCOL_SD_HZ = 0.5


def toy_observables(restitution, static_friction, rolling_friction, amplitude_m,
                    frequency_hz, ball_diameter_m):
    """Noise-free toy observables (broadcasting over array inputs).

    Parameters
    ----------
    restitution, static_friction, rolling_friction : array_like - contact parameters [-]
    amplitude_m : array_like - jar half stroke A [m]
    frequency_hz : array_like - jar frequency f [Hz]
    ball_diameter_m : array_like - ball diameter d [m]

    Returns
    -------
    v_mean_m_s, f_col_hz : ndarray - toy mean speed [m/s] and end-cap collision rate [1/s]
    """
    cr = np.asarray(restitution, float)
    sf = np.asarray(static_friction, float)
    rf = np.asarray(rolling_friction, float)
    f = np.asarray(frequency_hz, float)
    d_rel = np.asarray(ball_diameter_m, float) / 0.0206
    fr = f / 25.0
    u = 2.0 * np.pi * f * np.asarray(amplitude_m, float)        # jar peak speed
    h = (1.09 + 0.55 * cr * fr - 0.30 * cr ** 2 - 0.8 * (sf - 0.5) * (d_rel - 0.92)
         - 0.25 * rf / fr + 0.3 * (sf - 0.5) * (rf - 0.3))
    v = u * h * d_rel ** -0.35
    fcol = 2.0 * f * (1.0 - 0.1 * (1.0 - cr) * rf * d_rel - 0.04 * (sf - 0.3) * fr)
    return v, fcol


def toy_effect_factor(effects, frequency_hz, ball_diameter_m, v_m_s):
    """Made-up multiplicative change of the toy speed by DEM catalog effects (tests only).

    Each effect gets a distinct, smooth pattern over frequency and ball size, loosely shaped
    like its physics: jar compliance the base-excitation gain 1 / (1 - (f/f_n)^2), a powder
    layer an energy loss growing as h^2 / d^2, rolling resistance a loss falling with f,
    viscoelastic restitution a loss growing with speed, arc motion a gain growing with f^2,
    air drag ~nothing. Kinetics effects do not act here."""
    fac = 1.0
    fr = frequency_hz / 25.0
    d_rel = ball_diameter_m / 0.0206
    for name, p in (effects or {}).items():
        if name == "viscoelastic_restitution":
            fac *= 1.0 - 0.25 * p.get("k", 0.1) * (v_m_s / 2.0) ** 0.2
        elif name == "arc_motion":
            fac *= 1.0 + 0.004 * p.get("curvature_1_m", 5.0) * fr ** 2
        elif name == "jar_compliance":
            fac *= 1.0 / (1.0 - (frequency_hz / p.get("f_n_hz", 200.0)) ** 2)
        elif name == "powder_layer":
            fac *= 1.0 - 0.08 * (p.get("layer_thickness_m", 1e-4) / 5e-4) ** 2 / d_rel ** 2
        elif name == "rolling_resistance":
            fac *= 1.0 - 0.08 * p.get("extra_rolling_friction", 0.2) / fr
        elif name == "air_drag":
            fac *= 1.0 - 1e-4 * p.get("drag_scale", 1.0)
    return fac


#: the FAKE twin's end fillet: the speed falls with the fillet's radius above the default jar's
#: (5 mm), more at high frequency and for a small ball (loosely docs/apparatus.md's tilted
#: impact normal)
FAKE_FILLET_M, FAKE_FILLET_SLOPE_1_M = 0.005, 12.0


def toy_apparatus_factor(cfg):
    """Made-up multiplicative change of the toy speed by the jar's end fillet (tests only):
    1 - k (r - r0) (f / 25 Hz)^2 (20.6 mm / d)^2, exactly 1 for the default jar."""
    r = float(cfg.get("jar_fillet_radius_m") or FAKE_FILLET_M)
    return 1.0 - (FAKE_FILLET_SLOPE_1_M * (r - FAKE_FILLET_M) * (cfg["frequency_hz"] / 25.0) ** 2
                  * (0.0206 / cfg["ball_diameter_m"]) ** 2)


def _noise_rng(cfg):
    key = json.dumps({k: cfg[k] for k in ("restitution", "static_friction", "rolling_friction",
                                          "amplitude_m", "frequency_hz", "ball_diameter_m",
                                          "seed")}, sort_keys=True)
    return np.random.default_rng(int(hashlib.sha256(key.encode()).hexdigest()[:15], 16))


def fake_summary(config):
    """Summary dict (as in meta.json["summary"]) of one complete or partial config."""
    cfg = twin_config.complete_config(dict(config))
    v, fcol = toy_observables(cfg["restitution"], cfg["static_friction"],
                              cfg["rolling_friction"], cfg["amplitude_m"],
                              cfg["frequency_hz"], cfg["ball_diameter_m"])
    v = float(v) * toy_effect_factor(cfg.get("effects"), cfg["frequency_hz"],
                                     cfg["ball_diameter_m"], float(v)) * toy_apparatus_factor(cfg)
    rng = _noise_rng(cfg)
    v = float(v) * (1.0 + FAKE_V_REL_SD * rng.standard_normal())
    fcol = float(fcol) + FAKE_FCOL_SD_HZ * rng.standard_normal()
    return {"v_mean_m_s": v, "v_mean_jar_m_s": v, "f_col_hz": fcol,
            "n_impacts": int(round(fcol * cfg["record_s"])), "motion_mode": "fake"}


#: replicate noise of the FAKE impact observables [their units]
FAKE_FLIGHT_SD = {"e_app": 0.01, "v_in_m_s": 0.03, "impact_phase_rad": 0.03,
                  "jar_amplitude_m": 2e-5, "vy_rms_m_s": 0.005}


def fake_flights(config) -> dict:
    """FAKE impact observables (``analysis.flights.FLIGHT_OBSERVABLES``) of one config: made-up
    smooth functions of the contact parameters, the stroke and the toy speed (so the effects
    that move the speed move v_in and vy_rms too), with seeded replicate noise drawn after the
    speed's and f_col's (tests only)."""
    cfg = twin_config.complete_config(dict(config))
    summ = fake_summary(cfg)
    v = summ["v_mean_m_s"]
    cr, sf, rf = cfg["restitution"], cfg["static_friction"], cfg["rolling_friction"]
    a_m, f_hz = cfg["amplitude_m"], cfg["frequency_hz"]
    # scaled like the DEM twin's near the paper's conditions (e_app ~0.37, v_in ~3.3 m/s,
    # phase ~2.2 rad, vy_rms ~0.25 m/s at 26 Hz, 19 mm)
    vals = {"e_app": 0.15 + 0.75 * cr - 0.05 * (sf - 0.5),
            "v_in_m_s": 1.2 * v + 0.3 * 2.0 * np.pi * f_hz * a_m,
            "impact_phase_rad": 2.2 + 0.4 * (sf - 0.5) - 0.3 * (rf - 0.3) + 0.5 * (cr - 0.3),
            "jar_amplitude_m": a_m,
            "vy_rms_m_s": 0.1 * v * (1.0 + 0.5 * (rf - 0.3)) + 0.02 * (sf - 0.5)}
    rng = _noise_rng(cfg)
    rng.standard_normal(2)                              # the speed's and f_col's draws
    return {k: float(x + FAKE_FLIGHT_SD[k] * rng.standard_normal()) for k, x in vals.items()}


def _burn_cpu(seconds):
    t_end = time.process_time() + seconds
    x = 0.0
    while time.process_time() < t_end:
        for i in range(2000):
            x += (i % 7) * 1e-9
    return x


def run_fake_twin(config, runs_dir=None, force=False, delay_s=0.0, cpu_s=0.0, exec_log=None,
                  fail_above_restitution=None, crash_above_restitution=None):
    """FAKE stand-in for ``analysis.twin.run_twin``: write a run folder and return its path.

    Parameters
    ----------
    config : dict - run config (completed with twin_config defaults)
    runs_dir : path-like, optional - parent of run folders (default RUNS_DIR)
    force : bool - recompute even when the folder holds meta.json
    delay_s : float - sleep this long [s] (wall-time cost, no CPU)
    cpu_s : float - burn this much CPU time [s] (for throughput benchmarks)
    exec_log : path-like, optional - folder; one empty file ``<run-id>.<uuid>`` is created per
        execution, so tests can count how often each run was really computed
    fail_above_restitution : float, optional - raise RuntimeError (like a failed YADE run) when
        the config's restitution exceeds this
    crash_above_restitution : float, optional - kill the whole process (os._exit, like a
        segfault or the out-of-memory killer) when the restitution exceeds this

    Returns
    -------
    Path - the run folder holding meta.json
    """
    cfg = twin_config.complete_config(dict(config))
    rid = twin_config.run_id(cfg)
    runs_dir = Path(runs_dir) if runs_dir is not None else RUNS_DIR
    out = runs_dir / rid
    if (out / "meta.json").exists() and not force:
        return out
    if exec_log is not None:
        Path(exec_log).mkdir(parents=True, exist_ok=True)
        (Path(exec_log) / ("%s.%s" % (rid, uuid.uuid4().hex))).touch()
    t0 = time.time()
    if delay_s:
        time.sleep(float(delay_s))
    if cpu_s:
        _burn_cpu(float(cpu_s))
    if crash_above_restitution is not None and cfg["restitution"] > float(crash_above_restitution):
        os._exit(139)
    if fail_above_restitution is not None and cfg["restitution"] > float(fail_above_restitution):
        raise RuntimeError("fake twin: YADE failed for run %s (restitution %g > %g, "
                           "simulated failure)" % (rid, cfg["restitution"],
                                                   float(fail_above_restitution)))
    meta = {"config": cfg, "run_id": rid, "yade_version": "FAKE (analysis.fake_twin)",
            "dt_s": cfg["dt_s"], "steps": 0, "wall_s": time.time() - t0, "steps_per_s": None,
            "git_commit": None, "seed": cfg["seed"], "record_start_s": 0.0,
            "steady": {"fake": True}, "summary": fake_summary(cfg)}
    runs_dir.mkdir(parents=True, exist_ok=True)
    tmp = runs_dir / (".tmp-%s-%s" % (rid, uuid.uuid4().hex[:8]))
    tmp.mkdir()
    with open(tmp / "meta.json", "w") as fh:
        json.dump(meta, fh, indent=1)
    if out.exists():
        shutil.rmtree(out)
    os.rename(tmp, out)
    return out


def simulate_fake(configs):
    """FAKE ``simulate(configs) -> table``: one row per config, no files written.

    Returns
    -------
    DataFrame, shape (n_configs, ...) - the configs' own keys plus v_mean_m_s, f_col_hz,
    motion_mode and status ("done").
    """
    rows = []
    for cfg in configs:
        row = dict(cfg)
        row.update(fake_summary(cfg))
        row["status"] = "done"
        rows.append(row)
    return pd.DataFrame(rows)
