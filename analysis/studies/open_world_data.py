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

import numpy as np
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


def posterior_draw(k, calibration_dir=None, within_steps=1.0):
    """Base parameters of null dataset ``k``: a draw from the Table-3 calibration's posterior
    samples (results/calibration/posterior_samples.csv), seeded by ``k``, rounded to 4 digits,
    kept only where every parameter lies within ``within_steps`` response steps
    (:data:`analysis.open_model.BASE_STEPS`) of the anchor - inside the model's measured
    responses, where no re-anchoring is needed (a draw outside is redrawn; about half of the
    posterior lies outside one step of restitution or stroke)."""
    from analysis.config import CALIBRATION_DIR
    from analysis.open_model import BASE_STEPS
    from analysis.twin_model import reference_parameters
    ref = reference_parameters()
    d = pd.read_csv(Path(calibration_dir or CALIBRATION_DIR) / "posterior_samples.csv")
    rng = np.random.default_rng(1000 + int(k))
    while True:
        row = d.iloc[int(rng.integers(len(d)))]
        th = {c: float("%.4g" % row[c]) for c in ("restitution", "static_friction",
                                                  "rolling_friction", "amplitude_m")}
        if all(abs(th[c] - ref[c]) <= within_steps * BASE_STEPS[c] for c in th):
            return th


def null_cases(n):
    """``n`` no-effect cases null_p00 .. : independent twin realisations (twin seeds 200 + k)
    with base parameters drawn from the calibration posterior."""
    return {"null_p%02d" % k: ({}, 200 + k, posterior_draw(k)) for k in range(int(n))}


def make(name, out_dir=OUT_DIR, workers=2, runner=None, conditions=CONDITIONS,
         base=OFF_ANCHOR, case=None):
    """Write dataset ``name`` of :data:`CASES` (or ``case`` = (effects, seed[, base])) into
    ``out_dir/name`` (truth in out_dir/truth)."""
    from analysis.hidden import make_hidden_dataset
    case = case or CASES[name]
    effects, seed = case[0], case[1]
    if len(case) > 2:
        base = case[2]
    out_dir = Path(out_dir)
    return make_hidden_dataset(name, effects, conditions=conditions, replicates=1, seed=seed,
                               base_config=dict(base), runner=runner, workers=workers,
                               out_dir=out_dir / name, truth_dir=out_dir / "truth",
                               twin_v_rel_sd=TWIN_V_REL_SD, twin_f_col_sd_hz=TWIN_F_COL_SD_HZ)


def make_film_copy(name, out_dir=OUT_DIR, seed=0, progress=True):
    """The dataset ``name`` with films instead of tracks: each condition's twin run (the one its
    track came from) filmed by :func:`analysis.synthvideo.render_video` (lab camera, 2134 fps,
    0.2 mm/px, motion blur, sensor noise, flicker, an occluding bar), written as
    ``<name>_film`` with ``videos/`` and no ``tracks/``; same summary, yields and truth."""
    import json
    import shutil
    import tempfile
    from tqdm.auto import tqdm
    from analysis.config import RUNS_DIR
    from analysis.measurements import Dataset, load_dataset, write_dataset
    from analysis.synthvideo import Camera, render_video
    out_dir = Path(out_dir)
    ds = load_dataset(out_dir / name)
    truth = json.loads((out_dir / "truth" / ("%s.truth.json" % name)).read_text())
    cam = Camera()
    tmp = Path(tempfile.mkdtemp(prefix="films-"))
    try:
        files = {}
        for cid, rid in tqdm(list(zip(ds.condition_ids, truth["run_ids"])), desc="filming",
                             unit="film", disable=not progress):
            f = tmp / ("%s.mkv" % cid)
            render_video(Path(RUNS_DIR) / rid, f, cam, seed=seed)
            files[cid] = f
        film = Dataset(name=name + "_film", description=ds.description + " Delivered as "
                       "SYNTHETIC films rendered from the same twin runs (no tracks).",
                       source=ds.source, velocity_frame=ds.velocity_frame,
                       conditions=ds.conditions, summary=ds.summary, yields=ds.yields,
                       meta=dict(ds.meta, name=name + "_film"), tracks={},
                       video={"fps": cam.fps, "m_per_px": cam.m_per_px}, video_files=files)
        path = write_dataset(film, out_dir / (name + "_film"), overwrite=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    t = dict(truth, name=name + "_film")
    (out_dir / "truth" / ("%s_film.truth.json" % name)).write_text(json.dumps(t, indent=1))
    return path


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 epilog="example: python -m analysis.studies.open_world_data "
                                 "--only null_a")
    ap.add_argument("--out", default=str(OUT_DIR), help="parent folder of the datasets")
    ap.add_argument("--only", action="append", choices=sorted(CASES),
                    help="make only this case (repeatable)")
    ap.add_argument("--workers", type=int, default=2, help="parallel twin runs")
    ap.add_argument("--films", action="append", default=None, metavar="NAME",
                    help="also write NAME_film: the dataset with films instead of tracks "
                    "(default: visco; 'none': no films)")
    ap.add_argument("--nulls", type=int, default=0,
                    help="also write this many no-effect datasets null_pNN with base "
                    "parameters drawn from the calibration posterior")
    a = ap.parse_args(argv)
    for name in a.only or sorted(CASES):
        ds, truth = make(name, a.out, a.workers)
        print("wrote %s (truth %s)" % (ds, truth))
    for name, case in null_cases(a.nulls).items():
        ds, truth = make(name, a.out, a.workers, case=case)
        print("wrote %s (truth %s)" % (ds, truth))
    for name in (a.films if a.films is not None else ["visco"]):
        if name != "none":
            print("wrote %s" % make_film_copy(name, a.out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
