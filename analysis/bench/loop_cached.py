"""The loop with every twin run already made: its analysis alone, without and with the emulator
fits of an earlier pass (:mod:`analysis.fit_cache`).

Default dataset: Table 3 (data/measurements/paper_table3, the demo's loop), whose runs are all in
the committed run table (data/twin_runs/runs.csv). Both passes read them from there into a fresh
temporary runs folder (budget 0: no twin run starts); the first finds no cached fit (the
committed fits are not read) and optimises every emulator's hyperparameters, the second replays
them. A third pass replays them with the analysis' independent fits (candidates, profile
intervals, interval ends) in 2 processes (``--workers 2``). Prints and writes
``results/bench/loop_cached.txt``: the wall times, the ratios, whether the first two passes wrote
the same tables (they must: a replayed fit is the same model) and how far the third pass's
numbers lie from the second's (0: the same numbers for any number of processes), the machine's
load before the start.

    python -m analysis.bench.loop_cached [--dataset D] [--option=--per-wave --option=6 ...]
"""
from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

from analysis.config import PAPER_TABLE3_DIR, RESULTS_DIR

OUT = RESULTS_DIR / "bench" / "loop_cached.txt"
#: the tables compared between the passes
TABLES = ("steps", "parameters", "staircase", "comparison", "diagnosis")
#: the passes: (label, --workers)
PASSES = (("no cached fit", "1"), ("fits cached", "1"), ("fits cached 2 processes", "2"))


def largest_difference(a: Path, b: Path) -> float:
    """The largest relative difference between the numbers of two loop folders' tables
    (:data:`TABLES`; inf when a table's shape, columns or text differ)."""
    import numpy as np
    import pandas as pd
    worst = 0.0
    for t in TABLES:
        x, y = pd.read_csv(a / (t + ".csv")), pd.read_csv(b / (t + ".csv"))
        if x.shape != y.shape or list(x.columns) != list(y.columns):
            return float("inf")
        num = x.select_dtypes("number").columns
        if not x.drop(columns=num).equals(y.drop(columns=num)):
            return float("inf")
        u, v = x[num].to_numpy(float), y[num].to_numpy(float)
        both = np.isfinite(u) & np.isfinite(v)
        if not np.array_equal(np.isfinite(u), np.isfinite(v)):
            return float("inf")
        d = np.abs(u - v)[both] / np.maximum(np.maximum(np.abs(u), np.abs(v))[both], 1e-300)
        worst = max(worst, float(d.max()) if d.size else 0.0)
    return worst


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                epilog="example: python -m analysis.bench.loop_cached --dataset "
                                "data/measurements/paper_table3")
    p.add_argument("--dataset", default=str(PAPER_TABLE3_DIR),
                   help="dataset folder whose loop's runs are all committed (default: %(default)s)")
    p.add_argument("--option", action="append", default=[], metavar="ARG",
                   help="an argument passed on to python -m analysis.loop (repeatable; write "
                        "--option=--per-wave --option=6)")
    a = p.parse_args(argv)
    from analysis import loop
    from analysis.twin_runs import BudgetError
    tmp = Path(tempfile.mkdtemp(prefix="bench-loop-cached-"))
    load = os.getloadavg()[0]
    lines, walls = [], []
    try:
        for label, workers in PASSES:
            out = tmp / label.replace(" ", "_")
            t0 = time.perf_counter()
            try:
                res, ds = loop.run_committed(["--dataset", a.dataset, "--out", str(out),
                                              "--workers", workers, *a.option], tmp / "runs",
                                             log=lambda s: print(s, file=sys.stderr),
                                             committed_fits=False)
            except BudgetError as exc:
                print("analysis.bench.loop_cached: not every run of the loop is committed: %s"
                      % exc, file=sys.stderr)
                return 3
            loop.write_loop(res, out, ds, protected=[a.dataset])
            walls.append(time.perf_counter() - t0)
            lines.append("%s: %.1f s" % (label, walls[-1]))
            print(lines[-1], flush=True)
        first, second, third = (tmp / l.replace(" ", "_") for l, _ in PASSES)
        same = all((first / (t + ".csv")).read_bytes() == (second / (t + ".csv")).read_bytes()
                   for t in TABLES)
        lines.append("ratio %.2f; the two passes' tables (%s) %s"
                     % (walls[1] / walls[0], ", ".join(TABLES),
                        "identical" if same else "DIFFER"))
        diff = largest_difference(second, third)
        lines.append("2 processes / 1: ratio %.2f; the largest relative difference of their "
                     "numbers %.1e" % (walls[2] / walls[1], diff))
        print("\n".join(lines[-2:]))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    head = ("the loop on %s from the committed runs, 1 core for the analysis (the third "
            "pass 2); load average "
            "before the start %.2f on %d cores" % (Path(a.dataset).name, load,
                                                    os.cpu_count() or 0))
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text("\n".join([head] + lines) + "\n")
    print(head)
    print("wrote %s" % OUT)
    return 0 if same and diff == 0.0 else 1


if __name__ == "__main__":
    sys.exit(main())
