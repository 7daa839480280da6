"""Coverage of the calibration's 95 % intervals, checked on the FAKE analytic twin.

Draws ``--trials`` true parameter sets from the central 80 % of the prior box, makes a
synthetic dataset at the paper's 8 Table-3 conditions from one FAKE-twin run per condition
(:func:`analysis.hidden.make_hidden_dataset`: the run's replicate noise plus 0.3 % measurement
noise on the speed), calibrates it (:func:`analysis.calibrate.calibrate`: the loop's emulator,
then emcee) and records whether each 95 % interval holds the truth. Writes
results/studies/calibration_coverage_fake.csv and prints coverage per parameter and the RMS of
(mean - truth) / sd.

This checks the machinery (design, emulator, likelihood, MCMC), not the real twin.

    python -m analysis.studies.calibration_coverage --trials 20
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd
from threadpoolctl import threadpool_limits

from analysis import calibrate as cal
from analysis.config import PAPER_TABLE3_DIR, STUDIES_DIR


def trial(t, truth, work: Path, n_steps):
    """One calibration of FAKE data made at ``truth``: a row of truth, mean, sd, covered."""
    from analysis.fake_twin import FAKE_FCOL_SD_HZ, FAKE_V_REL_SD, run_fake_twin
    from analysis.hidden import make_hidden_dataset
    from analysis.measurements import load_dataset
    from analysis.twin_runs import TwinRuns
    conds = pd.read_csv(PAPER_TABLE3_DIR / "conditions.csv")
    ds_dir, _ = make_hidden_dataset(
        "cov%02d" % t, {}, conditions=conds, replicates=1, seed=5000 + t,
        runner=run_fake_twin, base_config=dict(truth), runs_dir=work / "runs",
        out_dir=work / "ds", truth_dir=work / "truth", twin_v_rel_sd=FAKE_V_REL_SD,
        twin_f_col_sd_hz=FAKE_FCOL_SD_HZ, progress=False, v_rel_sd=0.003,
        yield_times_min=())
    twin = TwinRuns(runner=run_fake_twin, runs_dir=work / "runs", workers=1, progress=False)
    t0 = time.time()
    res = cal.calibrate(load_dataset(ds_dir), cal.calibration_settings(seed=t), twin=twin,
                        n_steps=n_steps, burn=n_steps // 3, seed=t, progress=False,
                        log=lambda s: None)
    cover = res.covers(truth)
    row = {"trial": t, "wall_s": time.time() - t0, "n_runs": res.n_runs}
    for k in cal.CALIBRATED:
        row.update({"truth_" + k: truth[k], "mean_" + k: res.params[k],
                    "sd_" + k: res.stderr[k], "covered_" + k: bool(cover[k])})
    return row


def run(trials=20, seed=2026, n_steps=1200):
    """One row per trial (truth, posterior mean and sd, covered)."""
    rng = np.random.default_rng(seed)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for t in range(trials):
            truth = {k: lo + (hi - lo) * (0.1 + 0.8 * rng.random())
                     for k, (lo, hi) in cal.CALIBRATED.items()}
            rows.append(trial(t, truth, Path(tmp) / str(t), n_steps))
            print("trial %d: covered %s (%.0f s)"
                  % (t, {k: rows[-1]["covered_" + k] for k in cal.CALIBRATED},
                     rows[-1]["wall_s"]), flush=True)
    return pd.DataFrame(rows)


def main(argv=None):
    p = argparse.ArgumentParser(prog="python -m analysis.studies.calibration_coverage",
                                description=__doc__,
                                epilog="example: python -m analysis.studies.calibration_coverage "
                                       "--trials 20",
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--trials", type=int, default=20,
                   help="true parameter sets drawn and calibrated [trials] (default %(default)s)")
    p.add_argument("--n-steps", type=int, default=1200,
                   help="emcee steps per walker, the first third burnt [steps] "
                        "(default %(default)s)")
    p.add_argument("--seed", type=int, default=2026,
                   help="random seed of the truths [-] (default %(default)s)")
    p.add_argument("--out", default=str(STUDIES_DIR / "calibration_coverage_fake.csv"),
                   help="CSV to write (default: results/studies/calibration_coverage_fake.csv)")
    args = p.parse_args(argv)
    if args.trials < 1 or args.n_steps < 10:
        print("calibration_coverage: error: --trials >= 1 and --n-steps >= 10",
              file=sys.stderr)
        return 2
    with threadpool_limits(1):
        df = run(args.trials, args.seed, args.n_steps)
    from analysis.atomic_dir import atomic_file
    with atomic_file(args.out) as tmp:
        df.to_csv(tmp, index=False, float_format="%.6g")
    for k in cal.CALIBRATED:
        z = (df["mean_" + k] - df["truth_" + k]) / df["sd_" + k]
        print("%-17s 95%% coverage %d/%d, RMS z %.2f, mean |error| %.3g, mean sd %.3g"
              % (k, df["covered_" + k].sum(), len(df), np.sqrt(np.mean(z ** 2)),
                 (df["mean_" + k] - df["truth_" + k]).abs().mean(), df["sd_" + k].mean()))
    print("wrote %s  [FAKE twin]" % args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
