"""The twin as a model for :mod:`analysis.diagnose`: which catalog effect is missing?

The command line of :mod:`analysis.twin_model` (``python -m analysis.twin_model``): build the
signature library, recompute its impact observables, or print it.

    python -m analysis.twin_model --build [--replicates 2] [--workers 2]   # the library
    python -m analysis.twin_model --flights      # impact observables of its cached runs

``--out`` follows the project's folder rule before any run (:func:`analysis.atomic_dir.
check_out_dir`): ``--build`` replaces, and ``--flights`` rewrites files in, only a library
folder this project wrote (or one in ``results/``).
"""
from __future__ import annotations

import argparse
import sys

from analysis.twin_model.library import (SIGNATURE_DIR, build_library, load_library,
                                         refresh_flights, top_level)


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m analysis.twin_model",
                                 description=__doc__.split("\n\n")[0],
                                 epilog="example: python -m analysis.twin_model --build "
                                 "--replicates 2 --out results/signatures")
    ap.add_argument("--build", action="store_true", help="run and write the signature library")
    ap.add_argument("--replicates", type=int, default=2,
                    help="twin runs per condition and effect level (the anchor has at least "
                    "4) [seeds] (default %(default)s)")
    ap.add_argument("--workers", type=int, default=2,
                    help="parallel twin runs [processes] (default %(default)s)")
    ap.add_argument("--out", default=str(SIGNATURE_DIR),
                    help="signature library folder (default: results/signatures)")
    ap.add_argument("--flights", action="store_true",
                    help="recompute the impact observables of the library's (and the "
                    "calibration's) cached runs; no new twin runs")
    a = ap.parse_args(argv)
    if a.build or a.flights:
        from analysis.atomic_dir import OutputError, check_out_dir
        try:
            check_out_dir(a.out)
        except OutputError as exc:
            print("analysis.twin_model: error: %s" % exc, file=sys.stderr)
            return 2
    if a.flights and not a.build:
        try:
            summ = refresh_flights(a.out)
        except (FileNotFoundError, ValueError) as exc:
            print("analysis.twin_model: error: %s" % exc, file=sys.stderr)
            return 2
        from analysis.flights import FLIGHT_OBSERVABLES
        print(summ[["label", "condition_id", *FLIGHT_OBSERVABLES]].round(4).to_string())
        return 0
    if not a.build:
        summ, meta = load_library(a.out)
        print(summ.to_string())
        return 0
    try:
        summ = build_library(a.out, replicates=a.replicates, workers=a.workers)
    except (RuntimeError, FileNotFoundError, ValueError) as exc:
        print("analysis.twin_model: error: %s" % exc, file=sys.stderr)
        return 2
    piv = top_level(summ).pivot(index="condition_id", columns="label", values="dv_pct")
    print(piv.round(2).to_string())
    return 0
