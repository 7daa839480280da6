"""What each apparatus and contact-law choice does to the 8 Table-3 speeds, one at a time.

At the paper's contact parameters (C_R 0.11, SF 0.7, RF 0.5) the twin is run at the 8 conditions
of Table 3 (2 start positions each) with one choice changed from the default apparatus (D 28 mm,
fillet 5 mm, 25 mL, A 13.5 mm, straight stroke) and contact law (YADE's rolling spring,
restitution compensated for the time step). Per variant: the mean v/f of each ball, the size
split (17.5 mm over 20.6 mm), and the change of v/f from 22.5 to 30 Hz - beside the same figures
of the paper's own EDEM column. The runs are the jar frame's except for the arc (lab frame);
cached by run id. Writes ``results/apparatus/screen.csv`` and ``README.md`` (the screen, and
links to the identification and calibration pages of ``make apparatus`` where they exist).

    python -m analysis.studies.apparatus_screen [--workers 2] [--seeds 2]
"""
from __future__ import annotations

import argparse
import sys

import numpy as np
import pandas as pd

from analysis.config import PAPER_TABLE3_DIR, RESULTS_DIR
from analysis.report import apparatus_screen_page
from analysis.run_configs import condition_runs

OUT = RESULTS_DIR / "apparatus"
PAPER_CONTACT = {"restitution": 0.11, "static_friction": 0.7, "rolling_friction": 0.5}
#: one change each from the default twin (name -> run config keys)
VARIANTS = {
    "default": {},
    "no restitution compensation": {"restitution_compensation": False},
    "rolling constant_torque (EDEM)": {"rolling_model": "constant_torque"},
    "A 12 mm": {"amplitude_m": 0.012},
    "A 15 mm": {"amplitude_m": 0.015},
    "D 24 mm (25 mL)": {"jar_inner_diameter_m": 0.024},
    "D 32 mm (25 mL)": {"jar_inner_diameter_m": 0.032},
    "L 50 mm (D 28 mm, 29 mL)": {"jar_inner_diameter_m": 0.028, "jar_inner_length_m": 0.050},
    "fillet 10 mm (25 mL)": {"jar_inner_diameter_m": 0.028, "jar_fillet_radius_m": 0.010},
    "arc, pivot below (c +10 1/m)": {"frame": "lab", "effects": {
        "arc_motion": {"curvature_1_m": 10.0, "tilt": 0.0}}},
    "arc, pivot above (c -10 1/m)": {"frame": "lab", "effects": {
        "arc_motion": {"curvature_1_m": -10.0, "tilt": 0.0}}},
}


def conditions():
    from analysis.demo import measured_table
    t = measured_table(PAPER_TABLE3_DIR)
    return t[["condition_id", "frequency_hz", "ball_diameter_mm", "v_mean_m_s",
              "v_mean_dem_paper_m_s"]]


def configs(cond, seeds):
    """(run configs, keys: variant, condition_id, seed) of every variant x condition x seed:
    the jar frame, the paper's contact parameters, the variant's change over both; the stroke
    is the variant's (a stated ``amplitude_mm`` is not applied)."""
    out, keys = [], []
    for name, change in VARIANTS.items():
        base = {"frame": "jar", **PAPER_CONTACT, **change}
        for r in condition_runs(cond, range(seeds), base_config=base, stated_stroke=False):
            out.append(r.config)
            keys.append({"variant": name, "condition_id": r.condition_id, "seed": r.seed})
    return out, pd.DataFrame(keys)


def shape_figures(vf: pd.Series, d: pd.Series, f: pd.Series) -> dict:
    """Mean v/f per ball [mm], size split and 22.5 -> 30 Hz change of v/f [%]."""
    t = pd.DataFrame({"vf": vf.to_numpy(float), "d": d.to_numpy(float),
                      "f": f.to_numpy(float)}).groupby(["d", "f"]).vf.mean()
    small, large = t.loc[17.5], t.loc[20.6]
    return {"vf_17_5_mm": small.mean(), "vf_20_6_mm": large.mean(),
            "split_pct": 100 * (small.mean() / large.mean() - 1),
            "trend_17_5_pct": 100 * (small.loc[30.0] / small.loc[22.5] - 1),
            "trend_20_6_pct": 100 * (large.loc[30.0] / large.loc[22.5] - 1)}


def summarize(keys: pd.DataFrame, runs: pd.DataFrame, cond: pd.DataFrame) -> pd.DataFrame:
    twin = runs.reset_index(drop=True)[["status", "v_mean_m_s", "motion_mode"]].rename(
        columns={"v_mean_m_s": "v_twin_m_s"})
    t = pd.concat([keys.reset_index(drop=True), twin], axis=1).merge(cond, on="condition_id")
    rows = [{"variant": "paper's EDEM column", **shape_figures(
        1e3 * cond["v_mean_dem_paper_m_s"] / cond["frequency_hz"], cond["ball_diameter_mm"],
        cond["frequency_hz"]), "runs": np.nan, "not_end_to_end": np.nan,
        "mean_abs_diff_dem_pct": 0.0}]
    for name, g in t.groupby("variant", sort=False):
        ok = g[g["status"].isin(["done", "cached"]) & (g["motion_mode"] == "end_to_end")]
        row = {"variant": name, **shape_figures(1e3 * ok["v_twin_m_s"] / ok["frequency_hz"],
                                                ok["ball_diameter_mm"], ok["frequency_hz"])}
        m = ok.groupby("condition_id").agg(v=("v_twin_m_s", "mean"),
                                           dem=("v_mean_dem_paper_m_s", "first"))
        row["mean_abs_diff_dem_pct"] = float((100 * (m.v / m.dem - 1)).abs().mean())
        row["runs"] = len(g)
        row["not_end_to_end"] = int((g["motion_mode"] != "end_to_end").sum())
        rows.append(row)
    order = list(VARIANTS)
    out = pd.DataFrame(rows)
    out["_o"] = [order.index(v) if v in order else -1 for v in out["variant"]]
    return out.sort_values("_o").drop(columns="_o").reset_index(drop=True)


def write(summary: pd.DataFrame, seeds: int, out=OUT):
    out.mkdir(parents=True, exist_ok=True)
    summary.to_csv(out / "screen.csv", index=False, float_format="%.4g")
    (out / "README.md").write_text(apparatus_screen_page(summary, seeds, out))


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                epilog="example: python -m analysis.studies.apparatus_screen "
                                "--workers 2 --seeds 2")
    p.add_argument("--workers", type=int, default=2,
                   help="parallel twin runs [processes] (default %(default)s)")
    p.add_argument("--seeds", type=int, default=2,
                   help="start positions per condition and variant [seeds] "
                   "(default %(default)s)")
    a = p.parse_args(argv)
    from analysis.sweep import run_sweep
    cond = conditions()
    cfgs, keys = configs(cond, a.seeds)
    res = run_sweep(cfgs, workers=a.workers)
    summary = summarize(keys, res.table, cond)
    write(summary, a.seeds)
    print(summary.to_string(index=False, float_format=lambda x: "%.2f" % x))
    return 0 if res.ok else 1


if __name__ == "__main__":
    sys.exit(main())
