"""SYNTHETIC blind datasets at conditions the paper never ran, for the open-world loop.

Each dataset is the twin run once per condition (one realisation of its chaos, as a real
measurement is) with base parameters drawn away from the calibration's mean, measurement noise,
a ball+jar track per condition and yields; the truth (effects, base parameters) is kept apart in
``<out>/truth/<name>.truth.json``.

    python -m analysis.studies.open_world_data --out results/open_world/nulls --nulls 20 [--only NAME]

Example::

    python -m analysis.studies.open_world_data --only null_a --workers 2

Every dataset folder and truth file it would write (films included) follows the project's
output rule before any run (:func:`analysis.hidden.check_outputs`): only what this project
wrote is ever replaced; a truth file is written atomically.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from analysis.config import RESULTS_DIR

OUT_DIR = RESULTS_DIR / "open_world" / "datasets"
#: the no-effect datasets the chain cases are made from
NULLS_DIR = RESULTS_DIR / "open_world" / "nulls"

#: six conditions none of which the paper ran
CONDITIONS = pd.DataFrame({
    "condition_id": ["c1", "c2", "c3", "c4", "c5", "c6"],
    "frequency_hz": [26.0, 28.0, 24.0, 21.0, 31.0, 23.5],
    "ball_diameter_mm": [19.0, 17.5, 20.0, 18.0, 16.0, 21.0],
})
#: off-anchor base parameters inside the calibration posterior, not at its mean
OFF_ANCHOR = {"restitution": 0.32, "static_friction": 0.55, "rolling_friction": 0.35,
              "amplitude_m": 0.0131}
#: the twin's scatter of one run at each of :data:`CONDITIONS` (relative v_mean, f_col [1/s]):
#: the pooled replicate sd of the open model's 282 runs there (groups of 2-3 seeds, anchor and
#: every response level), f_col floored at 1.0 Hz (a 0.5 s record counts collisions in steps
#: of 2 Hz). A dataset is one run: its stated sd must hold this scatter, or a correct model
#: fails it (c1's collision rate scatters 2.8 Hz, not the 1.0 Hz of the paper's conditions)
TWIN_V_REL_SD = {"c1": 0.0080, "c2": 0.0098, "c3": 0.0047, "c4": 0.0061, "c5": 0.0054,
                 "c6": 0.0023}
TWIN_F_COL_SD_HZ = {"c1": 2.79, "c2": 1.0, "c3": 1.87, "c4": 1.0, "c5": 1.0, "c6": 1.04}

CASES = {
    "null_a": ({}, 11),
    "null_b": ({}, 12),
    "visco": ({"viscoelastic_restitution": {"k": 0.33}}, 13),
    "arc": ({"arc_motion": {"curvature_1_m": 9.0}}, 14),
    "visco_arc": ({"viscoelastic_restitution": {"k": 0.33},
                   "arc_motion": {"curvature_1_m": 9.0}}, 15),
}


def posterior_draw(k, calibration_dir=None):
    """Base parameters of blind dataset draw ``k``: one sample of the Table-3 calibration's
    posterior (results/calibration/posterior_samples.csv), picked with seed 1000 + ``k``,
    rounded to 4 digits - anywhere in the posterior, not only near its mean (the loop's
    emulator covers the whole prior box)."""
    from analysis.config import CALIBRATION_DIR
    d = pd.read_csv(Path(calibration_dir or CALIBRATION_DIR) / "posterior_samples.csv")
    row = d.iloc[int(np.random.default_rng(1000 + int(k)).integers(len(d)))]
    return {c: float("%.4g" % row[c]) for c in ("restitution", "static_friction",
                                                "rolling_friction", "amplitude_m")}


def null_cases(n):
    """``n`` no-effect cases null_p00 .. : independent twin realisations (twin seeds 200 + k)
    with base parameters drawn from the calibration posterior."""
    return {"null_p%02d" % k: ({}, 200 + k, posterior_draw(k)) for k in range(int(n))}


#: DEM effects hidden one at a time by :func:`effect_cases` (the catalog's candidates that the
#: twin's observables can tell apart; the decoys - air drag, rolling resistance - are never
#: hidden, and must never be named)
HIDDEN_EFFECTS = ("viscoelastic_restitution", "arc_motion", "jar_compliance", "powder_layer")
#: hidden strengths, as fractions of each candidate's diagnose range (uniform between)
EFFECT_FRACTION = (0.35, 0.9)


def effect_cases(n):
    """``n`` one-effect cases eff_p00 .. : the effect cycles through :data:`HIDDEN_EFFECTS`,
    its strength drawn uniformly in :data:`EFFECT_FRACTION` of the candidate's range (seeded
    by k), base parameters drawn from the calibration posterior (draw 100 + k), independent
    twin realisations (twin seeds 300 + k)."""
    from analysis.catalog import candidates
    cands = candidates("dem")
    out = {}
    for k in range(int(n)):
        c = cands[HIDDEN_EFFECTS[k % len(HIDDEN_EFFECTS)]]
        fr = np.random.default_rng(3000 + k).uniform(*EFFECT_FRACTION)
        spec = c.spec(float("%.3g" % (fr * c.s_max)))
        spec = {e: {q: float("%.4g" % v) for q, v in ps.items()} for e, ps in spec.items()}
        out["eff_p%02d" % k] = (spec, 300 + k, posterior_draw(100 + k))
    return out


#: hidden strengths of the two-effect cases, as fractions of each candidate's range
PAIR_FRACTION = (0.5, 0.9)


def pair_cases(n):
    """``n`` two-effect cases pair_p00 .. : the pairs of :data:`HIDDEN_EFFECTS` in turn (6
    pairs), each strength drawn uniformly in :data:`PAIR_FRACTION` of its range (seeded by k),
    base parameters from the calibration posterior (draw 500 + k), twin seeds 500 + k."""
    from itertools import combinations
    from analysis.catalog import candidates
    cands = candidates("dem")
    pairs = list(combinations(HIDDEN_EFFECTS, 2))
    out = {}
    for k in range(int(n)):
        rng = np.random.default_rng(5000 + k)
        spec = {}
        for name in pairs[k % len(pairs)]:
            c = cands[name]
            s = c.spec(float("%.3g" % (rng.uniform(*PAIR_FRACTION) * c.s_max)))
            spec.update({e: {q: float("%.4g" % v) for q, v in ps.items()}
                         for e, ps in s.items()})
        out["pair_p%02d" % k] = (spec, 500 + k, posterior_draw(500 + k))
    return out


#: observation effects hidden by :func:`chain_cases`, in turn
HIDDEN_OBSERVATION = ("smoothing_window", "apparent_scale")
#: the hidden smoothing: a Savitzky-Golay window of this many frames (odd, drawn), this order,
#: run straight through the impacts on the dataset's own ball track
CHAIN_WINDOW_FRAMES, CHAIN_POLYORDER = (13, 37), 2
#: the chain cases are made from the no-effect datasets null_p10 .. (their twin realisations,
#: noise and tracks), observed through a chain the dataset does not state
CHAIN_FROM = 10


def chain_cases(n):
    """``n`` observation cases chain_p00 ..: the measurement chain hides
    :data:`HIDDEN_OBSERVATION` in turn - a smoothing window of an odd number of frames drawn in
    :data:`CHAIN_WINDOW_FRAMES`, or a blurred length scale (blur fraction drawn in
    :data:`EFFECT_FRACTION` of its diagnose range) - each made from null_p(10 + k)."""
    from analysis.catalog import candidates
    out = {}
    for k in range(int(n)):
        name = HIDDEN_OBSERVATION[k % len(HIDDEN_OBSERVATION)]
        rng = np.random.default_rng(7000 + k)
        if name == "smoothing_window":
            lo, hi = CHAIN_WINDOW_FRAMES
            spec = {"window_frames": int(lo + 2 * rng.integers(0, (hi - lo) // 2 + 1))}
        else:
            s_max = candidates("observation")["apparent_scale"].s_max
            spec = {"blur_fraction": float("%.3g" % (rng.uniform(*EFFECT_FRACTION) * s_max))}
        out["chain_p%02d" % k] = (name, spec, "null_p%02d" % (CHAIN_FROM + k))
    return out


def smoothing_factors(dataset, window_frames, polyorder=CHAIN_POLYORDER) -> pd.DataFrame:
    """Per condition of ``dataset`` (which must carry tracks): the mean speed of its ball track
    smoothed straight through the impacts (``window_frames``, ``polyorder``: the plain recipe,
    no kink handling) over the operator's own best estimate of it (kink-corrected), the
    collision rate, and the moving-average window tau = 2 (1 - ratio) / f_col [s] that the
    catalog's smoothing_window gives for that loss. Columns condition_id, ratio, f_col_hz,
    tau_s."""
    from analysis.observe import observe_track
    rows = []
    freq = dataset.conditions.set_index("condition_id")["frequency_hz"].astype(float)
    for cid in dataset.condition_ids:
        tr = dataset.tracks.get(cid)
        if tr is None:
            raise ValueError("dataset %s: condition %s has no track to re-observe"
                             % (dataset.name, cid))
        args = (tr["t_s"].to_numpy(float), tr["x_m"].to_numpy(float), tr["y_m"].to_numpy(float))
        best = observe_track(*args, frequency_hz=float(freq[cid]))
        plain = observe_track(*args, frequency_hz=float(freq[cid]), window=int(window_frames),
                              polyorder=int(polyorder), kink_correction=False)
        r = plain.v_mean_m_s / best.v_mean_m_s
        rows.append((cid, r, best.f_col_hz, 2.0 * (1.0 - r) / best.f_col_hz))
    return pd.DataFrame(rows, columns=["condition_id", "ratio", "f_col_hz", "tau_s"])


def make_chain(name, case, nulls_dir, out_dir):
    """Write chain dataset ``name`` = ``case`` (effect, spec, source null) into
    ``out_dir/name`` (truth in out_dir/truth): the source's summary, tracks and yields observed
    through the hidden chain - the speeds of a track smoothed over ``window_frames`` (the ratio
    measured on each condition's own track), or every length / (1 + blur_fraction). The truth
    states the catalog strength (the smoothing: the mean of the per-condition tau) and the
    factor applied to each observable at each condition."""
    import json
    from effects.apparent_scale import SCALED
    from effects.smoothing_window import SMOOTHED
    from analysis.atomic_dir import atomic_file
    from analysis.hidden import check_outputs
    from analysis.measurements import Dataset, load_dataset, write_dataset
    effect, spec, source = case
    nulls_dir, out_dir = Path(nulls_dir), Path(out_dir)
    _, truth_file = check_outputs(name, out_dir / name, out_dir / "truth")   # before any write
    ds = load_dataset(nulls_dir / source)
    truth = json.loads((nulls_dir / "truth" / ("%s.truth.json" % source)).read_text())
    if effect == "smoothing_window":
        fac = smoothing_factors(ds, spec["window_frames"])
        strength = {"window_s": float(fac["tau_s"].mean())}
        factor = {c: {o: float(r) for o in SMOOTHED} for c, r in zip(fac["condition_id"],
                                                                     fac["ratio"])}
        extra = {"tau_s": dict(zip(fac["condition_id"], map(float, fac["tau_s"])))}
        tracks = ds.tracks
    elif effect == "apparent_scale":
        strength = {"blur_fraction": float(spec["blur_fraction"])}
        k = 1.0 / (1.0 + strength["blur_fraction"])
        factor = {c: {o: k for o in SCALED} for c in ds.condition_ids}
        extra = {}
        tracks = {c: t.assign(**{q: k * t[q] for q in ("x_m", "y_m", "jar_x_m") if q in t})
                  for c, t in ds.tracks.items()}
    else:
        raise ValueError("chain case %s: %s is not a hidden observation effect (%s)"
                         % (name, effect, ", ".join(HIDDEN_OBSERVATION)))
    v = ds.summary["condition_id"].map(lambda c: factor[c].get("v_mean_m_s", 1.0))
    summary = ds.summary.assign(v_mean_m_s=ds.summary["v_mean_m_s"] * v,
                                v_mean_sd_m_s=ds.summary["v_mean_sd_m_s"] * v)
    desc = ("SYNTHETIC blind dataset %s observed through a measurement chain it does not state "
            "(made from %s); its truth is kept apart" % (name, source))
    out = Dataset(name=name, description=desc, source=ds.source,
                  velocity_frame=ds.velocity_frame, conditions=ds.conditions, summary=summary,
                  yields=ds.yields, meta=dict(ds.meta, name=name, description=desc),
                  tracks=tracks)
    path = write_dataset(out, out_dir / name, overwrite=True)
    t = dict(truth, name=name, effects={effect: strength},
             observation={"effect": effect, "made_from": source, **spec, **extra,
                          "factor": factor})
    with atomic_file(truth_file) as tmp:
        tmp.write_text(json.dumps(t, indent=1))
    return path, truth_file


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
    from analysis.atomic_dir import atomic_file
    from analysis.hidden import check_outputs
    _, truth_file = check_outputs(name + "_film", out_dir / (name + "_film"), out_dir / "truth")
    t = dict(truth, name=name + "_film")
    with atomic_file(truth_file) as tmp_file:
        tmp_file.write_text(json.dumps(t, indent=1))
    return path


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 epilog="example: python -m analysis.studies.open_world_data "
                                 "--only null_a")
    ap.add_argument("--out", default=str(OUT_DIR), help="parent folder of the datasets")
    ap.add_argument("--only", action="append", choices=sorted(CASES) + ["none"],
                    help="make only this case (repeatable; 'none': no case, e.g. with "
                    "--nulls)")
    ap.add_argument("--workers", type=int, default=2,
                    help="parallel twin runs [processes] (default %(default)s)")
    ap.add_argument("--films", action="append", default=None, metavar="NAME",
                    help="also write NAME_film: the dataset with films instead of tracks "
                    "(default: visco; 'none': no films)")
    ap.add_argument("--nulls", type=int, default=0,
                    help="also write this many no-effect datasets null_pNN with base "
                    "parameters drawn from the calibration posterior [datasets]")
    ap.add_argument("--effects", type=int, default=0,
                    help="also write this many one-effect datasets eff_pNN (effect and "
                    "strength drawn, base parameters from the calibration posterior) [datasets]")
    ap.add_argument("--pairs", type=int, default=0,
                    help="also write this many two-effect datasets pair_pNN (pairs of hidden "
                    "effects in turn, strengths drawn, base parameters from the posterior) "
                    "[datasets]")
    ap.add_argument("--chain", type=int, default=0,
                    help="also write this many datasets chain_pNN: null_p10 .. observed "
                    "through a hidden smoothing window or blurred scale (no twin run; needs "
                    "--nulls-dir) [datasets]")
    ap.add_argument("--nulls-dir", default=str(NULLS_DIR),
                    help="the no-effect datasets --chain is made from (default %(default)s)")
    a = ap.parse_args(argv)
    from analysis.atomic_dir import OutputError
    from analysis.hidden import check_outputs
    named = [c for c in (a.only or sorted(CASES)) if c != "none"]
    films = [f for f in (a.films if a.films is not None else ["visco"]) if f != "none"]
    drawn = {**null_cases(a.nulls), **effect_cases(a.effects), **pair_cases(a.pairs)}
    chain = chain_cases(a.chain)
    out = Path(a.out)
    try:                                    # every folder and truth file before any run
        for name in named + list(drawn) + list(chain) + ["%s_film" % f for f in films]:
            check_outputs(name, out / name, out / "truth")
        for _, _, source in chain.values():
            if not (Path(a.nulls_dir) / source / "dataset.json").is_file():
                raise OutputError("--chain: %s has no dataset %s to observe"
                                  % (a.nulls_dir, source))
    except OutputError as exc:
        print("open_world_data: error: %s" % exc, file=sys.stderr)
        return 2
    for name in named:
        ds, truth = make(name, a.out, a.workers)
        print("wrote %s (truth %s)" % (ds, truth))
    for name, case in drawn.items():
        ds, truth = make(name, a.out, a.workers, case=case)
        print("wrote %s (truth %s)" % (ds, truth))
    for name in films:
        print("wrote %s" % make_film_copy(name, a.out))
    for name, case in chain.items():
        ds, truth = make_chain(name, case, a.nulls_dir, a.out)
        print("wrote %s (truth %s)" % (ds, truth))
    return 0


if __name__ == "__main__":
    sys.exit(main())
