"""Twin runs for the surrogates and the kinetics (paper Sections 4-5).

The paper's design: 9 frequencies 20-30 Hz x 3 balls (analysis.surrogate.design_27: 14.3, 17.5,
20.6 mm), plus the Table 5 validation cases (10 mm ball radius at 25, 27.5 and 30 Hz), which are
also the 20 mm ball of the yield experiments. The twin is chaotic (one run's v_mean scatters by
~1 % between start positions, as much as the surrogate errors compared), so every design point
and every validation case is the mean of ``--replicates`` / ``--validation-replicates`` seeded
runs (seeds seed, seed + 1, ...; the paper ran one per point). Writes into results/twin_tables/:

* twin_runs.csv, validation_runs.csv - one row per run (frequency_hz, ball_diameter_m, bvr, seed,
  v_mean_m_s, f_col_hz, e_kin_j, motion_mode, run_id);
* twin_table.csv, validation_table.csv - one row per point, the mean of its runs
  (analysis.surrogate.average_replicates: + n_replicates, v_mean_sd_m_s, f_col_sd_hz), the
  tables `python -m analysis.surrogate --twin-table/--validation-table` read;
* all_runs.csv - every run of both, which `python -m analysis.kinetics --twin-table` averages.

    python -m analysis.studies.surrogate_runs [--workers 2] [--seed 0] [--replicates 3]
"""
import argparse
import sys

import pandas as pd

from analysis.config import RESULTS_DIR

from analysis.surrogate import average_replicates, bvr, design_27

TABLES_DIR = RESULTS_DIR / "twin_tables"  # apart from results/surrogate/, which the CLI rewrites

VALIDATION = [(25.0, 0.020), (27.5, 0.020), (30.0, 0.020)]


def table_from_sweep(configs, sweep_table):
    t = sweep_table.reset_index(drop=True)
    rows = []
    for cfg, r in zip(configs, t.itertuples()):
        if r.status not in ("done", "cached"):
            continue
        rows.append({"frequency_hz": cfg["frequency_hz"], "ball_diameter_m": cfg["ball_diameter_m"],
                     "bvr": float(bvr(cfg["ball_diameter_m"])), "seed": cfg["seed"],
                     "v_mean_m_s": r.v_mean_m_s,
                     "f_col_hz": r.f_col_hz, "e_kin_j": r.e_kin_j, "motion_mode": r.motion_mode,
                     "run_id": r.run_id})
    return pd.DataFrame(rows)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                epilog="example: python -m analysis.studies.surrogate_runs "
                                "--workers 2 --seed 0 --replicates 3")
    p.add_argument("--workers", type=int, default=2,
                   help="parallel twin runs [processes] (default %(default)s)")
    p.add_argument("--seed", type=int, default=0,
                   help="first seed; replicates use seed + k [-] (default %(default)s)")
    p.add_argument("--replicates", type=int, default=3,
                   help="seeded runs (start positions) per design point; the point's value is "
                        "their mean [seeds] (default %(default)s)")
    p.add_argument("--validation-replicates", type=int, default=3,
                   help="start positions per validation case; the case's value is their mean "
                        "(one chaotic run scatters by ~1 %%, as much as the errors compared) "
                        "[seeds] (default %(default)s)")
    a = p.parse_args(argv)
    if a.replicates < 1 or a.validation_replicates < 1:
        p.error("--replicates and --validation-replicates must be >= 1")
    from analysis.sweep import run_sweep
    # point-major order (all seeds of a point together); points in design_27() order, so the
    # averaged table - and the surrogate's seeded 70/30 split over its rows - keep that order
    design = [{"frequency_hz": f, "ball_diameter_m": d, "seed": a.seed + k}
              for f, d in design_27() for k in range(a.replicates)]
    valid = [{"frequency_hz": f, "ball_diameter_m": d, "seed": a.seed + k}
             for f, d in VALIDATION for k in range(a.validation_replicates)]
    res = run_sweep(design + valid, workers=a.workers)
    train_runs = table_from_sweep(design, res.table.iloc[:len(design)])
    val_runs = table_from_sweep(valid, res.table.iloc[len(design):])
    train, val = average_replicates(train_runs), average_replicates(val_runs)
    TABLES_DIR.mkdir(parents=True, exist_ok=True)
    train_runs.to_csv(TABLES_DIR / "twin_runs.csv", index=False, float_format="%.6g")
    train.to_csv(TABLES_DIR / "twin_table.csv", index=False, float_format="%.6g")
    val_runs.to_csv(TABLES_DIR / "validation_runs.csv", index=False, float_format="%.6g")
    val.to_csv(TABLES_DIR / "validation_table.csv", index=False, float_format="%.6g")
    # every run of both: the kinetics' Figure 9 (E_kin over f and d) and its 20 mm yield
    # conditions; analysis.kinetics averages the replicates itself
    pd.concat([train_runs, val_runs]).to_csv(TABLES_DIR / "all_runs.csv", index=False,
                                             float_format="%.6g")
    print(pd.concat([train, val]).drop(columns="run_id").to_string(index=False))
    print(res)
    return 0 if res.ok else 1


if __name__ == "__main__":
    sys.exit(main())
