"""Bayesian calibration of the twin's contact and apparatus parameters from Table-3-like data.

Estimates restitution (C_R), static_friction (SF), rolling_friction (RF) and amplitude_m (the
jar's half stroke A, 0.010-0.016 m) from the mean ball speed v_mean and the end-cap collision
frequency f_col measured at several operating conditions (the paper's 8 conditions of Table 3:
22.5-30 Hz x 17.5 / 20.6 mm; ``data/measurements/paper_table3/``).

Method
------
1. Observation function (:func:`observe`): the measurement's own operator
   (``analysis.observe.observe_recording``: camera rate, camera plane, Savitzky-Golay,
   collisions from x-velocity sign changes) applied to each twin recording, in the frame
   ``dataset.json`` names - one operator for both sides; the scene's meta.json summary
   (``v_mean_m_s`` / ``v_mean_jar_m_s``, ``f_col_hz``) when a run has no trajectory.
2. Design: a Latin hypercube (scipy.stats.qmc, ``n_initial`` ~ 30 parameter sets) over the
   prior box, each set run at every condition (one seed per set: different start positions,
   common across conditions).
3. Emulator: a GP (``analysis.emulator.GPEmulator``) of (parameters, f, d) -> (v_mean, f_col).
   Why an emulator and not MCMC on the twin: a twin run costs minutes of CPU and MCMC needs
   ~1e5 likelihood evaluations; the twin is chaotic, so its output for one parameter set is a
   random variable - the GP's WhiteKernel nugget learns that replicate scatter from the design
   and carries it into the likelihood (Kennedy & O'Hagan 2001). GrainLearning (Cheng et al.
   2019, the YADE community's iterative Bayesian filter with sequential Monte Carlo and
   Gaussian-mixture resampling) is the alternative; it re-runs the twin at each iteration
   instead of emulating it.
4. Posterior: uniform prior on the box; Gaussian likelihood with variance = emulator
   predictive variance of a new run (latent + replicate nugget) + measurement variance
   (the dataset's sd columns, else ``v_rel_sd`` x v and ``f_col_sd_hz``); sampled with emcee's
   affine-invariant ensemble (Foreman-Mackey et al. 2013).
5. Sequential design: ``n_rounds`` times, ``n_refine`` new parameter sets are drawn from the
   posterior samples (greedy maximin in the unit cube, so they spread over the posterior
   instead of piling on the mode), run, and the emulator and posterior are refitted.
6. Validation: the twin is run at the posterior mean with ``n_validation`` seeds at every
   condition; the Table-3-style comparison (measured, paper DEM, ours +- sd, % errors) uses
   these real runs, not the emulator.

Budget: n_initial + n_rounds * n_refine + 1 parameter sets (default 30 + 2 x 10 + 1 = 51,
x 8 conditions, plus 2 extra validation seeds x 8).

References
----------
Kennedy & O'Hagan (2001) JRSS B 63:425. Foreman-Mackey et al. (2013) PASP 125:306.
Cheng, Shuku, Thoeni, Tempone, Vincent & Yamamoto (2019) CMAME 350:268 (GrainLearning).
"""
from __future__ import annotations

import argparse
import json
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.stats import qmc

from analysis import run_configs
from analysis.atomic_dir import check_out_dir, output_dir
from analysis.config import CALIBRATION_DIR, PAPER_TABLE3_DIR
from analysis.emulator import GPEmulator
from analysis.measurements import DatasetError as MeasurementError
from analysis.measurements import load_dataset
# calibrated parameters and their prior bounds (CALIBRATED), the apparatus parameters a
# calibration may free (APPARATUS), every parameter ``--free NAME[=LO:HI]`` accepts (PRIORS):
# declared in analysis.parameter_space
from analysis.parameter_space import APPARATUS, CALIBRATED, PRIORS, parse_free

OUTPUTS = ("v_mean_m_s", "f_col_hz")
CONDITION_INPUTS = ("frequency_hz", "ball_diameter_m")


def load_measurements(dataset_dir=PAPER_TABLE3_DIR):
    """Read a measurement dataset (validated by ``analysis.measurements.load_dataset``) into
    one table of conditions and summary observables.

    Returns
    -------
    DataFrame, shape (n_conditions, ...) - condition_id, frequency_hz, ball_diameter_m,
    v_mean_m_s, v_mean_sd_m_s (NaN if not given), f_col_hz, f_col_sd_hz, and any other
    summary columns; ``df.attrs["velocity_frame"]`` is 'lab' or 'jar'.

    Raises
    ------
    MeasurementError (analysis.measurements.DatasetError) naming the file, row and column of
    a missing or bad value, or a condition without a summary row.
    """
    from analysis.measurements import summary_wide
    return summary_wide(load_dataset(dataset_dir), source=dataset_dir)


def observe(table, velocity_frame="lab", operator="auto"):
    """Observation function: twin runs -> the quantities the measurement holds.

    Parameters
    ----------
    table : DataFrame - rows of a sweep table (run_dir and/or the run summary columns
        v_mean_m_s, v_mean_jar_m_s, f_col_hz)
    velocity_frame : {'lab', 'jar'} - frame of the measured speed
    operator : {'auto', 'camera', 'summary'}
        'camera': the measurement's own operator, ``analysis.observe.observe_recording``
        (trajectory sampled at the camera rate, projected on the camera plane, Savitzky-Golay,
        collisions from x-velocity sign changes) applied to the run folder - one operator for
        both sides; 'summary': the scene's own figures in meta.json; 'auto': 'camera' where a
        run folder with trajectory.csv exists, else 'summary'.

    Returns
    -------
    DataFrame, shape (n, 2) - v_mean_m_s, f_col_hz (NaN for failed runs)
    """
    if operator not in ("auto", "camera", "summary"):
        raise ValueError("operator must be 'auto', 'camera' or 'summary', got %r" % operator)
    vcol = "v_mean_m_s" if velocity_frame == "lab" else "v_mean_jar_m_s"
    out = pd.DataFrame(index=table.index)
    out["v_mean_m_s"] = pd.to_numeric(table.get(vcol), errors="coerce")
    out["f_col_hz"] = pd.to_numeric(table.get("f_col_hz"), errors="coerce")
    if operator == "summary" or "run_dir" not in table:
        if operator == "camera":
            raise ValueError("operator='camera' needs a run_dir column (a sweep table)")
        return out
    from analysis.observe import observe_recording
    for i, rd in table["run_dir"].items():
        if not isinstance(rd, str) or not (Path(rd) / "trajectory.csv").exists():
            if operator == "camera" and isinstance(rd, str):
                raise ValueError("run %s has no trajectory.csv for the camera operator" % rd)
            continue
        ob = observe_recording(rd, frame=velocity_frame)
        out.loc[i, "v_mean_m_s"] = ob.v_mean_m_s
        out.loc[i, "f_col_hz"] = ob.f_col_hz
    return out


def condition_runs(params, conditions, seed=0, base=None):
    """(condition_id, seed, config) of one parameter set at every condition
    (:func:`analysis.run_configs.condition_runs`): the ball diameter is taken from the table's
    ``ball_diameter_m`` as it stands (:func:`load_measurements` holds ``ball_diameter_mm /
    1000.0``), and a stated stroke is not applied (``amplitude_m`` is a calibrated parameter
    here, from ``params`` or ``base``)."""
    return run_configs.condition_runs(conditions, (seed,), params, base, stated_stroke=False,
                                      diameter_column="ball_diameter_m")


def condition_configs(params, conditions, seed=0, base=None):
    """Run configs of one parameter set at every condition (:func:`condition_runs`).

    Parameters
    ----------
    params : dict - calibrated parameter values
    conditions : DataFrame with frequency_hz, ball_diameter_m
    seed : int - start-position seed (common to all conditions: common random numbers)
    base : dict, optional - further config keys (record_s, dt_s, ...)
    """
    return [r.config for r in condition_runs(params, conditions, seed, base)]


# ----------------------------------------------------------------------------------- results

@dataclass
class CalibrationResult:
    """Posterior of the calibrated parameters and the evidence behind it.

    Attributes
    ----------
    params : Series - posterior mean per parameter
    stderr : Series - posterior sd
    interval : DataFrame - q2.5, q50, q97.5 per parameter
    map_params : Series - highest-posterior sample
    samples : ndarray, shape (n_samples, n_params) - thinned posterior samples
    comparison : DataFrame - Table-3-style: measured, paper DEM, twin at the posterior mean
        (mean, sd over validation seeds), emulator prediction, % errors
    residuals : DataFrame - measured minus twin (validation runs) per condition
    design : DataFrame - every twin run used (set_id, round, params, condition, outputs)
    loo : DataFrame - emulator leave-one-out report
    n_parameter_sets, n_runs : int - twin budget used (incl. validation)
    history : list of dict - posterior mean / sd after each round
    """
    params: pd.Series
    stderr: pd.Series
    interval: pd.DataFrame
    map_params: pd.Series
    samples: np.ndarray
    comparison: pd.DataFrame
    residuals: pd.DataFrame
    design: pd.DataFrame
    loo: pd.DataFrame
    n_parameter_sets: int
    n_runs: int
    n_failed: int = 0
    history: list = field(default_factory=list)
    acceptance: float = float("nan")
    emulator: object = None
    bounds: dict = field(default_factory=dict)
    base_config: dict = field(default_factory=dict)

    def to_frame(self):
        """Per parameter: mean, sd, q2.5, q50, q97.5, map, prior lower, prior upper."""
        df = pd.DataFrame({"mean": self.params, "sd": self.stderr})
        df = df.join(self.interval)
        df["map"] = self.map_params
        df["prior_lower"] = [self.bounds[k][0] for k in df.index]
        df["prior_upper"] = [self.bounds[k][1] for k in df.index]
        df.index.name = "parameter"
        return df

    def covers(self, truth):
        """Per parameter: does the 95 % interval hold ``truth[name]``?"""
        return pd.Series({k: bool(self.interval.loc[k, "q2.5"] <= truth[k]
                                  <= self.interval.loc[k, "q97.5"]) for k in self.params.index})


# ------------------------------------------------------------------------------- posterior

class _Posterior:
    """Vectorised log posterior on the emulator (uniform prior on the box)."""

    def __init__(self, emulator, meas, names, bounds, v_rel_sd, f_col_sd_hz):
        self.em, self.names = emulator, names
        self.lo = np.array([bounds[k][0] for k in names])
        self.hi = np.array([bounds[k][1] for k in names])
        self.cond = meas[list(CONDITION_INPUTS)].to_numpy(float)
        self.y = meas[list(OUTPUTS)].to_numpy(float)
        sd_v = meas["v_mean_sd_m_s"].to_numpy(float)
        sd_v = np.where(np.isfinite(sd_v), sd_v, v_rel_sd * self.y[:, 0])
        sd_f = meas["f_col_sd_hz"].to_numpy(float)
        sd_f = np.where(np.isfinite(sd_f), sd_f, f_col_sd_hz)
        self.meas_var = np.column_stack([sd_v, sd_f]) ** 2
        self.order = [*names, *CONDITION_INPUTS]
        em_order = list(emulator.bounds)
        self.perm = [self.order.index(k) for k in em_order]

    def inputs(self, theta):
        theta = np.atleast_2d(theta)
        w, c = len(theta), len(self.cond)
        X = np.hstack([np.repeat(theta, c, axis=0), np.tile(self.cond, (w, 1))])
        return X[:, self.perm]

    def __call__(self, theta):
        theta = np.atleast_2d(theta)
        ok = np.all((theta >= self.lo) & (theta <= self.hi), axis=1)
        lp = np.full(len(theta), -np.inf)
        if not ok.any():
            return lp
        t = theta[ok]
        m, s = self.em.predict(self.inputs(t), return_std=True, include_noise=True)
        c = len(self.cond)
        m = m.reshape(len(t), c, -1)
        var = s.reshape(len(t), c, -1) ** 2 + self.meas_var[None]
        r2 = (self.y[None] - m) ** 2 / var
        lp[ok] = -0.5 * np.sum(r2 + np.log(2 * np.pi * var), axis=(1, 2))
        return lp


def sample_posterior(logpost, bounds, names, n_walkers=32, n_steps=2500, burn=800, thin=5,
                     rng=None):
    """emcee ensemble sampling of ``logpost`` on the prior box.

    Walkers start from an importance resample of 4000 prior draws. Returns (samples, logp,
    acceptance fraction).
    """
    import emcee
    rng = np.random.default_rng(rng)
    lo = np.array([bounds[k][0] for k in names])
    hi = np.array([bounds[k][1] for k in names])
    cand = lo + (hi - lo) * rng.random((4000, len(names)))
    lp = logpost(cand)
    w = np.exp(lp - lp.max())
    idx = rng.choice(len(cand), size=n_walkers, replace=False, p=w / w.sum()) \
        if (w > 0).sum() >= n_walkers else np.argsort(lp)[-n_walkers:]
    p0 = cand[idx] + 1e-3 * (hi - lo) * rng.standard_normal((n_walkers, len(names)))
    p0 = np.clip(p0, lo + 1e-9 * (hi - lo), hi - 1e-9 * (hi - lo))
    sampler = emcee.EnsembleSampler(n_walkers, len(names), logpost, vectorize=True)
    sampler.random_state = np.random.RandomState(int(rng.integers(2**31))).get_state()
    sampler.run_mcmc(p0, n_steps, progress=False)
    samples = sampler.get_chain(discard=burn, thin=thin, flat=True)
    logp = sampler.get_log_prob(discard=burn, thin=thin, flat=True)
    return samples, logp, float(np.mean(sampler.acceptance_fraction))


def _maximin_pick(candidates, existing, k, lo, hi, rng):
    """Greedy maximin choice of k candidate rows (unit-cube distance to chosen + existing)."""
    c = (candidates - lo) / (hi - lo)
    e = (existing - lo) / (hi - lo)
    chosen = [int(rng.integers(len(c)))]
    dmin = np.min(np.linalg.norm(c[:, None] - e[None], axis=2), axis=1) if len(e) else \
        np.full(len(c), np.inf)
    dmin = np.minimum(dmin, np.linalg.norm(c - c[chosen[0]], axis=1))
    while len(chosen) < k:
        j = int(np.argmax(dmin))
        chosen.append(j)
        dmin = np.minimum(dmin, np.linalg.norm(c - c[j], axis=1))
    return candidates[chosen]


# ------------------------------------------------------------------------------- calibrate

def calibrate(simulate, measurements, bounds=None, n_initial=30, n_refine=10, n_rounds=2,
              n_validation=3, v_rel_sd=0.02, f_col_sd_hz=1.0, base_config=None,
              exclude_modes=None, operator="auto", n_walkers=32, n_steps=2500, burn=800,
              random_state=0, progress=None):
    """Calibrate contact + apparatus parameters against measured (v_mean, f_col).

    Parameters
    ----------
    simulate : callable ``simulate(configs) -> DataFrame`` - one row per config with the run
        summary columns (``analysis.sweep.make_simulator()`` for the twin,
        ``analysis.fake_twin.simulate_fake`` for tests)
    measurements : DataFrame from :func:`load_measurements`
    bounds : dict name -> (lo, hi), optional - calibrated parameters (default CALIBRATED)
    n_initial : int - parameter sets of the initial Latin hypercube
    n_refine, n_rounds : int - new sets per refinement round, number of rounds
    n_validation : int - seeds of the validation runs at the posterior mean (0: none)
    v_rel_sd : float - relative measurement sd of v_mean when the dataset has none [-]
    f_col_sd_hz : float - measurement sd of f_col when the dataset has none [Hz]
    base_config : dict, optional - config keys fixed in every run (record_s, dt_s, the jar,
        ...); recorded in the result (``summary.json``: ``base_config``)
    exclude_modes : list of str, optional - motion_mode values left out of the emulator's
        training data (default: none; the counts per mode are always reported)
    operator : {'auto', 'camera', 'summary'} - observation function, see :func:`observe`
    n_walkers, n_steps, burn : emcee settings
    random_state : int
    progress : callable(str), optional - receives one line per stage

    Returns
    -------
    CalibrationResult
    """
    bounds = dict(bounds or CALIBRATED)
    names = list(bounds)
    rng = np.random.default_rng(random_state)
    say = progress or (lambda s: None)
    meas = measurements.reset_index(drop=True)
    frame = meas.attrs.get("velocity_frame", "lab")
    lo = np.array([bounds[k][0] for k in names])
    hi = np.array([bounds[k][1] for k in names])
    em_bounds = dict(bounds)
    for c in CONDITION_INPUTS:
        a, b = float(meas[c].min()), float(meas[c].max())
        pad = 0.05 * (b - a) if b > a else 0.05 * abs(a)
        em_bounds[c] = (a - pad, b + pad)

    design_rows = []

    def run_sets(thetas, round_no, first_id):
        cfgs, keys = [], []
        for i, th in enumerate(thetas):
            sid = first_id + i
            p = dict(zip(names, th))
            for run in condition_runs(p, meas, seed=sid, base=base_config):
                cfgs.append(run.config)
                keys.append({"set_id": sid, "round": round_no,
                             "condition_id": run.condition_id, **p,
                             "frequency_hz": run.config["frequency_hz"],
                             "ball_diameter_m": run.config["ball_diameter_m"], "seed": run.seed})
        tab = simulate(cfgs).reset_index(drop=True)
        obs = observe(tab, frame, operator)
        rows = pd.DataFrame(keys)
        for col in OUTPUTS:
            rows[col] = obs[col].to_numpy()
        for col in ("status", "error", "motion_mode", "run_id"):
            if col in tab:
                rows[col] = tab[col].to_numpy()
        design_rows.append(rows)
        return rows

    def training():
        d = pd.concat(design_rows, ignore_index=True)
        d = d[d["round"] >= 0]
        ok = d[list(OUTPUTS)].notna().all(axis=1)
        if exclude_modes and "motion_mode" in d:
            ok &= ~d["motion_mode"].isin(exclude_modes)
        return d[ok]

    theta0 = qmc.scale(qmc.LatinHypercube(d=len(names), rng=rng).random(n_initial), lo, hi)
    say("round 0: %d parameter sets x %d conditions" % (n_initial, len(meas)))
    run_sets(theta0, 0, 0)
    n_sets = n_initial
    history = []
    for rnd in range(n_rounds + 1):
        train = training()
        em = GPEmulator(em_bounds, outputs=OUTPUTS, random_state=int(rng.integers(2**31)))
        em.fit(train, train)
        post = _Posterior(em, meas, names, bounds, v_rel_sd, f_col_sd_hz)
        samples, logp, acc = sample_posterior(post, bounds, names, n_walkers=n_walkers,
                                              n_steps=n_steps, burn=burn, rng=rng)
        history.append({"round": rnd, "n_sets": n_sets, "n_train": len(train),
                        **{"mean_" + k: float(v) for k, v in zip(names, samples.mean(0))},
                        **{"sd_" + k: float(v) for k, v in zip(names, samples.std(0))},
                        **{"loo_rel_rmse_pct_" + o: float(em.loo_.loc[o, "rel_rmse_pct"])
                           for o in OUTPUTS}})
        say("round %d: posterior mean %s, sd %s (emulator LOO v %.2f %%)"
            % (rnd, np.round(samples.mean(0), 4), np.round(samples.std(0), 4),
               em.loo_.loc["v_mean_m_s", "rel_rmse_pct"]))
        if rnd == n_rounds:
            break
        existing = train.drop_duplicates("set_id")[names].to_numpy(float)
        pool = samples[rng.choice(len(samples), size=min(2000, len(samples)), replace=False)]
        new = _maximin_pick(pool, existing, n_refine, lo, hi, rng)
        say("round %d: %d refinement sets near the posterior" % (rnd + 1, n_refine))
        run_sets(new, rnd + 1, n_sets)
        n_sets += n_refine

    mean = pd.Series(samples.mean(0), index=names)
    sd = pd.Series(samples.std(0, ddof=1), index=names)
    q = np.quantile(samples, [0.025, 0.5, 0.975], axis=0)
    interval = pd.DataFrame(q.T, index=names, columns=["q2.5", "q50", "q97.5"])
    map_params = pd.Series(samples[int(np.argmax(logp))], index=names)

    # emulator prediction at the posterior (propagating parameter uncertainty)
    sub = samples[rng.choice(len(samples), size=min(400, len(samples)), replace=False)]
    m_all = em.predict(post.inputs(sub)).reshape(len(sub), len(meas), -1)
    comp = meas[["condition_id", "frequency_hz", "ball_diameter_m"]].copy()
    comp["ball_diameter_mm"] = comp["ball_diameter_m"] * 1000.0
    comp["v_mean_measured_m_s"] = meas["v_mean_m_s"]
    if "v_mean_dem_paper_m_s" in meas:
        comp["v_mean_dem_paper_m_s"] = meas["v_mean_dem_paper_m_s"]
    comp["v_mean_emulator_m_s"] = m_all[:, :, 0].mean(0)
    comp["v_mean_emulator_sd_m_s"] = m_all[:, :, 0].std(0)
    comp["f_col_measured_hz"] = meas["f_col_hz"]
    comp["f_col_emulator_hz"] = m_all[:, :, 1].mean(0)

    n_val_runs = 0
    if n_validation > 0:
        say("validation: twin at the posterior mean, %d seeds x %d conditions"
            % (n_validation, len(meas)))
        vals = []
        for k in range(n_validation):
            r = run_sets([mean.to_numpy()], -1, 10**6 + k)
            vals.append(r[list(OUTPUTS)].to_numpy(float))
            n_val_runs += len(r)
        vals = np.stack(vals)                       # (n_validation, n_cond, 2)
        comp["v_mean_twin_m_s"] = np.nanmean(vals[:, :, 0], axis=0)
        comp["v_mean_twin_sd_m_s"] = (np.nanstd(vals[:, :, 0], axis=0, ddof=1)
                                      if n_validation > 1 else np.nan)
        comp["f_col_twin_hz"] = np.nanmean(vals[:, :, 1], axis=0)
        comp["f_col_twin_sd_hz"] = (np.nanstd(vals[:, :, 1], axis=0, ddof=1)
                                    if n_validation > 1 else np.nan)
        ours_v, ours_f = comp["v_mean_twin_m_s"], comp["f_col_twin_hz"]
    else:
        ours_v, ours_f = comp["v_mean_emulator_m_s"], comp["f_col_emulator_hz"]
    comp["v_err_pct"] = 100.0 * (ours_v - comp["v_mean_measured_m_s"]) / comp[
        "v_mean_measured_m_s"]
    comp["f_col_err_pct"] = 100.0 * (ours_f - comp["f_col_measured_hz"]) / comp[
        "f_col_measured_hz"]
    if "v_mean_dem_paper_m_s" in comp:
        comp["v_err_paper_pct"] = 100.0 * (comp["v_mean_dem_paper_m_s"]
                                           - comp["v_mean_measured_m_s"]) / comp[
            "v_mean_measured_m_s"]
    residuals = pd.DataFrame({"condition_id": comp["condition_id"],
                              "v_mean_m_s": comp["v_mean_measured_m_s"] - ours_v,
                              "f_col_hz": comp["f_col_measured_hz"] - ours_f})
    design = pd.concat(design_rows, ignore_index=True)
    n_failed = int(design[list(OUTPUTS)].isna().any(axis=1).sum())
    return CalibrationResult(
        params=mean, stderr=sd, interval=interval, map_params=map_params, samples=samples,
        comparison=comp, residuals=residuals, design=design, loo=em.loo_,
        n_parameter_sets=n_sets + (1 if n_validation > 0 else 0), n_runs=len(design),
        n_failed=n_failed, history=history, acceptance=acc, emulator=em, bounds=bounds,
        base_config=dict(base_config or {}))


# ------------------------------------------------------------------------------------- CLI

def write_results(res, out_dir, measurements_name="", protected=()):
    """Write the calibration's tables and figures into ``out_dir`` atomically (temporary folder
    beside it, swapped in when complete); an ``out_dir`` that is not ours to replace, or touches
    a ``protected`` input, is refused (:func:`analysis.atomic_dir.check_out_dir`)."""
    with output_dir(out_dir, protected) as tmp:
        _write_results(res, tmp, measurements_name)
    return Path(out_dir)


def _write_results(res, tmp, measurements_name):
    from analysis.plotting.calibration_plots import write_calibration_figures

    res.to_frame().to_csv(tmp / "parameters.csv", float_format="%.6g")
    res.comparison.to_csv(tmp / "table3_comparison.csv", index=False, float_format="%.5g")
    res.design.to_csv(tmp / "design_runs.csv", index=False, float_format="%.6g")
    res.loo.to_csv(tmp / "emulator_loo.csv", float_format="%.5g")
    pd.DataFrame(res.history).to_csv(tmp / "rounds.csv", index=False, float_format="%.6g")
    pd.DataFrame(res.samples, columns=res.params.index).to_csv(
        tmp / "posterior_samples.csv", index=False, float_format="%.6g")
    summary = {"dataset": measurements_name, "n_parameter_sets": res.n_parameter_sets,
               "n_runs": res.n_runs, "n_failed_runs": res.n_failed,
               "acceptance_fraction": res.acceptance,
               "params": res.params.to_dict(), "stderr": res.stderr.to_dict(),
               "bounds": {k: list(v) for k, v in res.bounds.items()},
               "base_config": res.base_config,
               "motion_modes": (res.design["motion_mode"].astype(str).value_counts().to_dict()
                                if "motion_mode" in res.design else {})}
    (tmp / "summary.json").write_text(json.dumps(summary, indent=1))
    write_calibration_figures(res, tmp)


def main(argv=None):
    p = argparse.ArgumentParser(prog="python -m analysis.calibrate",
                                description="Calibrate restitution, static/rolling friction "
                                            "and the jar amplitude against a measurement "
                                            "dataset (GP emulator + emcee).",
                                epilog="example: python -m analysis.calibrate --dataset "
                                       "data/measurements/paper_table3 --out "
                                       "results/calibration --workers 2")
    p.add_argument("--dataset", default=str(PAPER_TABLE3_DIR),
                   help="measurement dataset folder (default: data/measurements/paper_table3)")
    p.add_argument("--out", default=str(CALIBRATION_DIR),
                   help="output folder (default: results/calibration)")
    p.add_argument("--fake", action="store_true",
                   help="use the FAKE analytic twin (analysis.fake_twin), no YADE")
    p.add_argument("--runner", default=None, help="twin runner 'module:function'")
    p.add_argument("--workers", type=int, default=2,
                   help="parallel twin runs [processes] (default %(default)s)")
    p.add_argument("--backend", default="local", choices=("local", "serial", "dask"))
    p.add_argument("--scheduler", default=None)
    p.add_argument("--runs-dir", default=None)
    p.add_argument("--n-initial", type=int, default=30,
                   help="Latin-hypercube design, each run at every condition "
                        "[parameter sets] (default %(default)s)")
    p.add_argument("--n-refine", type=int, default=10,
                   help="new sets drawn from the posterior per round [parameter sets] "
                        "(default %(default)s)")
    p.add_argument("--rounds", type=int, default=2,
                   help="sequential-design rounds [rounds] (default %(default)s)")
    p.add_argument("--n-validation", type=int, default=3,
                   help="twin runs at the posterior mean per condition [seeds] "
                        "(default %(default)s)")
    p.add_argument("--v-rel-sd", type=float, default=0.02,
                   help="measured v_mean sd where the dataset states none, as a fraction of "
                        "v_mean [-] (default %(default)s)")
    p.add_argument("--f-col-sd-hz", type=float, default=1.0,
                   help="measured f_col sd where the dataset states none [Hz] "
                        "(default %(default)s)")
    p.add_argument("--exclude-mode", action="append", default=None)
    p.add_argument("--operator", default="auto", choices=("auto", "camera", "summary"),
                   help="observation function (default: the camera operator where "
                        "trajectories exist)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="config key fixed in every run, e.g. record_s=0.5 (repeatable; "
                        "VALUE in the SI unit the key's name states, e.g. record_s [s], "
                        "amplitude_m [m])")
    p.add_argument("--base-profile", default=None, metavar="FILE",
                   help="a profile JSON (its 'config': run-config keys, e.g. "
                        "results/apparatus/paper_apparatus.json) fixed in every run, except "
                        "the keys freed by --free; --set overrides it")
    p.add_argument("--free", action="append", default=None, metavar="NAME[=LO:HI]",
                   help="a parameter to calibrate, with optional bounds inside its declared "
                        "range, LO and HI in the parameter's unit [SI unit of NAME, e.g. m "
                        "for amplitude_m; - for restitution] (repeatable; default: %s; "
                        "apparatus: %s)"
                        % (", ".join(CALIBRATED), ", ".join(APPARATUS)))
    p.add_argument("--seed", type=int, default=0,
                   help="random seed of the design and the sampler [-] (default %(default)s)")
    args = p.parse_args(argv)
    # the twin's inputs and caches are never an output
    protected = [args.dataset, args.runs_dir]
    try:
        check_out_dir(args.out, protected)
        bounds = parse_free(args.free)
        meas = load_measurements(args.dataset)
        base = {}
        if args.base_profile:
            try:
                prof = json.loads(Path(args.base_profile).read_text())
                base = {k: v for k, v in dict(prof["config"]).items() if k not in bounds}
            except (KeyError, TypeError) as exc:
                raise ValueError("--base-profile %s has no 'config' object (%s)"
                                 % (args.base_profile, exc))
        for kv in args.set:
            if "=" not in kv:
                raise MeasurementError("--set needs KEY=VALUE, got %r" % kv)
            k, v = kv.split("=", 1)
            base[k] = json.loads(v) if v[:1] in "0123456789-[{" else v
        if args.fake:
            from analysis.fake_twin import simulate_fake as simulate
        else:
            from analysis.sweep import make_simulator
            simulate = make_simulator(runner=args.runner, workers=args.workers,
                                      backend=args.backend, scheduler=args.scheduler,
                                      runs_dir=args.runs_dir)
        clash = sorted(set(base) & set(bounds))
        if clash:
            raise ValueError("--set fixes %s, which --free calibrates" % ", ".join(clash))
        res = calibrate(simulate, meas, bounds=bounds, n_initial=args.n_initial,
                        n_refine=args.n_refine, n_rounds=args.rounds,
                        n_validation=args.n_validation,
                        v_rel_sd=args.v_rel_sd, f_col_sd_hz=args.f_col_sd_hz,
                        base_config=base, exclude_modes=args.exclude_mode,
                        operator=args.operator,
                        random_state=args.seed, progress=lambda s: print(s, flush=True))
        out = write_results(res, args.out, meas.attrs.get("name", ""), protected)
    except (ValueError, OSError) as exc:   # OutputError is a ValueError
        print("analysis.calibrate: error: %s" % exc, file=sys.stderr)
        return 2
    print(res.to_frame().to_string(float_format=lambda x: "%.4g" % x))
    cols = [c for c in ("condition_id", "v_mean_measured_m_s", "v_mean_dem_paper_m_s",
                        "v_mean_twin_m_s", "v_mean_twin_sd_m_s", "v_err_pct",
                        "f_col_measured_hz", "f_col_twin_hz", "f_col_err_pct")
            if c in res.comparison]
    print(res.comparison[cols].to_string(index=False, float_format=lambda x: "%.3g" % x))
    if "motion_mode" in res.design:
        print("motion modes of the twin runs: %s"
              % res.design["motion_mode"].astype(str).value_counts().to_dict())
    print("twin budget: %d parameter sets, %d runs (%d failed); wrote %s%s"
          % (res.n_parameter_sets, res.n_runs, res.n_failed, out,
             "  [FAKE twin]" if args.fake else ""))
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except KeyboardInterrupt as exc:          # SIGINT / SIGTERM: one line, 130 / 143
        from analysis.sweep import interrupted_exit
        sys.exit(interrupted_exit("analysis.calibrate", exc))
