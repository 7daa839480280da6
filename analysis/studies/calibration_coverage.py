"""Coverage of the calibration's 95 % intervals, checked on the FAKE analytic twin.

Draws ``--trials`` true parameter sets from the central 80 % of the prior box, makes synthetic
Table-3 measurements from one fake-twin run per condition (its replicate noise is the only
noise), runs :func:`analysis.calibrate.calibrate` with the default budget, and records whether
each 95 % interval holds the truth. Writes results/studies/calibration_coverage_fake.csv and
prints coverage per parameter, RMS of (mean - truth) / sd, and the emulator's LOO error.

This checks the machinery (design, emulator, likelihood, MCMC), not the real twin.

    python -m analysis.studies.calibration_coverage --trials 30
"""
from __future__ import annotations

import argparse
import sys
import time

import numpy as np
import pandas as pd
from threadpoolctl import threadpool_limits

from analysis import calibrate as cal
from analysis.config import STUDIES_DIR
from analysis.fake_twin import simulate_fake


def run(trials=30, seed=2026, **calib_kw):
    """Return one row per trial (truth, posterior mean and sd, covered, emulator LOO)."""
    names = list(cal.CALIBRATED)
    rng = np.random.default_rng(seed)
    base = cal.load_measurements()
    rows = []
    for t in range(trials):
        truth = {k: lo + (hi - lo) * (0.1 + 0.8 * rng.random())
                 for k, (lo, hi) in cal.CALIBRATED.items()}
        meas = base.copy()
        r = simulate_fake(cal.condition_configs(truth, meas, seed=5000 + t))
        meas["v_mean_m_s"] = r["v_mean_m_s"].to_numpy()
        meas["f_col_hz"] = r["f_col_hz"].to_numpy()
        meas["v_mean_sd_m_s"] = 0.0      # the run's own replicate noise is in the emulator
        meas["f_col_sd_hz"] = 0.0
        t0 = time.time()
        res = cal.calibrate(simulate_fake, meas, n_validation=0, random_state=t, **calib_kw)
        cover = res.covers(truth)
        row = {"trial": t, "wall_s": time.time() - t0, "n_runs": res.n_runs,
               "loo_v_rel_rmse_pct": res.loo.loc["v_mean_m_s", "rel_rmse_pct"],
               "loo_v_coverage95": res.loo.loc["v_mean_m_s", "coverage95"]}
        for k in names:
            row.update({"truth_" + k: truth[k], "mean_" + k: res.params[k],
                        "sd_" + k: res.stderr[k], "covered_" + k: bool(cover[k])})
        rows.append(row)
        print("trial %d: covered %s (%.0f s)" % (t, cover.to_dict(), row["wall_s"]),
              flush=True)
    return pd.DataFrame(rows)


def main(argv=None):
    p = argparse.ArgumentParser(prog="python -m analysis.studies.calibration_coverage",
                                description=__doc__,
                                epilog="example: python -m analysis.studies.calibration_coverage "
                                       "--trials 30 --out "
                                       "results/studies/calibration_coverage_fake.csv",
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--trials", type=int, default=30,
                   help="true parameter sets drawn and calibrated [trials] "
                        "(default %(default)s)")
    p.add_argument("--n-steps", type=int, default=1500,
                   help="emcee steps per walker, the first third burnt [steps] "
                        "(default %(default)s)")
    p.add_argument("--seed", type=int, default=2026,
                   help="random seed of the truths and the calibrations [-] "
                        "(default %(default)s)")
    p.add_argument("--out", default=str(STUDIES_DIR / "calibration_coverage_fake.csv"),
                   help="CSV to write (default: results/studies/calibration_coverage_fake.csv)")
    args = p.parse_args(argv)
    with threadpool_limits(1):
        df = run(args.trials, args.seed, n_steps=args.n_steps, burn=args.n_steps // 3)
    from analysis.atomic_dir import atomic_file
    with atomic_file(args.out) as tmp:
        df.to_csv(tmp, index=False, float_format="%.6g")
    for k in cal.CALIBRATED:
        z = (df["mean_" + k] - df["truth_" + k]) / df["sd_" + k]
        print("%-17s 95%% coverage %d/%d, RMS z %.2f, mean |error| %.3g, mean sd %.3g"
              % (k, df["covered_" + k].sum(), len(df), np.sqrt(np.mean(z ** 2)),
                 (df["mean_" + k] - df["truth_" + k]).abs().mean(), df["sd_" + k].mean()))
    print("emulator LOO v: %.2f %% RMSE (mean), 95 %% coverage %.3f; wrote %s  [FAKE twin]"
          % (df["loo_v_rel_rmse_pct"].mean(), df["loo_v_coverage95"].mean(), args.out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
