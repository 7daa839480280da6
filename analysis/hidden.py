"""Hidden-effect measurement datasets: the twin with effects switched on, plus measurement noise.

A dataset made here looks like any measurement dataset (DESIGN.md format: dataset.json,
conditions.csv, summary.csv with sd columns) and says nothing of how it was made beyond
"SYNTHETIC"; the truth (effects, strengths, base config, seeds, noise, the twin's noise-free
means) goes to a separate file, ``results/hidden/<name>.truth.json``, to be revealed after a blind
loop (``python -m analysis.loop``).

    python -m analysis.hidden --name hidden_visco --effect viscoelastic_restitution:k=0.05 \
        [--replicates 2] [--v-rel-sd 0.015] [--f-col-sd-hz 1.0] [--seed 0] [--fake]
"""
import argparse
import json
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from analysis.config import MEASUREMENTS_DIR, PAPER_TABLE3_DIR, RESULTS_DIR, twin_config
from analysis.run_configs import condition_runs

HIDDEN_TRUTH_DIR = RESULTS_DIR / "hidden"


#: keys every truth file this module writes holds (how it recognises its own earlier file)
TRUTH_KEYS = ("name", "effects", "base_config", "noise", "run_ids")


def _own_truth(path) -> bool:
    try:
        d = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return isinstance(d, dict) and all(k in d for k in TRUTH_KEYS)


def check_outputs(name, out_dir=None, truth_dir=None, flag="--out"):
    """The project's output rule for a hidden dataset, before any run (raises
    :class:`analysis.atomic_dir.OutputError`): its folder (``out_dir``, default
    data/measurements/<name>) is replaced only when this project wrote it, its truth file
    (``<truth_dir>/<name>.truth.json``) only when it is a truth file written here. Returns
    (dataset folder, truth file) resolved."""
    from analysis.atomic_dir import check_out_dir, check_out_file
    out = check_out_dir(Path(out_dir or MEASUREMENTS_DIR / name), area="datasets", flag=flag)
    truth = Path(truth_dir or HIDDEN_TRUTH_DIR) / ("%s.truth.json" % name)
    return out, check_out_file(truth, [out], is_own=_own_truth, flag=flag)


def parse_effect(text):
    """'name:p=v,q=w' -> ('name', {'p': v, 'q': w})."""
    name, _, rest = text.partition(":")
    params = {}
    for item in filter(None, rest.split(",")):
        if "=" not in item:
            raise twin_config.ConfigError("effect parameter %r must be p=value" % item)
        k, v = item.split("=", 1)
        try:
            params[k.strip()] = float(v)
        except ValueError:
            raise twin_config.ConfigError("effect %s: %s=%r is not a number" % (name, k, v))
    return name.strip(), params


YIELD_TIMES_MIN = (2.5, 5.0, 7.5, 10.0)


def make_hidden_dataset(name, effects, *, conditions=None, replicates=2, v_rel_sd=0.015,
                        f_col_sd_hz=1.0, seed=0, base_config=None, runner=None, workers=2,
                        runs_dir=None, out_dir=None, truth_dir=None,
                        yield_times_min=YIELD_TIMES_MIN, yield_sd_pct=1.0,
                        slope_pct_per_kj=None, intercept_pct=None, progress=True,
                        twin_seed=None, twin_v_rel_sd=None, twin_f_col_sd_hz=None,
                        tracks="auto", track_noise_m=5e-6, track_scale_sd=None):
    """Run the twin with ``effects`` at every condition and write a noisy measurement dataset.

    Parameters
    ----------
    name : str - dataset name (folder data/measurements/<name> unless ``out_dir``)
    effects : dict {effect: {param: value}} - validated against effects/ before any run
    conditions : DataFrame, optional - condition_id, frequency_hz, ball_diameter_mm (default:
        the paper's Table 3 conditions)
    replicates : int - twin runs per condition (different start positions); their mean is the
        noise-free "truth" of the observable
    v_rel_sd, f_col_sd_hz : float - measurement noise: relative sd of v_mean, sd of f_col [1/s]
    seed : int - seeds the measurement noise and (unless ``twin_seed``) the replicate start
        positions (seeds 1000 seed + k)
    twin_seed : int, optional - seeds the replicate start positions instead (1000 twin_seed + k):
        several noise draws on the same twin runs
    twin_v_rel_sd, twin_f_col_sd_hz : the twin's replicate scatter of one run (relative for
        v_mean, 1/s for f_col), a number or a dict per condition_id, when known from elsewhere
        (needed with ``replicates=1``; default: estimated from the replicates, pooled over the
        conditions; 0 with one replicate)
    runner : callable, optional - twin runner (default analysis.twin.run_twin)
    yield_times_min : milling times [min] of the yield measurements at every condition (the
        default 2.5-10 min keeps the paper's conditions in the powder regime); () for none
    yield_sd_pct : sd of the yield noise [percentage points]
    slope_pct_per_kj, intercept_pct : the powder line X = a E_tot + b (default: the paper's
        Table 4); a kinetics effect in ``effects`` replaces it by its own law
    tracks : True, False or 'auto' - also write tracks/<condition_id>.csv: the first replicate
        as the camera sees it (2134 frames/s, lab frame) with the jar's position (jar_x_m), for
        the impact observables of analysis.flights; 'auto': when the runs have trajectories
        (the FAKE twin's have none)
    track_noise_m : sd of the white tracking noise added to x, y and jar_x [m] (5 um: the
        tracker's 0.01-0.04 px at ~0.1 mm/px, results/observe)
    track_scale_sd : relative sd of each film's length scale (a camera calibrated on a
        reference length is off by a fixed factor for the whole film); default the relative
        scale sd the impact observables' lengths carry (analysis.flights.FILM_SCALE_REL_SD, 0.5 %)

    The twin runs only the DEM effects (kinetics effects act on the yields). The reported sd of
    v_mean and f_col is the measurement noise combined with the twin's own replicate scatter of
    the mean of ``replicates`` runs (pooled over the conditions): the measured value of a chaotic
    system differs from its expectation by both.

    Returns
    -------
    (dataset_path, truth_path)
    """
    from effects import load_effects
    from analysis import kinetics
    from analysis.measurements import Dataset, load_dataset
    if replicates < 1 or v_rel_sd < 0 or f_col_sd_hz < 0 or yield_sd_pct < 0:
        raise ValueError("replicates must be >= 1 and noise sds >= 0")
    if any(not np.isfinite(t) or t <= 0 for t in yield_times_min):
        raise ValueError("yield times must be finite and > 0 min, got %r" % (yield_times_min,))
    load_effects(effects)  # unknown effects / parameters fail here, before any run
    check_outputs(name, out_dir, truth_dir)   # and a folder or truth file not ours to replace
    kin = load_effects(effects, side="kinetics")
    if len(kin) > 1:
        raise ValueError("kinetics effects do not compose: %s" % [k.name for k in kin])
    dem_effects = {k: v for k, v in effects.items() if k in
                   {e.name for e in load_effects(effects, side="dem")}}
    line = _PowderLine(
        kinetics.PAPER_SLOPE_PCT_PER_KJ if slope_pct_per_kj is None else slope_pct_per_kj,
        kinetics.PAPER_INTERCEPT_PCT if intercept_pct is None else intercept_pct,
        kin[0] if kin else None)
    if conditions is None:
        conditions = load_dataset(PAPER_TABLE3_DIR).conditions
    base = dict(base_config or {})
    twin_seed = seed if twin_seed is None else twin_seed
    t = _replicate_runs(name, conditions, [1000 * twin_seed + k for k in range(replicates)],
                        base, dem_effects, runner=runner, workers=workers, runs_dir=runs_dir,
                        progress=progress)
    ids = list(conditions["condition_id"])
    means = t.groupby("condition_id", sort=False)[["v_mean_m_s", "f_col_hz"]].mean()
    twin = _TwinMeans(ids, means.loc[ids, "v_mean_m_s"].to_numpy(float),
                      means.loc[ids, "f_col_hz"].to_numpy(float),
                      *_twin_scatter(t, ids, replicates, twin_v_rel_sd, twin_f_col_sd_hz),
                      replicates)
    rng = np.random.default_rng(seed)
    summary = _measured_summary(twin, v_rel_sd, f_col_sd_hz, rng)
    yields, y_true = (_measured_yields(twin, conditions, line, yield_times_min, yield_sd_pct,
                                       rng) if len(yield_times_min) else (None, {}))
    if tracks and track_scale_sd is None:
        from analysis.flights import FILM_SCALE_REL_SD
        track_scale_sd = FILM_SCALE_REL_SD
    track_tables, twin_flights = _camera_tracks(t, runs_dir, tracks, track_noise_m,
                                                track_scale_sd, rng, seed)
    meta = {"name": name,
            "description": "SYNTHETIC hidden-effect dataset made from the twin with measurement "
                           "noise; its truth is kept apart (results/hidden/%s.truth.json)" % name,
            "source": "analysis.hidden (SYNTHETIC)", "velocity_frame": "lab", "synthetic": True}
    cond = conditions[["condition_id", "frequency_hz", "ball_diameter_mm"]].copy()
    ds = Dataset(name=name, description=meta["description"], source=meta["source"],
                 velocity_frame="lab", conditions=cond, summary=summary, yields=yields,
                 meta=meta, tracks=track_tables)
    truth = {"name": name, "effects": effects, "base_config": base, "replicates": replicates,
             "noise": {"v_rel_sd": v_rel_sd, "f_col_sd_hz": f_col_sd_hz, "seed": seed,
                       "twin_seed": twin_seed, "yield_sd_pct": yield_sd_pct,
                       "twin_v_rel_sd": dict(zip(ids, map(float, twin.v_rel_rep))),
                       "twin_f_col_sd_hz": dict(zip(ids, map(float, twin.f_rep_hz)))},
             "kinetics": {"slope_pct_per_kj": line.slope, "intercept_pct": line.intercept,
                          "yield_times_min": list(yield_times_min), "yields_true": y_true},
             "twin_means": {cid: {"v_mean_m_s": float(v), "f_col_hz": float(f)}
                            for cid, v, f in zip(ids, twin.v_m_s, twin.f_hz)},
             "twin_flights": twin_flights,
             "track_noise_m": track_noise_m if track_tables else None,
             "track_scale_sd": track_scale_sd if track_tables else None,
             "run_ids": list(t["run_id"])}
    return _write_pair(ds, truth, name, out_dir, truth_dir)


@dataclass(frozen=True)
class _PowderLine:
    """The yields' law: X = slope E_tot + intercept [% per kJ, %], or a kinetics effect's."""
    slope: float
    intercept: float
    kinetics: object = None

    def yield_pct(self, e_kin_j, f_col_hz, t_s):
        if self.kinetics is not None:
            return self.kinetics.yield_pct(e_kin_j, f_col_hz, t_s, self.slope, self.intercept)
        return self.slope * e_kin_j * f_col_hz * t_s / 1000.0 + self.intercept


@dataclass(frozen=True)
class _TwinMeans:
    """The twin's noise-free means per condition (in ``ids`` order) and its own scatter of one
    run: relative for v_mean, [1/s] for f_col; ``replicates`` runs make each mean."""
    ids: list
    v_m_s: np.ndarray
    f_hz: np.ndarray
    v_rel_rep: np.ndarray
    f_rep_hz: np.ndarray
    replicates: int


def _replicate_runs(name, conditions, seeds, base, dem_effects, **sweep) -> pd.DataFrame:
    """The twin's runs at every condition and seed (a condition that states its stroke,
    amplitude_mm, is run at it, as the loop's model runs it): the sweep's table with
    condition_id. Raises RuntimeError when a run failed."""
    from analysis.sweep import run_sweep
    runs = condition_runs(conditions, seeds, base_config=base, effects=dem_effects,
                          stated_stroke=True)
    res = run_sweep([r.config for r in runs], **sweep)
    if not res.ok:
        raise RuntimeError("hidden dataset %s: %d twin run(s) failed:\n%s"
                           % (name, res.n_failed, res.failed()[["run_id", "error"]].to_string()))
    return res.table.reset_index(drop=True).assign(condition_id=[r.condition_id for r in runs])


def _twin_scatter(t, ids, replicates, twin_v_rel_sd, twin_f_col_sd_hz):
    """The twin's scatter of one run per condition (relative v_mean, f_col [1/s]): as given, or
    pooled over the conditions from the replicates (0 with one replicate)."""
    g = t.groupby("condition_id", sort=False)
    v_rel_rep = (float(np.sqrt(np.nanmean((g["v_mean_m_s"].std() / g["v_mean_m_s"].mean())
                                          ** 2))) if replicates > 1 else 0.0)
    f_rep = float(np.sqrt(np.nanmean(g["f_col_hz"].std() ** 2))) if replicates > 1 else 0.0
    return (_per_condition(twin_v_rel_sd, v_rel_rep, ids, "twin_v_rel_sd"),
            _per_condition(twin_f_col_sd_hz, f_rep, ids, "twin_f_col_sd_hz"))


def _measured_summary(twin, v_rel_sd, f_col_sd_hz, rng) -> pd.DataFrame:
    """summary.csv: the twin's means with measurement noise; the sd stated is that noise and
    the twin's own scatter of a mean of its replicates combined."""
    n = len(twin.ids)
    v_meas = twin.v_m_s * (1.0 + v_rel_sd * rng.standard_normal(n))
    f_meas = twin.f_hz + f_col_sd_hz * rng.standard_normal(n)
    v_sd = np.hypot(v_rel_sd, twin.v_rel_rep / np.sqrt(twin.replicates)) * v_meas
    f_sd = np.hypot(f_col_sd_hz, twin.f_rep_hz / np.sqrt(twin.replicates))
    return pd.DataFrame({"condition_id": twin.ids, "v_mean_m_s": v_meas, "v_mean_sd_m_s": v_sd,
                         "f_col_hz": f_meas, "f_col_sd_hz": f_sd})


def _measured_yields(twin, conditions, line, times_min, yield_sd_pct, rng):
    """yields.csv from the twin's means through ``line``, with noise (clipped to [0, 100] %),
    and the noise-free yields per condition."""
    from analysis import kinetics
    d_mm = conditions.set_index("condition_id")["ball_diameter_mm"]
    t_s = np.asarray(times_min, float) * 60.0
    rows, y_true = [], {}
    for i, (cid, v, f) in enumerate(zip(twin.ids, twin.v_m_s, twin.f_hz)):
        m = kinetics.ball_mass_kg(float(d_mm.loc[cid]) * 1e-3)
        e_kin = 0.5 * m * v * v
        x = line.yield_pct(e_kin, f, t_s)
        y_true[cid] = [float(z) for z in np.atleast_1d(x)]
        # the twin's own scatter of (v, f_col) carried into E_tot, beside the measurement
        # noise: the reported sd, as for v_mean and f_col
        twin_y_sd = (line.slope * t_s / 1000.0
                     * np.hypot(m * v * f * twin.v_rel_rep[i] * v, e_kin * twin.f_rep_hz[i])
                     / math.sqrt(twin.replicates))
        for tm, z, tsd in zip(times_min, np.atleast_1d(x), twin_y_sd):
            z_meas = min(max(float(z) + yield_sd_pct * rng.standard_normal(), 0.0), 100.0)
            rows.append((cid, float(tm), z_meas, float(math.hypot(yield_sd_pct, tsd))))
    return (pd.DataFrame(rows, columns=["condition_id", "time_min", "yield_pct",
                                        "yield_sd_pct"]), y_true)


def _camera_tracks(t, runs_dir, tracks, noise_m, scale_sd, rng, seed):
    """tracks/<condition_id>.csv: each condition's first run as the camera sees it (lab frame,
    jar_x_m), with white tracking noise and one length-scale error per film; and the twin's
    mean impact observables per condition (for the truth). ({}, {}) when ``tracks`` is False,
    or 'auto' and a run has no trajectory."""
    if not tracks:
        return {}, {}
    from analysis.config import RUNS_DIR
    from analysis.twin_runs import run_flights
    from analysis.observe import camera_track
    root = Path(runs_dir or RUNS_DIR)
    if tracks == "auto" and not all((root / str(r) / "trajectory.csv").is_file()
                                    for r in t["run_id"]):
        return {}, {}
    # its own stream: the scale draws leave the other noise of a seed as it was
    rng_scale = np.random.default_rng([int(seed), 7])
    tables, flights = {}, {}
    for cid, g in t.groupby("condition_id", sort=False):
        tr = camera_track(root / str(g["run_id"].iloc[0]))
        scale = 1.0 + scale_sd * rng_scale.standard_normal()
        for c in ("x_m", "y_m", "jar_x_m"):
            tr[c] = scale * tr[c] + noise_m * rng.standard_normal(len(tr))
        tables[cid] = tr[["t_s", "x_m", "y_m", "jar_x_m"]]
        fl = run_flights(list(g["run_id"]), root).dropna()
        if len(fl):
            flights[cid] = {k: float(fl[k].mean()) for k in fl.columns if k != "run_id"}
    return tables, flights


def _write_pair(ds, truth, name, out_dir, truth_dir):
    """Write the dataset and its truth file together: the truth is staged first and renamed
    only once the dataset's folder is in place, so an error or a kill leaves the earlier pair
    as it was (never a new dataset beside an old truth). Returns (dataset, truth) paths."""
    from analysis.atomic_dir import atomic_file
    from analysis.measurements import write_dataset
    out, truth_path = check_outputs(name, out_dir, truth_dir)
    with atomic_file(truth_path) as tmp:
        tmp.write_text(json.dumps(truth, indent=1))
        ds_path = write_dataset(ds, out, overwrite=True)
    return ds_path, truth_path


def _per_condition(given, estimated, ids, what):
    """An array over ``ids`` from a number, a dict per condition_id or (None) ``estimated``."""
    if given is None:
        return np.full(len(ids), float(estimated))
    if isinstance(given, dict):
        missing = [c for c in ids if c not in given]
        if missing:
            raise ValueError("%s: no value for condition(s) %s" % (what, missing))
        return np.array([float(given[c]) for c in ids])
    return np.full(len(ids), float(given))


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                epilog="example: python -m analysis.hidden --name hidden_visco "
                                "--effect viscoelastic_restitution:k=0.05 --replicates 2")
    p.add_argument("--name", required=True,
                   help="dataset name: folder data/measurements/NAME, truth "
                   "results/hidden/NAME.truth.json")
    p.add_argument("--effect", action="append", default=[],
                   help="name:param=value,... (repeatable; none = a no-effect control); each "
                   "value in the unit its effect declares [effects/<name>.py 'unit', e.g. - "
                   "for viscoelastic_restitution's k]")
    p.add_argument("--replicates", type=int, default=2,
                   help="twin runs per condition, their mean is the measured value [seeds] "
                   "(default %(default)s)")
    p.add_argument("--v-rel-sd", type=float, default=0.015,
                   help="measurement noise sd of v_mean, as a fraction of v_mean [-] "
                   "(default %(default)s)")
    p.add_argument("--f-col-sd-hz", type=float, default=1.0,
                   help="measurement noise sd of f_col [Hz] (default %(default)s)")
    p.add_argument("--seed", type=int, default=0,
                   help="seeds the measurement noise and the replicates' start positions [-] "
                   "(default %(default)s)")
    p.add_argument("--workers", type=int, default=2,
                   help="parallel twin runs [processes] (default %(default)s)")
    p.add_argument("--fake", action="store_true", help="use the FAKE analytic twin (tests)")
    a = p.parse_args(argv)
    try:
        effects = dict(parse_effect(e) for e in a.effect)
        runner = None
        if a.fake:
            from analysis.fake_twin import run_fake_twin
            runner = run_fake_twin
        ds, truth = make_hidden_dataset(a.name, effects, replicates=a.replicates,
                                        v_rel_sd=a.v_rel_sd, f_col_sd_hz=a.f_col_sd_hz,
                                        seed=a.seed, runner=runner, workers=a.workers)
    except (twin_config.ConfigError, ValueError, RuntimeError) as exc:
        print("analysis.hidden: error: %s" % exc, file=sys.stderr)
        return 2
    print("wrote %s (truth kept apart in %s)" % (ds, truth))
    return 0


if __name__ == "__main__":
    sys.exit(main())
