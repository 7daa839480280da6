"""SYNTHETIC blind datasets at conditions the paper never ran, for the open-world loop.

Each dataset is the twin run once per condition (one realisation of its chaos, as a real
measurement is) with base parameters drawn away from the calibration's mean, measurement noise,
a ball+jar track per condition and yields; the truth (effects, base parameters) is kept apart in
``<out>/truth/<name>.truth.json``.

    python -m analysis.studies.open_world_data --out results/open_world/datasets [--only NAME]

Example::

    python -m analysis.studies.open_world_data --only null_a --workers 2
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import pandas as pd

from analysis.config import RESULTS_DIR

OUT_DIR = RESULTS_DIR / "open_world" / "datasets"

#: six conditions none of which the paper (or the committed library) ran
CONDITIONS = pd.DataFrame({
    "condition_id": ["c1", "c2", "c3", "c4", "c5", "c6"],
    "frequency_hz": [26.0, 28.0, 24.0, 21.0, 31.0, 23.5],
    "ball_diameter_mm": [19.0, 17.5, 20.0, 18.0, 16.0, 21.0],
})
#: off-anchor base parameters inside the calibration posterior, not at its mean
OFF_ANCHOR = {"restitution": 0.32, "static_friction": 0.55, "rolling_friction": 0.35,
              "amplitude_m": 0.0131}
#: the twin's scatter of one run (relative v_mean, f_col [1/s]) as the library measured it
TWIN_V_REL_SD = 0.008
TWIN_F_COL_SD_HZ = 1.0

CASES = {
    "null_a": ({}, 11),
    "null_b": ({}, 12),
    "visco": ({"viscoelastic_restitution": {"k": 0.33}}, 13),
    "arc": ({"arc_motion": {"curvature_1_m": 9.0}}, 14),
    "visco_arc": ({"viscoelastic_restitution": {"k": 0.33},
                   "arc_motion": {"curvature_1_m": 9.0}}, 15),
}


def make(name, out_dir=OUT_DIR, workers=2, runner=None, conditions=CONDITIONS,
         base=OFF_ANCHOR):
    """Write dataset ``name`` of :data:`CASES` into ``out_dir/name`` (truth in out_dir/truth)."""
    from analysis.hidden import make_hidden_dataset
    effects, seed = CASES[name]
    out_dir = Path(out_dir)
    return make_hidden_dataset(name, effects, conditions=conditions, replicates=1, seed=seed,
                               base_config=dict(base), runner=runner, workers=workers,
                               out_dir=out_dir / name, truth_dir=out_dir / "truth",
                               twin_v_rel_sd=TWIN_V_REL_SD, twin_f_col_sd_hz=TWIN_F_COL_SD_HZ)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 epilog="example: python -m analysis.studies.open_world_data "
                                 "--only null_a")
    ap.add_argument("--out", default=str(OUT_DIR), help="parent folder of the datasets")
    ap.add_argument("--only", action="append", choices=sorted(CASES),
                    help="make only this case (repeatable)")
    ap.add_argument("--workers", type=int, default=2, help="parallel twin runs")
    a = ap.parse_args(argv)
    for name in a.only or sorted(CASES):
        ds, truth = make(name, a.out, a.workers)
        print("wrote %s (truth %s)" % (ds, truth))
    return 0


if __name__ == "__main__":
    sys.exit(main())
