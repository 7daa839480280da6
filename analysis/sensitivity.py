"""Sensitivity of the twin's mean ball speed to the contact parameters.

(a) The paper's Figure 8 design (Anglou et al. 2024, Sec. 3.2): one 20.6 mm ball at 25 Hz, a
    full grid over restitution C_R, static_friction SF and rolling_friction RF within Table 2's
    bounds (default 4 x 3 x 3 levels), ``replicates`` runs per grid point that differ only in
    the seed (the ball's start position). Reported: mean +- sd of v_mean per point, and which
    points reproduce the measured 2.13 m/s "within the noise" - solution multiplicity.
    A point matches when |mean - target| <= z * sqrt(s_rep^2 / n_rep + sd_meas^2), with s_rep
    the replicate sd pooled over the grid (3 replicates alone give a very rough sd) and sd_meas
    the measurement sd (default 2 % of the target).
(b) Variance-based (Sobol) indices, first order and total, with bootstrap confidence intervals,
    through SALib (Saltelli/Sobol' sequence sampling, Saltelli et al. 2010; Jansen estimators),
    evaluated on a cheap model - the GP emulator (analysis.emulator) of the twin, or any
    vectorised function. The indices are those of the emulator's mean response; the emulator's
    own uncertainty is not propagated into them.

All functions take ``simulate(configs) -> DataFrame`` (a sweep, ``analysis.sweep.
make_simulator()``; or ``analysis.fake_twin.simulate_fake``) or a model function, so tests use
cheap analytic stand-ins.

References
----------
Saltelli et al. (2010) Comput. Phys. Commun. 181:259. Herman & Usher (2017) JOSS 2(9):97
(SALib). Sobol' (2001) Math. Comput. Simul. 55:271.
"""
from __future__ import annotations

import argparse
import itertools
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from analysis.parameter_space import CALIBRATED
from analysis.config import STUDIES_DIR

#: Table 2 bounds of the contact parameters (declared once: the calibration's priors)
CONTACT_BOUNDS = {k: CALIBRATED[k] for k in ("restitution", "static_friction",
                                             "rolling_friction")}
#: default grid of the Figure-8 study (the paper does not list its levels)
FIGURE8_LEVELS = {"restitution": (0.1, 0.3, 0.5, 0.7), "static_friction": (0.3, 0.5, 0.7),
                  "rolling_friction": (0.1, 0.3, 0.5)}
FIGURE8_CONDITION = {"frequency_hz": 25.0, "ball_diameter_m": 0.0206}
FIGURE8_TARGET_M_S = 2.13


# ------------------------------------------------------------------------------ (a) grid study

def figure8_design(levels=None, replicates=3, base=None, condition=None):
    """Configs of the Figure-8 grid: every level combination x ``replicates`` seeds.

    Parameters
    ----------
    levels : dict name -> sequence, optional - grid levels (default FIGURE8_LEVELS)
    replicates : int - runs per grid point, seeds 0 .. replicates-1 (start positions)
    base : dict, optional - further config keys (record_s, amplitude_m, ...)
    condition : dict, optional - default 25 Hz, 20.6 mm

    Returns
    -------
    list of dict, length prod(len(levels)) * replicates
    """
    levels = dict(levels or FIGURE8_LEVELS)
    for k, vals in levels.items():
        lo, hi = CONTACT_BOUNDS.get(k, (-np.inf, np.inf))
        for v in vals:
            if not lo <= v <= hi:
                raise ValueError("grid level %s = %g outside Table 2 bounds [%g, %g]"
                                 % (k, v, lo, hi))
    if replicates < 1:
        raise ValueError("replicates must be >= 1, got %d" % replicates)
    cond = dict(condition or FIGURE8_CONDITION)
    names = list(levels)
    out = []
    for combo in itertools.product(*[levels[k] for k in names]):
        for rep in range(replicates):
            cfg = dict(base or {})
            cfg.update(cond)
            cfg.update({k: float(v) for k, v in zip(names, combo)})
            cfg["seed"] = rep
            out.append(cfg)
    return out


@dataclass
class GridStudy:
    """Result of :func:`grid_study`.

    Attributes
    ----------
    runs : DataFrame - one row per run (parameters, seed, v_mean_m_s, status, motion_mode)
    summary : DataFrame - one row per grid point: parameters, n_ok, v_mean_m_s_mean,
        v_mean_m_s_sd, modes (motion modes seen), mixed_modes (replicates in different
        modes: their mean mixes motions), matches (reproduces the target)
    pooled_sd_m_s : float - replicate sd pooled over the grid [m/s]
    tol_m_s : float - half width of the "reproduces the target" band [m/s]
    target_m_s : float
    """
    runs: pd.DataFrame
    summary: pd.DataFrame
    pooled_sd_m_s: float
    tol_m_s: float
    target_m_s: float

    @property
    def matches(self):
        """Grid points reproducing the target within the noise."""
        return self.summary[self.summary["matches"]]

    def to_frame(self):
        return self.summary.copy()


def grid_study(simulate, configs=None, names=None, target_m_s=FIGURE8_TARGET_M_S,
               meas_rel_sd=0.02, z=1.96):
    """Run the grid and summarise replicates; flag the points that reproduce ``target_m_s``.

    Parameters
    ----------
    simulate : callable ``simulate(configs) -> DataFrame`` with a v_mean_m_s column
    configs : list of dict, optional - default :func:`figure8_design()`
    names : list of str, optional - grid parameters (default the FIGURE8_LEVELS keys)
    target_m_s : float - measured speed [m/s]
    meas_rel_sd : float - relative measurement sd of the target [-]
    z : float - band half width in standard errors

    Returns
    -------
    GridStudy
    """
    configs = configs if configs is not None else figure8_design()
    names = list(names or FIGURE8_LEVELS)
    tab = simulate(configs).reset_index(drop=True)
    if "v_mean_m_s" not in tab:
        raise ValueError("simulate() returned no v_mean_m_s column")
    runs = pd.DataFrame(configs)[names + ["seed"]].copy()
    runs["v_mean_m_s"] = pd.to_numeric(tab["v_mean_m_s"], errors="coerce").to_numpy()
    runs["motion_mode"] = tab["motion_mode"].to_numpy() if "motion_mode" in tab else "unknown"
    runs["status"] = tab["status"].to_numpy() if "status" in tab else "done"
    g = runs.groupby(names, sort=True)
    summ = g["v_mean_m_s"].agg(v_mean_m_s_mean="mean", v_mean_m_s_sd="std",
                               n_ok="count").reset_index()
    summ["n_runs"] = g.size().to_numpy()
    summ["modes"] = g["motion_mode"].agg(lambda s: ",".join(sorted(set(map(str, s))))) \
        .to_numpy()
    # never average across motion modes silently: flag grid points whose replicates differ
    summ["mixed_modes"] = summ["modes"].str.contains(",")
    ok = summ["n_ok"] > 1
    dof = (summ.loc[ok, "n_ok"] - 1).sum()
    pooled = float(np.sqrt(((summ.loc[ok, "n_ok"] - 1) * summ.loc[ok, "v_mean_m_s_sd"] ** 2)
                           .sum() / dof)) if dof > 0 else float("nan")
    n_rep = summ["n_ok"].clip(lower=1)
    tol = z * np.sqrt(np.nan_to_num(pooled) ** 2 / n_rep + (meas_rel_sd * target_m_s) ** 2)
    summ["tol_m_s"] = tol
    summ["matches"] = (summ["v_mean_m_s_mean"] - target_m_s).abs() <= tol
    return GridStudy(runs=runs, summary=summ, pooled_sd_m_s=pooled,
                     tol_m_s=float(np.median(tol)), target_m_s=target_m_s)


# ----------------------------------------------------------------------------- (b) Sobol

@dataclass
class SobolResult:
    """First-order (S1) and total (ST) Sobol indices with confidence half widths."""
    names: list
    S1: np.ndarray
    S1_conf: np.ndarray
    ST: np.ndarray
    ST_conf: np.ndarray
    n_evaluations: int
    conf_level: float

    @property
    def params(self):
        return pd.Series(self.S1, index=self.names)

    @property
    def stderr(self):
        """Approximate standard errors of S1 (confidence half width / z)."""
        from scipy.stats import norm
        return pd.Series(self.S1_conf / norm.ppf(0.5 + self.conf_level / 2), index=self.names)

    def to_frame(self):
        return pd.DataFrame({"S1": self.S1, "S1_conf": self.S1_conf, "ST": self.ST,
                             "ST_conf": self.ST_conf}, index=pd.Index(self.names,
                                                                      name="parameter"))


def sobol_indices(model, bounds, n_base=1024, conf_level=0.95, num_resamples=200, seed=0):
    """Sobol indices of a vectorised model over a box, through SALib.

    Parameters
    ----------
    model : callable ``model(X) -> y`` with X ndarray, shape (n, k), y shape (n,)
    bounds : dict name -> (lo, hi)
    n_base : int - base sample size N (a power of 2); N * (k + 2) model evaluations
    conf_level : float - confidence level of the bootstrap intervals
    num_resamples : int - bootstrap resamples
    seed : int

    Returns
    -------
    SobolResult
    """
    from SALib.analyze import sobol as sobol_analyze
    from SALib.sample import sobol as sobol_sample
    names = list(bounds)
    problem = {"num_vars": len(names), "names": names,
               "bounds": [list(map(float, bounds[k])) for k in names]}
    X = sobol_sample.sample(problem, n_base, calc_second_order=False, seed=seed)
    y = np.asarray(model(X), float).ravel()
    if y.shape != (len(X),):
        raise ValueError("model returned shape %s for %d inputs" % (y.shape, len(X)))
    if not np.isfinite(y).all():
        raise ValueError("model returned NaN or inf")
    si = sobol_analyze.analyze(problem, y, calc_second_order=False, conf_level=conf_level,
                               num_resamples=num_resamples, seed=seed)
    return SobolResult(names=names, S1=np.asarray(si["S1"]), S1_conf=np.asarray(si["S1_conf"]),
                       ST=np.asarray(si["ST"]), ST_conf=np.asarray(si["ST_conf"]),
                       n_evaluations=len(X), conf_level=conf_level)


def emulator_model(emulator, output="v_mean_m_s", fixed=None):
    """Wrap a fitted GPEmulator as ``model(X) -> y`` over the inputs not in ``fixed``.

    Parameters
    ----------
    emulator : analysis.emulator.GPEmulator
    output : str - one of emulator.outputs
    fixed : dict, optional - input values held fixed (e.g. the condition 25 Hz, 20.6 mm)

    Returns
    -------
    model, free_names
    """
    fixed = dict(fixed or {})
    free = [k for k in emulator.inputs if k not in fixed]
    j = list(emulator.outputs).index(output)

    def model(X):
        X = np.atleast_2d(X)
        full = pd.DataFrame(X, columns=free)
        for k, v in fixed.items():
            full[k] = v
        return emulator.predict(full)[:, j]
    return model, free


def emulator_sobol(emulator, bounds, output="v_mean_m_s", fixed=None, **kw):
    """Sobol indices of the emulator's mean response over ``bounds`` (others fixed)."""
    model, free = emulator_model(emulator, output, fixed)
    missing = [k for k in free if k not in bounds]
    if missing:
        raise ValueError("no bounds for free emulator input(s) %s" % ", ".join(missing))
    return sobol_indices(model, {k: bounds[k] for k in free}, **kw)


# ----------------------------------------------------------------------------------- CLI

def main(argv=None):
    p = argparse.ArgumentParser(prog="python -m analysis.sensitivity",
                                description="Figure-8 grid study (C_R x SF x RF at 25 Hz, "
                                            "20.6 mm, replicates) and Sobol indices on a GP "
                                            "emulator fitted to the grid runs.",
                                epilog="example: python -m analysis.sensitivity --out "
                                       "results/studies/sensitivity --replicates 3 --workers 2")
    p.add_argument("--out", default=str(STUDIES_DIR / "sensitivity"),
                   help="output folder (default: results/studies/sensitivity)")
    p.add_argument("--fake", action="store_true", help="use the FAKE analytic twin")
    p.add_argument("--runner", default=None, help="twin runner 'module:function'")
    p.add_argument("--workers", type=int, default=2,
                   help="parallel twin runs [processes] (default %(default)s)")
    p.add_argument("--backend", default="local", choices=("local", "serial", "dask"))
    p.add_argument("--runs-dir", default=None)
    p.add_argument("--replicates", type=int, default=3,
                   help="runs per grid point, differing in the seed [seeds] "
                        "(default %(default)s)")
    p.add_argument("--record-s", type=float, default=None,
                   help="recorded time per run [s] (default: the run config's)")
    p.add_argument("--target", type=float, default=FIGURE8_TARGET_M_S,
                   help="measured mean ball speed the grid points must reproduce [m/s] "
                        "(default %(default)s)")
    p.add_argument("--n-base", type=int, default=1024,
                   help="Sobol base sample size N, a power of 2 [samples] "
                        "(default %(default)s)")
    p.add_argument("--seed", type=int, default=0,
                   help="random seed of the emulator fit and the Sobol sampling [-] "
                        "(default %(default)s)")
    args = p.parse_args(argv)
    from analysis.atomic_dir import check_out_dir, output_dir
    from analysis.emulator import GPEmulator
    from analysis.plotting.calibration_plots import write_sensitivity_figures
    protected = [args.runs_dir]          # the twin's run cache is never an output
    try:
        check_out_dir(args.out, protected)   # before any twin run
        if args.fake:
            from analysis.fake_twin import simulate_fake as simulate
        else:
            from analysis.sweep import make_simulator
            simulate = make_simulator(runner=args.runner, workers=args.workers,
                                      backend=args.backend, runs_dir=args.runs_dir)
        base = {"record_s": args.record_s} if args.record_s else None
        study = grid_study(simulate, figure8_design(replicates=args.replicates, base=base),
                           target_m_s=args.target)
        ok = study.runs.dropna(subset=["v_mean_m_s"])
        em = GPEmulator(CONTACT_BOUNDS, outputs=("v_mean_m_s",), random_state=args.seed)
        em.fit(ok, ok)
        sob = emulator_sobol(em, CONTACT_BOUNDS, n_base=args.n_base, seed=args.seed)
        out = Path(args.out)
        with output_dir(out, protected) as tmp:
            study.runs.to_csv(tmp / "figure8_runs.csv", index=False, float_format="%.6g")
            study.summary.to_csv(tmp / "figure8_grid.csv", index=False, float_format="%.6g")
            sob.to_frame().to_csv(tmp / "sobol_v_mean.csv", float_format="%.5g")
            em.loo_.to_csv(tmp / "emulator_loo.csv", float_format="%.5g")
            write_sensitivity_figures(study.summary, study.target_m_s, study.tol_m_s,
                                      sob.to_frame(), tmp)
    except (ValueError, OSError) as exc:   # OutputError is a ValueError
        print("analysis.sensitivity: error: %s" % exc, file=sys.stderr)
        return 2
    m = study.matches
    print("grid: %d points x %d replicates, pooled replicate sd %.3f m/s, band +-%.3f m/s"
          % (len(study.summary), args.replicates, study.pooled_sd_m_s, study.tol_m_s))
    if study.summary["mixed_modes"].any():
        print("WARNING: %d grid point(s) have replicates in different motion modes (see "
              "figure8_grid.csv, column modes)" % int(study.summary["mixed_modes"].sum()))
    print("%d grid point(s) reproduce %.2f m/s within the noise:" % (len(m), study.target_m_s))
    print(m.to_string(index=False, float_format=lambda x: "%.3g" % x) if len(m) else "  none")
    print("emulator LOO:\n" + em.loo_.to_string(float_format=lambda x: "%.3g" % x))
    print("Sobol indices of v_mean (emulator, %d evaluations):\n%s"
          % (sob.n_evaluations, sob.to_frame().to_string(float_format=lambda x: "%.3f" % x)))
    print("wrote %s%s" % (out, "  [FAKE twin]" if args.fake else ""))
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except KeyboardInterrupt as exc:          # SIGINT / SIGTERM: one line, 130 / 143
        from analysis.sweep import interrupted_exit
        sys.exit(interrupted_exit("analysis.sensitivity", exc))
