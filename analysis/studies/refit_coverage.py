"""The twin-corrected refits on the open-world loop's own answers: do they bring the fitted
strengths' intervals onto the truth?

For every dataset of ``--loops`` (loop outputs of :mod:`analysis.open_suite`) where the loop
added an effect, the loop's model is rebuilt from its cached runs, its final joint fit redone,
and :func:`analysis.loop.twin_corrected_refits` run on it: twin reruns at the fitted point
(``--rerun-replicates`` seeds per condition, fresh seeds) and refits of the model shifted onto
them. Each dataset's result is written to ``<out>/<dataset>.json`` when it is done (a killed
study resumes there); ``summary.csv`` and ``README.md`` hold the strengths before and after
with the coverage of their 95 % intervals. ``--out`` follows the project's folder rule before
any run (:func:`analysis.atomic_dir.check_out_dir`: never an input, never a folder holding
files this study did not write); every file is written atomically and the folder is marked.

Example::

    python -m analysis.studies.refit_coverage
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from analysis.config import RESULTS_DIR
from analysis.report import refit_coverage_page

LOOPS_DIR = RESULTS_DIR / "open_world" / "loop_effects"
DATASETS_DIR = RESULTS_DIR / "open_world" / "effects"
OUT_DIR = RESULTS_DIR / "open_world" / "refits"


def refit_one(name, loops_dir, datasets_dir, *, rerun_replicates=3, max_refits=2, workers=2,
              log=print) -> dict:
    from analysis.loop import fit_observations, joint_fit, rerun_table, twin_corrected_refits
    from analysis.measurements import load_dataset
    from analysis.open_model import OpenTwinModel
    from analysis.open_suite import truth_strengths
    from analysis.twin_model import dataset_observations, yield_times_of
    info = json.loads((loops_dir / name / "loop.json").read_text())
    par = pd.read_csv(loops_dir / name / "parameters.csv")
    truth = json.loads((datasets_dir / "truth" / ("%s.truth.json" % name)).read_text())
    ds = load_dataset(datasets_dir / name)
    obs0, fl_ids, _ = dataset_observations(ds, True)
    m = OpenTwinModel(ds.conditions, yield_times_of(ds), theta_ref=info["anchor"],
                      flight_conditions=fl_ids, progress=False, workers=workers)
    m.fit("all")
    obs = fit_observations(obs0, m)
    theta = {r.name: float(r.value) for r in par.itertuples() if r.role == "base"}
    added = {r.name: float(r.value) for r in par.itertuples() if r.role == "effect"}
    final = joint_fit(m, obs, theta, added)
    before = {k: (float(final.params[k]), float(final.stderr[k])) for k in added}
    theta = {k: float(final.params[k]) for k in theta}
    added = {k: float(final.params[k]) for k in added}

    def rerun_fn(th, eff):
        pred, se, rm = rerun_table(ds, dict(m.theta_ref, **th), eff,
                                   replicates=rerun_replicates, seed0=100,
                                   sweep_kw=dict(workers=workers, progress=False),
                                   base_config=None, flight_ids=fl_ids)
        return pred, se, rm.runs_

    tc = twin_corrected_refits(m, obs, theta, added, final, rerun_fn, max_refits=max_refits,
                               log=log)
    true = truth_strengths(truth)
    out = {"dataset": name, "truth": true, "before": before,
           "after": {k: (float(tc["final"].params[k]), float(tc["final"].stderr[k]))
                     for k in added},
           "refits": tc["refits"], "reruns": int(tc["rerun"]["runs"]["rerun"].max()),
           "chi2_dof_model": float(final.chi2_dof),
           "chi2_dof_corrected": float(tc["final"].chi2_dof),
           "chi2_dof_rerun": float(tc["rerun"]["chi2"] / max(tc["rerun"]["dof"], 1))}
    return out


def summary_rows(results) -> pd.DataFrame:
    rows = []
    for r in results:
        for k, s in r["truth"].items():
            if k not in r["before"]:
                continue
            b, bse = r["before"][k]
            a, ase = r["after"][k]
            rows.append({"dataset": r["dataset"], "effect": k, "truth": s,
                         "before": b, "before_se": bse, "z_before": (b - s) / bse,
                         "after": a, "after_se": ase, "z_after": (a - s) / ase,
                         "covered_before": abs(b - s) <= 1.96 * bse,
                         "covered_after": abs(a - s) <= 1.96 * ase, "reruns": r["reruns"],
                         "chi2_dof_model": r["chi2_dof_model"],
                         "chi2_dof_corrected": r["chi2_dof_corrected"],
                         "chi2_dof_rerun": r["chi2_dof_rerun"]})
    return pd.DataFrame(rows)


def check_out(out, loops, datasets, names=()):
    """The folder rule for ``--out`` (raises :class:`analysis.atomic_dir.OutputError`): an
    unmarked folder is taken as this study's own when it holds only its files."""
    from analysis.atomic_dir import check_out_dir
    own = ["%s.json" % n for n in names] + ["summary.csv", "README.md"]
    return check_out_dir(out, [loops, datasets], own_names=own)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 epilog="example: python -m analysis.studies.refit_coverage "
                                 "--loops results/open_world/loop_effects --datasets "
                                 "results/open_world/effects --out results/open_world/refits")
    ap.add_argument("--loops", default=str(LOOPS_DIR), help="the suite's loop outputs")
    ap.add_argument("--datasets", default=str(DATASETS_DIR), help="their datasets")
    ap.add_argument("--out", default=str(OUT_DIR), help="output folder")
    ap.add_argument("--only", action="append", help="only this dataset (repeatable)")
    ap.add_argument("--rerun-replicates", type=int, default=3,
                    help="twin reruns per condition at the fitted point, fresh seeds [seeds] "
                    "(default %(default)s)")
    ap.add_argument("--max-refits", type=int, default=2,
                    help="most twin-corrected refits per dataset [refits] "
                    "(default %(default)s)")
    ap.add_argument("--workers", type=int, default=2,
                    help="parallel twin runs [processes] (default %(default)s)")
    a = ap.parse_args(argv)
    from analysis.atomic_dir import MARKER, OutputError, atomic_file
    loops, dsets, out = Path(a.loops), Path(a.datasets), Path(a.out)
    try:
        if not loops.is_dir():
            raise OutputError("--loops %s is not a folder of loop outputs" % a.loops)
        names = sorted(p.name for p in loops.iterdir() if (p / "loop.json").is_file())
        check_out(out, loops, dsets, names)
    except OutputError as exc:
        print("refit_coverage: error: %s" % exc, file=sys.stderr)
        return 2
    out.mkdir(parents=True, exist_ok=True)
    if not (out / MARKER).exists():
        (out / MARKER).write_text("written by the mill twin project; a rerun may replace "
                                  "this folder\n")
    results = []
    for name in names:
        if a.only and name not in a.only:
            continue
        if not json.loads((loops / name / "loop.json").read_text()).get("effects"):
            continue
        f = out / ("%s.json" % name)
        if not f.exists():
            print("== %s" % name, file=sys.stderr, flush=True)
            r = refit_one(name, loops, dsets, rerun_replicates=a.rerun_replicates,
                          max_refits=a.max_refits, workers=a.workers,
                          log=lambda s: print(s, file=sys.stderr, flush=True))
            with atomic_file(f) as tmp:
                tmp.write_text(json.dumps(r, indent=1))
        results.append(json.loads(f.read_text()))
    t = summary_rows(results)
    with atomic_file(out / "summary.csv") as tmp:
        t.to_csv(tmp, index=False)
    text = refit_coverage_page(t)
    with atomic_file(out / "README.md") as tmp:
        tmp.write_text(text)
    print("\n".join(text.split("\n")[:3]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
