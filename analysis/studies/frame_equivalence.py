"""The jar-frame scene against the lab-frame scene at the paper's 8 conditions.

The lab-frame runs are Table 3's 8 conditions at the reference parameters (the Table-3
calibration's posterior mean, :func:`analysis.parameter_space.reference_parameters`), ``--seeds``
start positions each; the same configs with ``frame: 'jar'`` are run (both cached by run id)
and compared per condition: v_mean, f_col, the impact observables of
:mod:`analysis.flights` (v_in, e_app, impact phase) and the motion modes, each as the
difference of the 3-seed means over its standard error (the two frames' replicate scatters
combined). The wall time per run of each frame is read from the recordings' meta.json where
they exist on this machine. Writes ``results/studies/frame_equivalence.csv`` and ``.md``
(``--out`` is their prefix; both follow the project's file rule before any run - never a file
this study did not write, never its input - and are written atomically).

    python -m analysis.studies.frame_equivalence [--workers 2]
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from analysis.config import PAPER_TABLE3_DIR, RESULTS_DIR, RUNS_DIR
from analysis.report import frame_equivalence_page

OUT = RESULTS_DIR / "studies" / "frame_equivalence"
COMPARED = ("v_mean_m_s", "f_col_hz", "v_in_m_s", "e_app", "impact_phase_rad")
#: the first columns of the table and the title of the page (how the study knows its own files)
TABLE_HEAD = ("condition_id", "n_lab", "n_jar", "modes_lab", "modes_jar")
PAGE_TITLE = "# Jar frame against lab frame"


def check_outputs(out, lab_dir=PAPER_TABLE3_DIR):
    """``out``.csv and ``out``.md under the file rule (raises
    :class:`analysis.atomic_dir.OutputError`); returns the two paths."""
    from analysis.atomic_dir import check_out_file, own_csv, own_text
    out = Path(out)
    csv = check_out_file(out.with_suffix(".csv"), [lab_dir],
                         is_own=own_csv(TABLE_HEAD, prefix=True), flag="--out")
    md = check_out_file(out.with_suffix(".md"), [lab_dir], is_own=own_text(PAGE_TITLE),
                        flag="--out")
    return csv, md


def lab_configs(seeds=3, dataset_dir=PAPER_TABLE3_DIR):
    """(table condition_id, seed; their lab-frame run configs): the dataset's conditions at the
    reference parameters, seeds 0 .. ``seeds`` - 1, conditions outer."""
    from analysis.measurements import load_dataset
    from analysis.parameter_space import reference_parameters
    from analysis.run_configs import condition_runs
    runs = condition_runs(load_dataset(dataset_dir).conditions, seeds=range(int(seeds)),
                          theta=reference_parameters(), base_config={"frame": "lab"})
    table = pd.DataFrame({"condition_id": [r.condition_id for r in runs],
                          "seed": [r.seed for r in runs]})
    return table, [r.config for r in runs]


def observed(table, sweep_table):
    """``table`` with each run's run_id, v_mean, f_col, motion mode and impact observables."""
    from analysis.twin_runs import run_flights
    t = sweep_table.reset_index(drop=True)
    out = table.copy()
    out["run_id"] = t["run_id"].to_numpy()
    for c in ("v_mean_m_s", "f_col_hz", "motion_mode"):
        out[c] = t[c].to_numpy()
    fl = run_flights(list(out["run_id"]))
    for c in ("v_in_m_s", "e_app", "impact_phase_rad"):
        out[c] = fl[c].to_numpy(float)
    return out


def compare(lab: pd.DataFrame, jar: pd.DataFrame) -> pd.DataFrame:
    """Per condition: the two frames' 3-seed means and z = difference / se, the se from the
    replicate variance pooled over every condition and both frames (32 degrees of freedom:
    a 3-seed sd of its own would make z a t with 4 dof, whose mean square is 2, not 1)."""
    both = pd.concat([lab.assign(frame="lab"), jar.assign(frame="jar")], ignore_index=True)
    pooled = {}
    for c in COMPARED:
        g = both.groupby(["condition_id", "frame"])[c]
        dof = (g.count() - 1).clip(lower=0)
        pooled[c] = float((g.var(ddof=1).fillna(0.0) * dof).sum() / max(dof.sum(), 1))
    rows = []
    for cid, g in lab.groupby("condition_id", sort=False):
        h = jar[jar["condition_id"] == cid]
        row = {"condition_id": cid, "n_lab": len(g), "n_jar": len(h),
               "modes_lab": "/".join(sorted(g["motion_mode"].astype(str))),
               "modes_jar": "/".join(sorted(h["motion_mode"].astype(str)))}
        for c in COMPARED:
            a, b = g[c].dropna().to_numpy(float), h[c].dropna().to_numpy(float)
            row[c + "_lab"] = a.mean() if len(a) else np.nan
            row[c + "_jar"] = b.mean() if len(b) else np.nan
            se = math.sqrt(pooled[c] * (1.0 / max(len(a), 1) + 1.0 / max(len(b), 1)))
            row[c + "_z"] = (row[c + "_jar"] - row[c + "_lab"]) / se if se > 0 else np.nan
            row[c + "_run_sd"] = math.sqrt(pooled[c])
        rows.append(row)
    return pd.DataFrame(rows)


def wall_times(ids, runs_dir=RUNS_DIR):
    out = []
    for r in ids:
        f = Path(runs_dir) / str(r) / "meta.json"
        if f.is_file():
            out.append(float(json.loads(f.read_text())["wall_s"]))
    return out


def main(argv=None):
    from analysis.sweep import run_sweep
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 epilog="example: python -m analysis.studies.frame_equivalence "
                                 "--workers 2 --out results/studies/frame_equivalence")
    ap.add_argument("--workers", type=int, default=2,
                    help="parallel twin runs [processes] (default %(default)s)")
    ap.add_argument("--out", default=str(OUT), help="output prefix (.csv and .md are added)")
    ap.add_argument("--seeds", type=int, default=3,
                    help="start positions per condition and frame [seeds] (default "
                    "%(default)s)")
    a = ap.parse_args(argv)
    from analysis.atomic_dir import OutputError, atomic_file
    try:
        check_outputs(a.out)
    except OutputError as exc:
        print("frame_equivalence: error: %s" % exc, file=sys.stderr)
        return 2
    lab, cfgs = lab_configs(a.seeds)
    res = run_sweep(cfgs + [dict(c, frame="jar") for c in cfgs], workers=a.workers)
    if not res.ok:
        print("frame_equivalence: error: %d twin runs failed" % res.n_failed, file=sys.stderr)
        return 1
    n = len(cfgs)
    jar = observed(lab, res.table.iloc[n:])
    lab = observed(lab, res.table.iloc[:n])
    tab = compare(lab, jar)
    wl, wj = wall_times(lab["run_id"]), wall_times(jar["run_id"])
    n_seeds = int(lab.groupby("condition_id").size().min())
    text = frame_equivalence_page(tab, wl, wj, n_seeds, COMPARED)
    try:
        csv, md = check_outputs(a.out)      # again: they may have appeared during the runs
    except OutputError as exc:
        print("frame_equivalence: error: %s" % exc, file=sys.stderr)
        return 2
    with atomic_file(csv) as tmp:
        tab.to_csv(tmp, index=False)
    with atomic_file(md) as tmp:
        tmp.write_text(text)
    print("\n".join(text.split("\n")[:5]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
