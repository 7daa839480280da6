"""Twin runs for the surrogates and the kinetics (paper Sections 4-5).

The paper's design: 9 frequencies 20-30 Hz x 3 balls (analysis.surrogate.design_27: 14.3, 17.5,
20.6 mm), plus the Table 5 validation cases (10 mm ball radius at 25, 27.5 and 30 Hz), which are
also the 20 mm ball of the yield experiments. One seeded run per design point (as the paper) and
the mean of ``--validation-replicates`` start positions per validation case. Writes
results/twin_tables/twin_table.csv and results/twin_tables/validation_table.csv (frequency_hz,
ball_diameter_m, bvr, v_mean_m_s, f_col_hz, e_kin_j, motion_mode, run_id), the tables that
`python -m analysis.surrogate --twin-table` and `python -m analysis.kinetics --twin-table` read.

    python -m analysis.studies.surrogate_runs [--workers 2] [--seed 0]
"""
import argparse
import sys

import pandas as pd

from analysis.config import RESULTS_DIR

TABLES_DIR = RESULTS_DIR / "twin_tables"  # apart from results/surrogate/, which the CLI rewrites
from analysis.surrogate import bvr, design_27

VALIDATION = [(25.0, 0.020), (27.5, 0.020), (30.0, 0.020)]


def table_from_sweep(configs, sweep_table):
    t = sweep_table.reset_index(drop=True)
    rows = []
    for cfg, r in zip(configs, t.itertuples()):
        if r.status not in ("done", "cached"):
            continue
        rows.append({"frequency_hz": cfg["frequency_hz"], "ball_diameter_m": cfg["ball_diameter_m"],
                     "bvr": float(bvr(cfg["ball_diameter_m"])), "v_mean_m_s": r.v_mean_m_s,
                     "f_col_hz": r.f_col_hz, "e_kin_j": r.e_kin_j, "motion_mode": r.motion_mode,
                     "run_id": r.run_id})
    return pd.DataFrame(rows)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--validation-replicates", type=int, default=3,
                   help="start positions per validation case; the case's value is their mean "
                        "(one chaotic run scatters by ~1 %%, as much as the errors compared)")
    a = p.parse_args(argv)
    from analysis.sweep import run_sweep
    design = [{"frequency_hz": f, "ball_diameter_m": d, "seed": a.seed} for f, d in design_27()]
    valid = [{"frequency_hz": f, "ball_diameter_m": d, "seed": a.seed + k}
             for f, d in VALIDATION for k in range(a.validation_replicates)]
    res = run_sweep(design + valid, workers=a.workers)
    train = table_from_sweep(design, res.table.iloc[:len(design)])
    val_runs = table_from_sweep(valid, res.table.iloc[len(design):])
    val = (val_runs.groupby(["frequency_hz", "ball_diameter_m", "bvr"], as_index=False)
           .agg(v_mean_m_s=("v_mean_m_s", "mean"), v_mean_sd_m_s=("v_mean_m_s", "std"),
                f_col_hz=("f_col_hz", "mean"), e_kin_j=("e_kin_j", "mean"),
                n_replicates=("v_mean_m_s", "size"),
                motion_mode=("motion_mode", lambda m: "/".join(sorted(set(m))))))
    TABLES_DIR.mkdir(parents=True, exist_ok=True)
    train.to_csv(TABLES_DIR / "twin_table.csv", index=False, float_format="%.6g")
    val.to_csv(TABLES_DIR / "validation_table.csv", index=False, float_format="%.6g")
    # both together: the kinetics' Figure 9 (E_kin over f and d) and its 20 mm yield conditions
    pd.concat([train, val]).to_csv(TABLES_DIR / "all_runs.csv", index=False, float_format="%.6g")
    val_runs.to_csv(TABLES_DIR / "validation_runs.csv", index=False, float_format="%.6g")
    print(pd.concat([train, val]).to_string(index=False))
    print(res)
    return 0 if res.ok else 1


if __name__ == "__main__":
    sys.exit(main())
