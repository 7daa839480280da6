"""The loop's stages on the one model of the twin, on a blind dataset whose truth is known.

A proving ground for the loop's next model (:mod:`analysis.emulated_twin`), before the loop
itself moves onto it: on a dataset made from the twin with a hidden effect (the open-world
suite's, ``results/open_world/effects/<name>``, truth in ``.../truth/<name>.truth.json``):

1. **waves** (:func:`analysis.emulated_twin.build_in_waves`): wave 0 - the same design as
   :mod:`analysis.studies.emulator_check`, so its runs come from the cache - then refinement
   waves where the data are plausible, with no effect and with each candidate effect free;
2. **calibrate** the base parameters on the emulator (its sd in the likelihood);
3. **diagnose and add** by forward selection (:func:`analysis.loop.forward_select`, the
   bootstrap-calibrated threshold);
4. **confirm**: the twin itself at the final point with the effects found (fresh seeds); these
   runs join the training runs, the emulator is refitted and the final fit redone on it - the
   confirmation runs are design points too;
5. the strengths' 95 % **profile-likelihood intervals** (:func:`analysis.diagnose.
   profile_interval`), set against the truth beside every base parameter's.

Writes ``--out`` (default ``results/studies/emulated_loop/<dataset>``): ``README.md`` (the
verdict, the staircase, the parameters against the truth), ``staircase.csv``, ``steps.csv``,
``parameters.csv``, ``runs.csv`` (every twin run: wave, point, condition, seed, run id, inputs,
observables). Twin runs are cached by run id: a killed study resumes.

Example::

    python -m analysis.studies.emulated_loop --dataset results/open_world/effects/eff_p01
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

from analysis.config import RESULTS_DIR

DEFAULT_DATASET = RESULTS_DIR / "open_world" / "effects" / "eff_p01"
DEFAULT_OUT = RESULTS_DIR / "studies" / "emulated_loop"
#: seeds of the confirmation runs at the final point
CONFIRM_SEED0 = 100


def truth_of(dataset_dir):
    p = Path(dataset_dir).parent / "truth" / (Path(dataset_dir).name + ".truth.json")
    return json.loads(p.read_text()) if p.is_file() else None


def stage_row(stage, what, fit, n_params):
    return {"stage": stage, "model": what, "chi2": fit.chi2, "dof": fit.dof,
            "chi2_dof": fit.chi2_dof, "n_params": n_params}


def confirm_runs(model, theta, added, replicates, base_config):
    """The twin at the final point with the DEM effects found on (as one design point)."""
    from analysis.history_matching import design_runs
    pt = model.point(theta, added)
    pt.insert(0, "point", int(model.runs_["point"].max()) + 1)
    r = design_runs(model.space, pt, model.conditions,
                    seeds=range(CONFIRM_SEED0, CONFIRM_SEED0 + replicates),
                    base_config=base_config)
    r["wave"] = "confirm"
    return r


def rerun_chi2(obs, runs, model):
    """chi2 of the data against the confirmation runs' means (sigma: the data's sd and the
    mean's own scatter); yields through the final fit's powder line are left out."""
    from analysis.emulated_twin import SPEED_COLUMN
    cid_col = runs.groupby("condition_id")
    rows = []
    for o in obs.itertuples():
        if o.observable.startswith("yield") or o.condition_id == "prior":
            continue
        col = SPEED_COLUMN[model.velocity_frame] if o.observable == "v_mean_m_s" \
            else o.observable
        if o.condition_id not in cid_col.groups or col not in runs:
            continue
        v = cid_col.get_group(o.condition_id)[col].to_numpy(float)
        v = v[np.isfinite(v)]
        if len(v) < 2:
            continue
        se = float(np.std(v, ddof=1) / np.sqrt(len(v)))
        rows.append(((float(np.mean(v)) - o.value) / np.hypot(o.sd, se)) ** 2)
    return float(np.sum(rows)), len(rows)


def main(argv=None):
    p = argparse.ArgumentParser(prog="python -m analysis.studies.emulated_loop",
                                description=__doc__.split("\n\n")[0],
                                epilog="example: python -m analysis.studies.emulated_loop "
                                       "--dataset results/open_world/effects/eff_p01")
    p.add_argument("--dataset", default=str(DEFAULT_DATASET), help="a blind dataset folder "
                   "(default %(default)s)")
    from analysis.studies.emulator_check import add_design_options
    add_design_options(p)
    p.add_argument("--waves", type=int, default=2, help="refinement waves [-] "
                   "(default %(default)s)")
    p.add_argument("--per-wave", type=int, default=8, help="design points per refinement "
                   "wave [-] (default %(default)s)")
    p.add_argument("--null-draws", type=int, default=10, help="bootstrap datasets per "
                   "diagnosis step [-] (default %(default)s)")
    p.add_argument("--out", default=None, help="output folder (default "
                   "results/studies/emulated_loop/<dataset>)")
    a = p.parse_args(argv)
    from analysis.atomic_dir import OutputError, check_out_dir, output_dir
    from analysis.measurements import DatasetError, load_dataset
    out = a.out or str(DEFAULT_OUT / Path(a.dataset).name)
    try:
        if min(a.points, a.replicates) < 2 or a.waves < 0 or a.per_wave < 1 or a.workers < 1:
            raise ValueError("--points, --replicates >= 2, --waves >= 0, --per-wave and "
                             "--workers >= 1")
        ds = load_dataset(a.dataset)
        check_out_dir(out, protected=(a.dataset,))
    except (OutputError, DatasetError, ValueError, OSError) as exc:
        print("analysis.studies.emulated_loop: error: %s" % exc, file=sys.stderr)
        return 2
    t0 = time.time()
    rows, steps, params, words = run(ds, a)
    from analysis.report.emulator_pages import emulated_loop_page
    with output_dir(out, protected=(a.dataset,)) as tmp:
        rows["staircase"].to_csv(tmp / "staircase.csv", index=False, float_format="%.5g")
        steps.to_csv(tmp / "steps.csv", index=False, float_format="%.5g")
        params.to_csv(tmp / "parameters.csv", index=False, float_format="%.6g")
        rows["runs"].drop(columns=["config"]).to_csv(tmp / "runs.csv", index=False,
                                                    float_format="%.6g")
        from analysis.studies.emulator_check import rel_path
        (tmp / "README.md").write_text(emulated_loop_page(
            dataset=rel_path(a.dataset), words=words, staircase=rows["staircase"], params=params,
            n_runs=len(rows["runs"]), waves=rows["waves"], wall_s=time.time() - t0,
            fake=a.fake))
    print("\n".join(words))
    print(rows["staircase"].to_string(index=False))
    print(params.to_string(index=False))
    return 0


def run(ds, a):
    """The stages; returns ({staircase, runs, waves}, steps table, parameters table, words)."""
    from analysis.catalog import candidates
    from analysis.diagnose import calibrate_base, profile_interval
    from analysis.emulated_twin import EmulatedTwin, build_in_waves
    from analysis.loop import WithAdded, fit_observations, fitted_parameters, forward_select
    from analysis.studies.emulator_check import design_space, run_plan
    from analysis.twin_model import dataset_observations, reference_parameters, yield_times_of
    base_config = None if a.frame == "lab" else {"frame": a.frame}
    # the FAKE twin writes no trajectory: no impact observables
    obs0, fl_ids, _ = dataset_observations(ds, not a.fake)
    model = EmulatedTwin(ds.conditions, design_space(), velocity_frame=ds.velocity_frame,
                         flight_conditions=fl_ids, yield_times_min=yield_times_of(ds),
                         theta_ref=reference_parameters(), seed=a.seed)

    def simulate(runs):
        return run_plan(runs, a.workers, a.fake)

    model, pts, hist = build_in_waves(model, obs0, simulate, n_initial=a.points,
                                      n_waves=a.waves, per_wave=a.per_wave,
                                      replicates=a.replicates, seed=a.seed,
                                      base_config=base_config, obs_chaos_runs=1.0)
    obs = fit_observations(obs0, model)

    from analysis.flights import FLIGHT_OBSERVABLES
    noise = {"v_mean_m_s", "f_col_hz"} | (set(FLIGHT_OBSERVABLES) if fl_ids else set())

    def analyse(model):
        w = WithAdded(model, {})
        baseline, cal = calibrate_base(model.predict, obs, model.base_params(),
                                       model_se=w.model_se())
        theta = {p.name: cal.params[p.name] for p in model.base_params()}
        fs = forward_select(model, obs, theta, conditions=ds.conditions, alpha=0.01,
                            max_effects=3, noise_observables=noise, log=print,
                            null_draws=a.null_draws)
        final = fs["last_fit"] or cal
        return baseline, cal, fs, final

    nb = len(model.base_params())
    baseline, cal, fs, final = analyse(model)
    stair = [stage_row("baseline", "model", baseline, 0),
             stage_row("calibrated", "model", cal, nb)]
    stair += [dict(r, model="model") for r in fs["stairs"]]
    added = dict(fs["added"])
    theta = {k: float(final.params[k]) for k in fs["theta"]}
    dem_added = {k: v for k, v in added.items() if candidates()[k].kind == "dem"}
    conf = simulate(confirm_runs(model, theta, dem_added, a.replicates, base_config))
    c2, n2 = rerun_chi2(obs, conf, model)
    stair.append({"stage": "twin at the final point", "model": "real twin", "chi2": c2,
                  "dof": n2 - nb - len(added), "chi2_dof": c2 / max(n2 - nb - len(added), 1),
                  "n_params": nb + len(added)})
    # the confirmation runs are design points: refit the emulator, the final fit on it
    model.theta_ref = {k: v for k, v in theta.items() if k in model.theta_ref}
    model.fit(pd.concat([model.runs_, conf], ignore_index=True))
    w = WithAdded(model, added, theta)
    _, final2 = calibrate_base(w.predict, obs, fitted_parameters(model, theta, added),
                               model_se=w.model_se())
    stair.append(stage_row("final (emulator refitted with the confirmation runs)", "model",
                           final2, nb + len(added)))
    truth = truth_of(a.dataset) or {}
    true_base = truth.get("base_config", {})
    from analysis.open_suite import truth_strengths
    true_eff = truth_strengths(truth) if truth else {}
    bp = fitted_parameters(model, {k: final2.params[k] for k in theta},
                      {k: final2.params[k] for k in added})
    prm = []
    for q in bp:
        iv = profile_interval(w.predict, obs, bp, q.name, final2, model_se=w.model_se())
        tv = true_eff.get(q.name, true_base.get(q.name, np.nan))
        prm.append({"name": q.name, "role": "effect" if q.name in added else "base",
                    "value": final2.params[q.name], "se": final2.stderr.get(q.name),
                    "profile_lo": iv.lower, "profile_hi": iv.upper,
                    "open": ("lower " if iv.open_lower else "") + ("upper" if iv.open_upper
                                                                   else ""),
                    "truth": tv, "covered": bool(iv.lower <= tv <= iv.upper)
                    if np.isfinite(tv) else None})
    for k, s in true_eff.items():
        if k not in added:
            prm.append({"name": k, "role": "hidden, not found", "value": 0.0, "truth": s})
    params = pd.DataFrame(prm)
    steps = pd.concat(fs["steps"], ignore_index=True) if fs["steps"] else pd.DataFrame()
    words = ["step %d: %s" % (i + 1, d.verdict) for i, d in enumerate(fs["diagnoses"])]
    words += [
        "effects added: %s" % (", ".join("%s %.3g" % kv for kv in added.items()) or "none"),
        "hidden: %s" % (", ".join("%s %.3g" % kv for kv in true_eff.items()) or "none")]
    runs = model.runs_
    return ({"staircase": pd.DataFrame(stair), "runs": runs, "waves": hist}, steps, params,
            words)


if __name__ == "__main__":
    sys.exit(main())
