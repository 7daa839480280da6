"""The apparatus identified from a calibration: posterior, residual per condition, uniqueness.

Reads a calibration folder written by ``python -m analysis.calibrate`` with apparatus
parameters free (``--free``), e.g. ``results/apparatus/identify_paper_dem`` - the jar and stroke
that make the twin, at the paper's contact parameters, reproduce the paper's own EDEM speeds
(``data/measurements/paper_dem_table3``) - and writes beside it ``README.md`` (the study page)
and ``posterior_correlation.csv``; with ``--profile FILE`` also the identified apparatus as a
run-config fragment (JSON ``config``: the fixed keys of the calibration's runs and the posterior
means rounded to 3 significant digits), the one place the demo reads "the twin of the paper's
mill" from.

    python -m analysis.studies.apparatus_identification [--cal DIR] [--profile FILE]
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import pandas as pd

from analysis.config import RESULTS_DIR
from analysis.report import apparatus_identification_page

CAL = RESULTS_DIR / "apparatus" / "identify_paper_dem"
#: goals (issue "a twin of the real mill"): twin vs the target column - the paper's DEM column
#: at its contact parameters (identification), the measured column once calibrated (the paper's
#: own DEM reaches 0.93 % / 4.84 % there)
GOAL_MEAN_PCT, GOAL_MAX_PCT = 1.5, 3.0
GOAL_MEASURED_MEAN_PCT, GOAL_MEASURED_MAX_PCT = 0.9, 3.0


def load(cal_dir):
    cal_dir = Path(cal_dir)
    params = pd.read_csv(cal_dir / "parameters.csv", index_col=0)
    comp = pd.read_csv(cal_dir / "table3_comparison.csv")
    samples = pd.read_csv(cal_dir / "posterior_samples.csv")
    summary = json.loads((cal_dir / "summary.json").read_text())
    design = pd.read_csv(cal_dir / "design_runs.csv")
    return params, comp, samples, summary, design


def residuals(comp: pd.DataFrame) -> pd.DataFrame:
    """Per condition: target v, the twin's mean at the posterior mean, the difference [%]."""
    t = comp[["condition_id", "frequency_hz", "ball_diameter_mm", "v_mean_measured_m_s",
              "v_mean_twin_m_s", "v_mean_twin_sd_m_s"]].copy()
    t["diff_pct"] = 100 * (t["v_mean_twin_m_s"] / t["v_mean_measured_m_s"] - 1)
    return t


def shape(t: pd.DataFrame, col: str) -> dict:
    from analysis.studies.apparatus_screen import shape_figures
    return shape_figures(1e3 * t[col] / t["frequency_hz"], t["ball_diameter_mm"],
                         t["frequency_hz"])


def write(cal_dir, params, comp, samples, summary, base, profile=None):
    cal_dir = Path(cal_dir)
    names = list(params.index)
    corr = samples[names].corr()
    corr.to_csv(cal_dir / "posterior_correlation.csv", float_format="%.3f")
    t = residuals(comp)
    ok = t["diff_pct"].notna()
    mean_abs, max_abs = t.loc[ok, "diff_pct"].abs().mean(), t.loc[ok, "diff_pct"].abs().max()
    tw, tg = shape(t[ok], "v_mean_twin_m_s"), shape(t[ok], "v_mean_measured_m_s")
    g_mean, g_max = ((GOAL_MEAN_PCT, GOAL_MAX_PCT) if "dem" in str(summary.get("dataset", ""))
                     else (GOAL_MEASURED_MEAN_PCT, GOAL_MEASURED_MAX_PCT))
    (cal_dir / "README.md").write_text(apparatus_identification_page(
        cal_dir, summary, base, params, corr, t, mean_abs, max_abs, tw, tg, g_mean, g_max))
    if profile:
        fitted = {k: float("%.3g" % params.loc[k, "mean"]) for k in names}
        prof = {"source": str(cal_dir), "dataset": summary.get("dataset", ""),
                "config": dict(base, **fitted), "free": names,
                "posterior_sd": {k: float("%.2g" % params.loc[k, "sd"]) for k in names},
                "mean_abs_diff_pct": round(float(mean_abs), 3),
                "max_abs_diff_pct": round(float(max_abs), 3)}
        Path(profile).parent.mkdir(parents=True, exist_ok=True)
        Path(profile).write_text(json.dumps(prof, indent=1) + "\n")
    return mean_abs, max_abs


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                epilog="example: python -m "
                                "analysis.studies.apparatus_identification "
                                "--cal results/apparatus/identify_paper_dem --profile "
                                "results/apparatus/paper_apparatus.json")
    p.add_argument("--cal", default=str(CAL), help="calibration folder")
    p.add_argument("--base", default=None,
                   help="JSON of the run-config keys the calibration held fixed (its --set; "
                   "default: summary.json's base_config)")
    p.add_argument("--profile", default=None, help="write the identified apparatus here (JSON)")
    a = p.parse_args(argv)
    try:
        params, comp, samples, summary, design = load(a.cal)
        base = json.loads(a.base) if a.base else summary.get("base_config", {})
    except (OSError, ValueError) as exc:
        print("apparatus_identification: error: %s" % exc, file=sys.stderr)
        return 2
    m, x = write(a.cal, params, comp, samples, summary, base, a.profile)
    print("twin at the posterior mean vs %s: mean |diff| %.2f %%, max %.2f %%"
          % (summary.get("dataset", ""), m, x))
    return 0


if __name__ == "__main__":
    sys.exit(main())
