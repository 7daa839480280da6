"""Sweep throughput: runs/hour with 1 and 2 workers and the speed-up between them.

Default runner: the real twin (analysis.twin.run_twin) with a short record_s when ``yade`` is on
PATH; otherwise (or with ``--fake``) a CPU-bound FAKE runner (analysis.fake_twin.run_fake_twin
burning ``--cpu-s`` seconds of CPU per run), and the output says so. Every timed run is new
(fresh temporary runs folder, distinct seeds), so nothing comes from the cache.

    python -m analysis.bench.sweep                 # real twin if yade exists
    python -m analysis.bench.sweep --fake --n-runs 8 --cpu-s 2
    python -m analysis.bench.sweep --runner pkg.mod:fn --runner-kw key=value
"""
from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time

from analysis.sweep import SweepInputError, parse_key_value, run_sweep


def _configs(n, record_s, offset):
    cfgs = []
    for i in range(n):
        c = {"seed": offset + i}
        if record_s is not None:
            c["record_s"] = record_s
        cfgs.append(c)
    return cfgs


def bench(runner, runner_kwargs, n_runs, record_s, workers_list=(1, 2)):
    """Time ``n_runs`` fresh runs per worker count; return a list of result dicts."""
    out = []
    for k, w in enumerate(workers_list):
        tmp = tempfile.mkdtemp(prefix="bench-sweep-")
        try:
            cfgs = _configs(n_runs, record_s, offset=1000 * (k + 1))
            t0 = time.perf_counter()
            res = run_sweep(cfgs, runner=runner, runner_kwargs=runner_kwargs, workers=w,
                            backend="local", runs_dir=tmp, progress=False)
            wall = time.perf_counter() - t0
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
        if not res.ok:
            raise RuntimeError("benchmark runs failed: %s" % res.failed()["error"].iloc[0])
        out.append({"workers": w, "n_runs": n_runs, "wall_s": wall,
                    "runs_per_hour": 3600.0 * n_runs / wall,
                    "mean_run_s": float(res.table["exec_s"].mean())})
    return out


def main(argv=None):
    p = argparse.ArgumentParser(prog="python -m analysis.bench.sweep", description=__doc__,
                                epilog="example: python -m analysis.bench.sweep --fake "
                                       "--n-runs 8 --cpu-s 2",
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--runner", help="runner 'module:function' (default: real twin if yade "
                                    "is available, else the fake)")
    p.add_argument("--runner-kw", action="append", type=parse_key_value, default=[])
    p.add_argument("--fake", action="store_true", help="force the CPU-bound FAKE runner")
    p.add_argument("--cpu-s", type=float, default=2.0,
                   help="fake runner: CPU time per run [s] (default %(default)s)")
    p.add_argument("--n-runs", type=int, default=None,
                   help="runs per worker count [runs] (default 8 fake, 4 real)")
    p.add_argument("--record-s", type=float, default=0.05,
                   help="record_s of the real twin's runs [s] (short: this times the sweep)")
    args = p.parse_args(argv)
    kwargs = dict(args.runner_kw)
    if args.runner and not args.fake:
        runner, label, record_s = args.runner, "runner %s" % args.runner, args.record_s
    elif not args.fake and shutil.which(os.environ.get("YADE", "yade")):
        runner, label, record_s = "analysis.twin:run_twin", \
            "REAL twin (yade), record_s = %g s" % args.record_s, args.record_s
    else:
        runner, record_s = "analysis.fake_twin:run_fake_twin", None
        kwargs.setdefault("cpu_s", args.cpu_s)
        label = ("FAKE runner (analysis.fake_twin, %.2g CPU s per run)%s"
                 % (kwargs["cpu_s"], "" if args.fake else ": yade not found"))
    n = args.n_runs or (8 if "fake" in runner else 4)
    print("bench-sweep: %s, %d runs per worker count, %d CPUs, load %.2f"
          % (label, n, os.cpu_count() or 0, os.getloadavg()[0]))
    try:
        rows = bench(runner, kwargs or None, n, record_s)
    except (SweepInputError, RuntimeError) as exc:
        print("analysis.bench.sweep: error: %s" % exc, file=sys.stderr)
        return 2
    for r in rows:
        print("  workers=%d: %d runs in %.1f s -> %.0f runs/hour (mean run %.2f s)"
              % (r["workers"], r["n_runs"], r["wall_s"], r["runs_per_hour"], r["mean_run_s"]))
    print("  speed-up 1 -> 2 workers: %.2fx" % (rows[1]["runs_per_hour"] / rows[0]["runs_per_hour"]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
