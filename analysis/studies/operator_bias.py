"""Bias of the observation operator against the twin's direct figures at the paper's 8 conditions.

For each condition of data/measurements/paper_table3 (the demo's runs, cached by run id; run
`make demo` first or let this script run them): the operator (camera at 2134 fps, (x, z) plane,
Savitzky-Golay, sign changes of v_x) against the true 3-D mean speed from trajectory.csv and the
collisions in impacts.csv, in the lab and the jar frame. Writes results/observe/operator_bias.csv.

    python -m analysis.studies.operator_bias [--replicates 2]
"""
import argparse
import sys

import pandas as pd

from analysis.config import OBSERVE_DIR


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                epilog="example: python -m analysis.studies.operator_bias "
                                "--replicates 2 --record-s 0.5")
    p.add_argument("--replicates", type=int, default=2,
                   help="twin runs per condition [seeds] (default %(default)s)")
    p.add_argument("--record-s", type=float, default=0.5,
                   help="recorded time per run [s] (default %(default)s)")
    p.add_argument("--workers", type=int, default=2,
                   help="parallel twin runs [processes] (default %(default)s)")
    a = p.parse_args(argv)
    from analysis.demo import demo_configs, measured_table
    from analysis.observe import operator_bias
    from analysis.sweep import run_sweep
    cond = measured_table()
    configs = demo_configs(cond, a.replicates, a.record_s)
    res = run_sweep(configs, workers=a.workers)
    rows = []
    for cfg, r in zip(configs, res.table.itertuples()):
        if r.status not in ("done", "cached"):
            continue
        for frame in ("lab", "jar"):
            b = operator_bias(r.run_dir, frame=frame)
            for q in b.itertuples():
                rows.append({"frequency_hz": cfg["frequency_hz"],
                             "ball_diameter_mm": cfg["ball_diameter_m"] * 1e3,
                             "seed": cfg["seed"], "frame": frame, "quantity": q.quantity,
                             "operator": q.operator, "direct": q.direct,
                             "relative_pct": 100 * q.relative, "motion_mode": r.motion_mode})
    out = pd.DataFrame(rows)
    OBSERVE_DIR.mkdir(parents=True, exist_ok=True)
    out.to_csv(OBSERVE_DIR / "operator_bias.csv", index=False, float_format="%.5g")
    summ = out.groupby(["frame", "quantity"])["relative_pct"].agg(["mean", "min", "max"])
    print(summ.to_string(float_format=lambda x: "%+.3f" % x))
    print("wrote", OBSERVE_DIR / "operator_bias.csv")
    return 0 if res.ok else 1


if __name__ == "__main__":
    sys.exit(main())
