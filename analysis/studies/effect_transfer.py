"""Can an effect's response measured at some conditions stand in for it at others?

The open model (:mod:`analysis.open_model`) measures every candidate effect at every condition
of a dataset: 24 of its 47 runs per condition. If an effect's change of an observable, relative
to the anchor at the same seeds, were a smooth function of frequency and ball size, the effect
responses could be measured at a few conditions spanning the dataset and predicted at the rest,
and the model's cost would grow by the anchor and base responses alone (23 runs) per added
condition.

This study reads the effect and anchor runs the loops committed (``model_runs.csv`` beside a
``loop.json`` that names each condition's frequency and ball; deduplicated by run id), groups
them by anchor, effect, level and condition, and computes per group the mean change from the
anchor's same seeds (v_mean and f_col relative to the anchor mean, the impact observables in their
own units) and its standard error from the seeds. Per anchor, effect, level and observable with
at least ``--min-conditions`` conditions it predicts each condition from the others
(leave-one-out) with a constant and with a plane in (frequency, ball diameter), and reports the
ratio of the leave-one-out rms error to the rms standard error of the measured changes: near 1,
the transfer is as good as measuring; well above 1, the effect's response has structure over
the conditions that a plane does not carry (a motion-mode change, a resonance).

Writes ``results/studies/effect_transfer/`` (``groups.csv``: the change per group;
``transfer.csv``: one row per anchor, effect, level and observable; ``README.md``).

Example::

    python -m analysis.studies.effect_transfer --min-conditions 6
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from analysis.config import RESULTS_DIR
from analysis.report import effect_transfer_page

OUT = RESULTS_DIR / "studies" / "effect_transfer"
#: observables whose change is taken relative to the anchor mean (the others absolute)
RELATIVE = ("v_mean_m_s", "v_mean_jar_m_s", "f_col_hz")


def collect(results_dir=RESULTS_DIR) -> pd.DataFrame:
    """Every committed anchor and effect run with its condition's frequency [Hz], ball
    diameter [mm] and its model's anchor (a JSON key), deduplicated by run id."""
    parts = []
    for lj in sorted(Path(results_dir).glob("**/loop.json")):
        mr = lj.parent / "model_runs.csv"
        if not mr.is_file() or "runs" in lj.parts:
            continue
        info = json.loads(lj.read_text())
        cond = {c["condition_id"]: (float(c["frequency_hz"]), float(c["ball_diameter_mm"]))
                for c in info["conditions"]}
        d = pd.read_csv(mr)
        d = d[d["role"].isin(["anchor", "effect"])].copy()
        if not len(d):
            continue
        d["frequency_hz"] = [cond[c][0] for c in d["condition_id"]]
        d["ball_diameter_mm"] = [cond[c][1] for c in d["condition_id"]]
        d["anchor_key"] = json.dumps(info["anchor"], sort_keys=True)
        d["frame"] = info.get("velocity_frame", "lab")
        parts.append(d)
    if not parts:
        return pd.DataFrame()
    d = pd.concat(parts, ignore_index=True).drop_duplicates("run_id")
    d["name"] = d["name"].fillna("")
    return d


def group_changes(runs, observables) -> pd.DataFrame:
    """Per anchor, effect, level and condition: the mean change of each observable from the
    anchor's same seeds and its standard error (seeds >= 2)."""
    rows = []
    key = ["anchor_key", "frequency_hz", "ball_diameter_mm"]
    anc = runs[runs["role"] == "anchor"]
    for (ak, f, d), a in anc.groupby(key):
        a = a.drop_duplicates("seed").set_index("seed")
        eff = runs[(runs["role"] == "effect") & (runs["anchor_key"] == ak)
                   & (runs["frequency_hz"] == f) & (runs["ball_diameter_mm"] == d)]
        for (name, val), g in eff.groupby(["name", "value"]):
            g = g.drop_duplicates("seed").set_index("seed")
            seeds = [s for s in g.index if s in a.index]
            if len(seeds) < 2:
                continue
            for o in observables:
                if o not in g.columns or o not in a.columns:
                    continue
                ch = g.loc[seeds, o].to_numpy(float) - a.loc[seeds, o].to_numpy(float)
                if o in RELATIVE:
                    ch = ch / float(a[o].mean())
                ch = ch[np.isfinite(ch)]
                if len(ch) < 2:
                    continue
                rows.append({"anchor_key": ak, "effect": name, "level": float(val),
                             "frequency_hz": f, "ball_diameter_mm": d, "observable": o,
                             "change": float(ch.mean()),
                             "change_se": float(ch.std(ddof=1) / np.sqrt(len(ch))),
                             "n_seeds": len(ch)})
    return pd.DataFrame(rows)


def loo_errors(g) -> dict:
    """Leave-one-out rms errors of a constant and of a plane in (f, d) over the conditions of
    one group, beside the rms standard error of the measured changes."""
    y = g["change"].to_numpy(float)
    se = g["change_se"].to_numpy(float)
    X = np.column_stack([np.ones(len(g)), (g["frequency_hz"] - 26.0) / 5.0,
                         (g["ball_diameter_mm"] - 18.5) / 3.0])
    out = {}
    for name, cols in (("constant", [0]), ("plane", [0, 1, 2])):
        e = []
        for i in range(len(y)):
            m = np.arange(len(y)) != i
            beta, *_ = np.linalg.lstsq(X[m][:, cols], y[m], rcond=None)
            e.append(y[i] - X[i, cols] @ beta)
        out["loo_rms_%s" % name] = float(np.sqrt(np.mean(np.square(e))))
    out["se_rms"] = float(np.sqrt(np.mean(np.square(se))))
    out["change_rms"] = float(np.sqrt(np.mean(np.square(y))))
    for name in ("constant", "plane"):
        out["ratio_%s" % name] = (out["loo_rms_%s" % name] / out["se_rms"]
                                  if out["se_rms"] > 0 else float("nan"))
    return out


def transfer_table(groups, min_conditions=6) -> pd.DataFrame:
    rows = []
    for (ak, eff, lev, o), g in groups.groupby(["anchor_key", "effect", "level", "observable"]):
        if len(g) < min_conditions:
            continue
        rows.append(dict(anchor_key=ak, effect=eff, level=lev, observable=o,
                         n_conditions=len(g), **loo_errors(g)))
    return pd.DataFrame(rows)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m analysis.studies.effect_transfer",
                                 description=__doc__.split("\n\n")[0],
                                 epilog="example: python -m analysis.studies.effect_transfer "
                                        "--min-conditions 6")
    ap.add_argument("--min-conditions", type=int, default=6,
                    help="[conditions] fewest conditions of a group to score (default 6)")
    ap.add_argument("--out", default=str(OUT), help="output folder (default %(default)s)")
    a = ap.parse_args(argv)
    if a.min_conditions < 4:
        print("effect_transfer: error: --min-conditions must be >= 4 (a plane has 3 "
              "coefficients), got %d" % a.min_conditions, file=sys.stderr)
        return 2
    from analysis.atomic_dir import output_dir
    from analysis.flights import FLIGHT_OBSERVABLES
    runs = collect()
    if not len(runs):
        print("effect_transfer: error: no committed model_runs.csv with a loop.json under %s"
              % RESULTS_DIR, file=sys.stderr)
        return 1
    obs = ["v_mean_m_s", "f_col_hz", *FLIGHT_OBSERVABLES]
    groups = group_changes(runs, obs)
    tab = transfer_table(groups, a.min_conditions)
    summ = (tab.groupby(["effect", "observable"])[["ratio_constant", "ratio_plane",
                                                    "n_conditions"]].median()
            .reset_index() if len(tab) else tab)
    out = Path(a.out)
    with output_dir(out) as tmp:
        groups.to_csv(tmp / "groups.csv", index=False)
        tab.to_csv(tmp / "transfer.csv", index=False)
        text = effect_transfer_page(len(runs), runs["anchor_key"].nunique(), summ)
        (tmp / "README.md").write_text(text)
    print("\n".join(text.split("\n")[:-1][-len(summ) - 2:]) if len(summ)
          else "no group with enough conditions")
    print("wrote %s" % out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
