"""Bayesian calibration of the twin's contact and apparatus parameters on the loop's one model.

Estimates restitution (C_R), static_friction (SF), rolling_friction (RF) and amplitude_m (the
jar's half stroke A) - or the parameters ``--free`` names, apparatus ones among them - from a
measurement dataset (default the paper's Table 3, ``data/measurements/paper_table3/``).

Method: the loop's stages (:mod:`analysis.loop`) without the diagnosis - one model of the twin
for both commands.

1. The emulator of the twin at the dataset's conditions (:class:`analysis.emulated_twin.
   EmulatedTwin`), built in waves of twin runs where the data are plausible (history
   matching), every run cached by its id and read from the committed run table.
2. The parameters fitted on it with its own uncertainty in the likelihood
   (-2 log L = chi2 + sum log sigma^2, sigma^2 = the data's sd^2 + the emulator's sd^2 at the
   point), a focus wave about the fit, the twin rerun at the fitted point (validation: its
   runs join the emulator and the fit is redone) and the profile-likelihood intervals - as
   the loop does them, with no effect added.
3. The posterior: that likelihood times a uniform prior on the box, sampled with emcee's
   affine-invariant ensemble (Foreman-Mackey et al. 2013) on the final emulator.

Writes ``--out`` (default results/calibration): ``summary.json`` (posterior mean and sd, the
fixed run-config keys, the twin budget), ``parameters.csv`` (mean, sd, quantiles, the fit's
value and profile interval), ``posterior_samples.csv``, ``table3_comparison.csv`` (measured,
the paper's DEM where the dataset has it, the emulator at the posterior, the twin rerun),
``design_runs.csv`` (every run the emulator was fitted to), ``staircase.csv``, parity.png,
posterior_pairs.png.

References: Kennedy & O'Hagan (2001) JRSS B 63:425; Vernon, Goldstein & Bower (2010) Bayesian
Analysis 5:619; Foreman-Mackey et al. (2013) PASP 125:306.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from analysis.atomic_dir import OutputError, check_out_dir, output_dir
from analysis.config import CALIBRATION_DIR, PAPER_TABLE3_DIR
from analysis.measurements import DatasetError as MeasurementError
from analysis.measurements import load_dataset
# calibrated parameters and their prior bounds (CALIBRATED), the apparatus parameters a
# calibration may free (APPARATUS), every parameter ``--free NAME[=LO:HI]`` accepts (PRIORS):
# declared in analysis.parameter_space
from analysis.parameter_space import APPARATUS, CALIBRATED, PRIORS, parse_free

#: emcee's ensemble: walkers, steps per walker, steps burnt
N_WALKERS, N_STEPS, N_BURN = 32, 1200, 400


@dataclass
class CalibrationResult:
    """The posterior of the calibrated parameters and what the twin says at it.

    params, stderr : Series - posterior mean and sd per parameter
    interval : DataFrame - q2.5, q50, q97.5 per parameter
    fit : DataFrame - the loop's fit: value, se, profile_lo, profile_hi per parameter
    samples : DataFrame - posterior samples (one column per parameter)
    comparison : DataFrame - per condition: measured, emulator at the posterior, twin rerun
    design : DataFrame - every twin run the emulator was fitted to
    staircase : DataFrame - the loop's chi2 stages (baseline, calibrated, twin rerun, refit)
    n_runs, new_runs : int - runs the emulator holds, runs made now
    acceptance : float - emcee's mean acceptance fraction
    bounds : {name: (lo, hi)} - the prior box
    base_config : dict - run-config keys fixed in every run
    """
    params: pd.Series
    stderr: pd.Series
    interval: pd.DataFrame
    fit: pd.DataFrame
    samples: pd.DataFrame
    comparison: pd.DataFrame
    design: pd.DataFrame
    staircase: pd.DataFrame
    n_runs: int
    new_runs: int
    acceptance: float
    bounds: dict
    base_config: dict = field(default_factory=dict)

    def to_frame(self):
        """Per parameter: mean, sd, q2.5, q50, q97.5, the fit's value and profile interval,
        prior lower, prior upper."""
        df = pd.DataFrame({"mean": self.params, "sd": self.stderr}).join(self.interval)
        df = df.join(self.fit.rename(columns={"value": "fit", "se": "fit_se"}))
        df["prior_lower"] = [self.bounds[k][0] for k in df.index]
        df["prior_upper"] = [self.bounds[k][1] for k in df.index]
        df.index.name = "parameter"
        return df

    def covers(self, truth):
        """Per parameter: does the 95 % posterior interval hold ``truth[name]``?"""
        return pd.Series({k: bool(self.interval.loc[k, "q2.5"] <= truth[k]
                                  <= self.interval.loc[k, "q97.5"]) for k in self.params.index})


# ------------------------------------------------------------------------------- posterior

class Posterior:
    """log posterior of the base parameters on the loop's emulator: a uniform prior on the
    box, the likelihood every fit of the loop uses (:class:`analysis.diagnose.Problem` on
    the model: the emulator's covariance at each point, its motion modes' mixture)."""

    def __init__(self, model, obs):
        from analysis.diagnose import Problem
        from analysis.loop import WithAdded
        self.model = model
        self.params = list(model.base_params())
        self.names = [p.name for p in self.params]
        self.lo = np.array([p.lower for p in self.params])
        self.hi = np.array([p.upper for p in self.params])
        self.problem = Problem(model.predict, obs, self.params, [], WithAdded(model, {}).model_se(),
                               None, 1e-3, None)

    def one(self, theta: dict) -> float:
        """log L up to a constant: -(chi2 + the log-determinant and mode rows) / 2."""
        p = self.problem
        r = p.white(p.y - p.mu(theta, {}), {}, theta)
        return float(-0.5 * (r @ r + p.penalty({}, theta)))

    def __call__(self, x):
        x = np.atleast_2d(x)
        ok = np.all((x >= self.lo) & (x <= self.hi), axis=1)
        out = np.full(len(x), -np.inf)
        thetas = [dict(zip(self.names, map(float, row))) for row in x[ok]]
        if len(thetas) > 1:
            self.model.prefetch([(t, {}) for t in thetas])
        out[ok] = [self.one(t) for t in thetas]
        return out


def sample_posterior(logpost, start, spread, n_walkers=N_WALKERS, n_steps=N_STEPS,
                     burn=N_BURN, seed=0):
    """emcee ensemble sampling of ``logpost`` (vectorised over rows) from a ball about
    ``start`` (``spread``: the fit's standard errors, each at least 1 % of the box).
    Returns (samples, acceptance fraction)."""
    import emcee
    rng = np.random.default_rng(seed)
    lo, hi = logpost.lo, logpost.hi
    sd = np.clip(np.nan_to_num(np.asarray(spread, float), nan=0.0), 0.01 * (hi - lo), hi - lo)
    p0 = np.clip(np.asarray(start, float) + sd * rng.standard_normal((n_walkers, len(lo))),
                 lo + 1e-9 * (hi - lo), hi - 1e-9 * (hi - lo))
    sampler = emcee.EnsembleSampler(n_walkers, len(lo), logpost, vectorize=True)
    sampler.random_state = np.random.RandomState(int(rng.integers(2**31))).get_state()
    sampler.run_mcmc(p0, n_steps, progress=False)
    return (sampler.get_chain(discard=burn, flat=True),
            float(np.mean(sampler.acceptance_fraction)))


# ------------------------------------------------------------------------------- calibrate

def calibration_settings(bounds=None, **loop_options):
    """The loop's settings of a calibration: ``bounds`` {name: (lo, hi)} (default
    :data:`CALIBRATED`) the calibrated parameters, no effect added. The loop's own base
    parameters over their declared priors come first, in its order, so that a calibration
    on a dataset asks for the same design - the same runs - as the loop on it."""
    from analysis.loop import DEFAULT_BASE, LoopSettings
    bounds = dict(bounds or CALIBRATED)
    base = tuple(k for k in DEFAULT_BASE
                 if k in bounds and tuple(bounds[k]) == tuple(PRIORS[k]))
    free = tuple((k, float(lo), float(hi)) for k, (lo, hi) in bounds.items() if k not in base)
    return LoopSettings(base=base, free=free, max_effects=0, null_draws=0, **loop_options)


def calibrate(dataset, settings=None, *, twin=None, base_config=None, n_walkers=N_WALKERS,
              n_steps=N_STEPS, burn=N_BURN, seed=0, progress=True,
              log=print) -> CalibrationResult:
    """Calibrate on a loaded dataset (:func:`analysis.measurements.load_dataset`): the loop's
    stages with ``settings`` (:func:`calibration_settings`), then the posterior sampled on its
    final emulator. ``twin`` runs the design (default: the YADE twin, cached, with the
    committed run table); ``base_config`` the run-config keys fixed in every run."""
    from analysis.loop import run_stages
    from analysis.twin_runs import TwinRuns
    s = settings or calibration_settings()
    twin = twin if twin is not None else TwinRuns(base_config=base_config, progress=progress)
    state = run_stages(dataset, s, twin=twin, base_config=base_config, progress=progress,
                       log=log)
    post = Posterior(state.model, state.obs)
    fit = state.final
    log("posterior: emcee, %d walkers x %d steps on the emulator (%d runs)"
        % (n_walkers, n_steps, len(state.model.runs_)))
    x, acc = sample_posterior(post, [fit.params[k] for k in post.names],
                              [fit.stderr.get(k, np.nan) for k in post.names],
                              n_walkers=n_walkers, n_steps=n_steps, burn=burn, seed=seed)
    samples = pd.DataFrame(x, columns=post.names)
    q = samples.quantile([0.025, 0.5, 0.975]).T
    q.columns = ["q2.5", "q50", "q97.5"]
    fit_tab = pd.DataFrame({k: {"value": float(fit.params[k]),
                                "se": float(fit.stderr.get(k, np.nan)),
                                "profile_lo": getattr(state.intervals.get(k), "lower", np.nan),
                                "profile_hi": getattr(state.intervals.get(k), "upper", np.nan)}
                            for k in post.names}).T
    from analysis.loop import run_table_of
    return CalibrationResult(
        params=samples.mean(), stderr=samples.std(ddof=1), interval=q, fit=fit_tab,
        samples=samples, comparison=comparison_table(state, post, samples),
        design=run_table_of(state.model.runs_), staircase=pd.DataFrame(state.stair),
        n_runs=int(len(state.model.runs_)), new_runs=int(twin.new_runs), acceptance=acc,
        bounds={p.name: (p.lower, p.upper) for p in post.params},
        base_config=dict(base_config or {}))


def comparison_table(state, post, samples, n_draws=200, seed=0) -> pd.DataFrame:
    """Per condition: the measured speed and rate (and the paper's DEM speed where the dataset
    has it), the emulator's prediction averaged over ``n_draws`` posterior samples (its sd the
    parameters' spread), the twin rerun's mean and sd at the fitted point, the errors [%]."""
    from analysis.emulated_twin import SPEED_COLUMN
    from analysis.measurements import summary_wide
    ds, m = state.dataset, state.model
    wide = summary_wide(ds).set_index("condition_id")
    v_col = SPEED_COLUMN[m.velocity_frame]
    rng = np.random.default_rng(seed)
    sub = samples.iloc[rng.choice(len(samples), size=min(n_draws, len(samples)), replace=False)]
    pred = pd.concat([m.predict(dict(r), {}) for r in sub.to_dict("records")], axis=1)
    cids = list(m.conditions["condition_id"])
    out = pd.DataFrame({"condition_id": cids})
    out["frequency_hz"] = wide.loc[cids, "frequency_hz"].to_numpy(float)
    out["ball_diameter_mm"] = 1e3 * wide.loc[cids, "ball_diameter_m"].to_numpy(float)
    for q, obs_name, unit in (("v_mean", "v_mean_m_s", "m_s"), ("f_col", "f_col_hz", "hz")):
        out["%s_measured_%s" % (q, unit)] = wide.loc[cids, obs_name].to_numpy(float)
        rows = pred.reindex([(c, obs_name) for c in cids])
        out["%s_emulator_%s" % (q, unit)] = rows.mean(axis=1).to_numpy(float)
        out["%s_emulator_sd_%s" % (q, unit)] = rows.std(axis=1).to_numpy(float)
    if "v_mean_dem_paper_m_s" in wide:
        out["v_mean_dem_paper_m_s"] = wide.loc[cids, "v_mean_dem_paper_m_s"].to_numpy(float)
    if state.reruns:
        runs = state.reruns[-1].runs
        for q, col, unit in (("v_mean", v_col, "m_s"), ("f_col", "f_col_hz", "hz")):
            g = runs.groupby("condition_id")[col]
            out["%s_twin_%s" % (q, unit)] = g.mean().reindex(cids).to_numpy(float)
            out["%s_twin_sd_%s" % (q, unit)] = g.std(ddof=1).reindex(cids).to_numpy(float)
    ours = "twin" if state.reruns else "emulator"
    out["v_err_pct"] = 100.0 * (out["v_mean_%s_m_s" % ours] / out["v_mean_measured_m_s"] - 1)
    out["f_col_err_pct"] = 100.0 * (out["f_col_%s_hz" % ours] / out["f_col_measured_hz"] - 1)
    if "v_mean_dem_paper_m_s" in out:
        out["v_err_paper_pct"] = 100.0 * (out["v_mean_dem_paper_m_s"]
                                          / out["v_mean_measured_m_s"] - 1)
    return out


# ------------------------------------------------------------------------------------- CLI

def write_results(res, out_dir, dataset_name="", protected=()):
    """Write the calibration's tables and figures into ``out_dir`` atomically (temporary folder
    beside it, swapped in when complete); an ``out_dir`` that is not ours to replace, or touches
    a ``protected`` input, is refused (:func:`analysis.atomic_dir.check_out_dir`)."""
    from analysis.plotting.calibration_plots import write_calibration_figures
    with output_dir(out_dir, protected) as tmp:
        res.to_frame().to_csv(tmp / "parameters.csv", float_format="%.6g")
        res.comparison.to_csv(tmp / "table3_comparison.csv", index=False, float_format="%.5g")
        res.design.to_csv(tmp / "design_runs.csv", index=False, float_format="%.6g")
        res.staircase.to_csv(tmp / "staircase.csv", index=False, float_format="%.5g")
        res.samples.to_csv(tmp / "posterior_samples.csv", index=False, float_format="%.6g")
        modes = (res.design["motion_mode"].astype(str).value_counts().to_dict()
                 if "motion_mode" in res.design else {})
        summary = {"dataset": dataset_name, "model": "the loop's emulator (analysis.loop)",
                   "n_runs": res.n_runs, "new_runs": res.new_runs,
                   "acceptance_fraction": res.acceptance,
                   "params": res.params.to_dict(), "stderr": res.stderr.to_dict(),
                   "bounds": {k: list(v) for k, v in res.bounds.items()},
                   "base_config": res.base_config, "motion_modes": modes}
        (tmp / "summary.json").write_text(json.dumps(summary, indent=1))
        write_calibration_figures(res, tmp)
    return Path(out_dir)


def base_config_of(base_profile, settings, bounds, frame="auto") -> dict:
    """The run-config keys fixed in every run: a profile's ``config`` (less the freed keys),
    then ``--set KEY=VALUE`` pairs over it, then the integration ``frame`` where neither
    names one (the loop's default, so that both ask for the same runs: 'auto', the jar frame
    where the effects allow it). ValueError for a profile without ``config``, a malformed
    pair, or a key both fixed and freed."""
    base = {}
    if base_profile:
        try:
            prof = json.loads(Path(base_profile).read_text())
            base = {k: v for k, v in dict(prof["config"]).items() if k not in bounds}
        except (KeyError, TypeError) as exc:
            raise ValueError("--base-profile %s has no 'config' object (%s)"
                             % (base_profile, exc))
    for kv in settings:
        if "=" not in kv:
            raise ValueError("--set needs KEY=VALUE, got %r" % kv)
        k, v = kv.split("=", 1)
        base[k] = json.loads(v) if v[:1] in "0123456789-[{" else v
    clash = sorted(set(base) & set(bounds))
    if clash:
        raise ValueError("--set fixes %s, which --free calibrates" % ", ".join(clash))
    if frame != "lab":
        base.setdefault("frame", frame)
    return base


def _parser():
    p = argparse.ArgumentParser(
        prog="python -m analysis.calibrate",
        description="Calibrate restitution, static/rolling friction and the jar's stroke (or "
        "the parameters --free names) on a measurement dataset: the loop's emulator of the "
        "twin, built in waves of twin runs, then emcee on it.",
        epilog="example: python -m analysis.calibrate --dataset data/measurements/paper_table3 "
        "--out results/calibration --workers 2")
    p.add_argument("--dataset", default=str(PAPER_TABLE3_DIR),
                   help="measurement dataset folder (default: data/measurements/paper_table3)")
    p.add_argument("--out", default=str(CALIBRATION_DIR),
                   help="output folder (default: results/calibration)")
    p.add_argument("--fake", action="store_true",
                   help="use the FAKE analytic twin (analysis.fake_twin), no YADE")
    p.add_argument("--workers", type=int, default=2,
                   help="parallel twin runs [processes] (default %(default)s)")
    p.add_argument("--points", type=int, default=24,
                   help="wave-0 design points, each run at every condition [points] "
                   "(default %(default)s)")
    p.add_argument("--waves", type=int, default=2,
                   help="refinement waves where the data are plausible [waves] "
                   "(default %(default)s)")
    p.add_argument("--per-wave", type=int, default=8,
                   help="design points per refinement wave [points] (default %(default)s)")
    p.add_argument("--focus-points", type=int, default=6,
                   help="design points of the focus wave about the fit (0: none) [points] "
                   "(default %(default)s)")
    p.add_argument("--rerun-replicates", type=int, default=3,
                   help="twin runs at the fitted point per condition (validation) [seeds] "
                   "(default %(default)s)")
    p.add_argument("--v-rel-sd", type=float, default=None,
                   help="measured v_mean sd where the dataset states none, as a fraction of "
                   "v_mean [-] (default the loop's 0.015)")
    p.add_argument("--frame", choices=("lab", "jar", "auto"), default="auto",
                   help="frame the twin runs are integrated in (default %(default)s, as the "
                   "loop's: the jar frame, 1.7-1.9x faster, where the effects allow it)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="run-config key fixed in every run, e.g. record_s=0.5 (repeatable; "
                   "VALUE in the SI unit the key's name states)")
    p.add_argument("--base-profile", default=None, metavar="FILE",
                   help="a profile JSON (its 'config': run-config keys, e.g. "
                   "results/apparatus/paper_apparatus.json) fixed in every run, except "
                   "the keys freed by --free; --set overrides it")
    p.add_argument("--free", action="append", default=None, metavar="NAME[=LO:HI]",
                   help="a parameter to calibrate, with optional bounds inside its declared "
                   "range, in the parameter's SI unit (repeatable; default: %s; apparatus: %s)"
                   % (", ".join(CALIBRATED), ", ".join(APPARATUS)))
    p.add_argument("--steps", type=int, default=N_STEPS,
                   help="emcee steps per walker, the first third burnt [steps] "
                   "(default %(default)s)")
    p.add_argument("--seed", type=int, default=0,
                   help="seed of the design and the sampler [-] (default %(default)s)")
    return p


def main(argv=None):
    args = _parser().parse_args(argv)
    protected = [args.dataset]
    try:
        check_out_dir(args.out, protected)
        for name in ("workers", "points", "per_wave", "rerun_replicates", "steps"):
            if getattr(args, name) < 1:
                raise ValueError("--%s must be >= 1" % name.replace("_", "-"))
        bounds = parse_free(args.free)
        base = base_config_of(args.base_profile, args.set, bounds, args.frame)
        ds = load_dataset(args.dataset)
        from analysis.conditions import physics_table
        from analysis.loop import check_balls_fit
        from analysis.measurements import conditions_file
        physics_table(ds.conditions, conditions_file(ds))     # one ball, distinct physics
        check_balls_fit(ds, base or {})                       # each ball fits the jar
        if args.v_rel_sd is not None:
            from analysis.loop import with_assumed_v_sd
            ds = with_assumed_v_sd(ds, args.v_rel_sd)
        settings = calibration_settings(bounds, points=args.points, waves=args.waves,
                                        per_wave=args.per_wave,
                                        focus_points=args.focus_points,
                                        rerun_replicates=args.rerun_replicates,
                                        confirm_rounds=1, seed=args.seed,
                                        n_jobs=args.workers).check()
        from analysis.loop import dof_limits
        dof_limits(ds, 0, (), settings.free, settings.base)     # too few data: refused here
        from analysis.twin_runs import TwinRuns
        twin = TwinRuns(workers=args.workers, base_config=base or None)
        if args.fake:
            from analysis.config import FAKE_RUNS_DIR
            from analysis.fake_twin import run_fake_twin
            twin = TwinRuns(runner=run_fake_twin, runs_dir=FAKE_RUNS_DIR, workers=args.workers,
                            base_config=base or None)
        t0 = time.time()
        res = calibrate(ds, settings, twin=twin, base_config=base or None,
                        n_steps=args.steps, burn=args.steps // 3, seed=args.seed,
                        log=lambda s: print(s, flush=True))
        out = write_results(res, args.out, ds.name, protected)
    except (MeasurementError, OutputError, ValueError, OSError) as exc:
        print("analysis.calibrate: error: %s" % exc, file=sys.stderr)
        return 2
    except RuntimeError as exc:                     # a twin run failed: not the input's fault
        print("analysis.calibrate: error: %s" % str(exc).replace("\n", " "), file=sys.stderr)
        return 1
    print(res.to_frame().to_string(float_format=lambda x: "%.4g" % x))
    cols = [c for c in ("condition_id", "v_mean_measured_m_s", "v_mean_dem_paper_m_s",
                        "v_mean_twin_m_s", "v_mean_twin_sd_m_s", "v_err_pct",
                        "f_col_measured_hz", "f_col_twin_hz", "f_col_err_pct")
            if c in res.comparison]
    print(res.comparison[cols].to_string(index=False, float_format=lambda x: "%.3g" % x))
    print("twin budget: %d runs in the emulator, %d new; %.0f s; wrote %s%s"
          % (res.n_runs, res.new_runs, time.time() - t0, out,
             "  [FAKE twin]" if args.fake else ""))
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except KeyboardInterrupt as exc:          # SIGINT / SIGTERM: one line, 130 / 143
        from analysis.sweep import interrupted_exit
        sys.exit(interrupted_exit("analysis.calibrate", exc))
