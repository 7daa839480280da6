"""Benchmark: time per yield-prediction query (goal < 10 ms per query).

    python -m analysis.bench.predict [--n 300] [--kinds lr gp rf]

Loads the saved surrogate bundle (results/surrogate/surrogate.joblib; trained on the fly from the
paper's Table 3 stand-in when missing) and the kinetics fit, then times
:meth:`analysis.predict.Predictor.query` at random conditions inside the domain (one query = one
condition and 4 milling times). Prints median / 95th percentile per query and the cold start.
"""
from __future__ import annotations

import argparse
import sys
import time

import numpy as np

GOAL_MS = 10.0


def bench(kind: str, n: int, seed: int = 0) -> dict:
    from analysis import predict as pr

    t0 = time.perf_counter()
    p = pr.load_predictor(kind)
    cold_s = time.perf_counter() - t0
    rng = np.random.default_rng(seed)
    lo, hi = p.surrogate.domain.min_, p.surrogate.domain.max_
    f = rng.uniform(lo[0], hi[0], n)
    times = np.array([5.0, 10.0, 20.0, 30.0])
    d = np.full(n, 0.020)
    p.query(f[0], d[0], times)                       # warm-up
    dt = np.empty(n)
    for i in range(n):
        t = time.perf_counter()
        p.query(f[i], d[i], times)
        dt[i] = time.perf_counter() - t
    return {"kind": kind, "n": n, "cold_start_s": cold_s, "median_ms": 1e3 * np.median(dt),
            "p95_ms": 1e3 * np.quantile(dt, 0.95), "max_ms": 1e3 * dt.max(),
            "source": p.surrogate.source}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m analysis.bench.predict", description=__doc__,
                                 epilog="example: python -m analysis.bench.predict --n 300 "
                                 "--kinds lr gp rf",
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=300,
                    help="timed queries per surrogate kind [queries] (default %(default)s)")
    ap.add_argument("--kinds", nargs="+", default=["lr", "gp", "rf"],
                    help="surrogate kinds to time (default: %(default)s)")
    args = ap.parse_args(argv)
    print(f"predict latency per query (1 condition x 4 times), goal < {GOAL_MS:g} ms")
    ok = True
    for k in args.kinds:
        r = bench(k, args.n)
        flag = "OK" if r["median_ms"] < GOAL_MS else "SLOW"
        ok &= r["median_ms"] < GOAL_MS
        print(f"  {k:>2}: median {r['median_ms']:.2f} ms, p95 {r['p95_ms']:.2f} ms, "
              f"max {r['max_ms']:.2f} ms over {r['n']} queries; cold start {r['cold_start_s']:.2f} s"
              f"  [{flag}]")
    print(f"  surrogate trained on: {r['source']}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
