"""The whole loop on a dataset of conditions never run, from an empty cache and then cached.

Default dataset: ``results/open_world/effects/eff_p01`` (6 frequency / ball pairs outside Table 3,
an arc motion of the jar hidden; the demo's blind dataset). The loop (:func:`analysis.loop.run_loop`,
defaults of ``python -m analysis.loop``: wave 0, the refinement waves, forward selection, the
twin reruns at the final point) runs in a fresh temporary runs folder with the scene in
``--frame`` (default 'auto': the jar frame where the effects allow it), so no run comes from
a cache or from the committed run table (it is not read: run_table points nowhere); then the
same loop once more on the now filled cache. Prints and writes
``results/bench/loop_cold.txt``: wall times, twin runs, the machine's load before the start.
The temporary runs folder is deleted at the end (``--keep-runs DIR`` keeps them there).

    python -m analysis.bench.loop_cold [--dataset D] [--workers 2] [--frame auto]
"""
from __future__ import annotations

import argparse
import math
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

from analysis.config import RESULTS_DIR

DEFAULT_DATASET = RESULTS_DIR / "open_world" / "effects" / "eff_p01"
OUT = RESULTS_DIR / "bench" / "loop_cold.txt"


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                epilog="example: python -m analysis.bench.loop_cold --dataset "
                                "results/open_world/effects/eff_p01 --workers 2 --frame auto")
    p.add_argument("--dataset", default=str(DEFAULT_DATASET),
                   help="dataset folder (default: %(default)s)")
    p.add_argument("--workers", type=int, default=2,
                   help="parallel twin runs [processes] (default %(default)s)")
    p.add_argument("--frame", choices=("lab", "jar", "auto"), default="auto",
                   help="frame of the twin's scene (default %(default)s: the jar frame where "
                   "the effects allow it)")
    p.add_argument("--keep-runs", default=None, metavar="DIR",
                   help="an empty or new folder that keeps the runs (default: a temporary "
                        "folder, deleted)")
    a = p.parse_args(argv)
    from analysis.loop import run_loop
    from analysis.measurements import load_dataset
    from analysis.twin_runs import TwinRuns, run_wall_s
    ds = load_dataset(a.dataset)
    if a.keep_runs:
        runs = Path(a.keep_runs)
        if runs.exists() and any(runs.iterdir()):
            print("analysis.bench.loop_cold: error: --keep-runs %s is not empty (the cache "
                  "must start empty)" % runs, file=sys.stderr)
            return 2
        runs.mkdir(parents=True, exist_ok=True)
    else:
        runs = Path(tempfile.mkdtemp(prefix="bench-loop-cold-"))
    load = os.getloadavg()[0]
    per_run_s = run_wall_s({"frame": a.frame})       # what the dry run would assume now
    lines = []
    try:
        times = []
        for label in ("empty cache", "cached"):
            t0 = time.perf_counter()
            twin = TwinRuns(workers=a.workers, runs_dir=runs, base_config={"frame": a.frame},
                            run_table=runs / "no-table.csv")
            res = run_loop(ds, twin=twin, base_config={"frame": a.frame},
                           log=lambda s: print(s, file=sys.stderr))
            wall = time.perf_counter() - t0
            times.append(wall)
            lines.append("%s: %.1f min, %d new twin runs, status %s"
                         % (label, wall / 60, res.info["new_runs"], res.status))
            print(lines[-1], flush=True)
            if label == "empty cache" and res.info["new_runs"]:
                est = math.ceil(res.info["new_runs"] / a.workers) * per_run_s
                lines.append("the dry run's estimate for these runs: %.1f min at %.1f s per run "
                             "(%+.0f %% of the measured)" % (est / 60, per_run_s,
                                                            100 * (est / wall - 1)))
                print(lines[-1], flush=True)
    finally:
        if not a.keep_runs:
            shutil.rmtree(runs, ignore_errors=True)
    head = ("the loop on %s (%d conditions), frame %s, %d worker(s); load average before the "
            "start %.2f on %d cores" % (ds.name, len(ds.conditions), a.frame, a.workers, load,
                                        os.cpu_count() or 0))
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text("\n".join([head] + lines) + "\n")
    print(head)
    print("wrote %s" % OUT)
    return 0


if __name__ == "__main__":
    sys.exit(main())
