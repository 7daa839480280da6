"""The blind hidden-effect dataset of tests/test_hidden_blind.py, made once by the REAL twin.

A viscoelastic wall (k = 0.4, 67 % of its diagnose range) hidden in one twin run per Table-3
condition (seeds the suite never uses) at the signature library's anchor, with measurement noise
and a ball+jar track per condition; the truth kept apart in ``<out>/truth``. The test diagnoses it
against the committed signature library without running YADE (8 twin runs, about 2 min on 2
cores, saved from every ``make test``).

    python -m analysis.studies.hidden_blind_data [--out results/hidden_blind] [--workers 2]

Each dataset folder and truth file follows the project's output rule before any run
(:func:`analysis.hidden.check_outputs`): only what this project wrote is ever replaced.
"""
from __future__ import annotations

import argparse
import sys

import pandas as pd

from analysis.config import RESULTS_DIR

OUT_DIR = RESULTS_DIR / "hidden_blind"
#: name -> (hidden effects, noise seed, twin seed)
CASES = {"visco_k0.4": ({"viscoelastic_restitution": {"k": 0.4}}, 4343, 43)}


def make(name, out_dir=OUT_DIR, workers=2, progress=True):
    """Write dataset ``name`` of :data:`CASES` into ``out_dir/name`` (truth in out_dir/truth)."""
    from analysis import twin_model
    from analysis.hidden import make_hidden_dataset
    effects, seed, twin_seed = CASES[name]
    library = twin_model.load_library()
    model = twin_model.TwinModel(pd.DataFrame(library[1]["conditions"]), {}, library=library)
    return make_hidden_dataset(name, effects, replicates=1, seed=seed, twin_seed=twin_seed,
                               base_config=library[1]["theta_ref"], workers=workers,
                               out_dir=out_dir / name, truth_dir=out_dir / "truth",
                               progress=progress, **model.twin_scatter())


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 epilog="example: python -m analysis.studies.hidden_blind_data")
    ap.add_argument("--out", default=str(OUT_DIR), help="parent folder of the datasets")
    ap.add_argument("--workers", type=int, default=2,
                    help="parallel twin runs [processes] (default %(default)s)")
    a = ap.parse_args(argv)
    from pathlib import Path
    from analysis.atomic_dir import OutputError
    from analysis.hidden import check_outputs
    try:
        for name in CASES:
            check_outputs(name, Path(a.out) / name, Path(a.out) / "truth")
    except OutputError as exc:
        print("hidden_blind_data: error: %s" % exc, file=sys.stderr)
        return 2
    for name in CASES:
        ds, truth = make(name, Path(a.out), a.workers)
        print("wrote %s (truth %s)" % (ds, truth))
    return 0


if __name__ == "__main__":
    sys.exit(main())
