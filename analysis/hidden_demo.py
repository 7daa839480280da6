"""make hidden-demo: hide an effect in twin data, find it blind, add it, watch the error fall.

1. **hide**: a secret seed picks one catalog effect (never the decoy) and a strength; the real
   twin makes a measurement dataset with it at the 8 Table-3 conditions (v_mean, f_col and yields
   at 2.5-10 min, with measurement noise); the truth is sealed in a separate file;
2. **compare** the calibrated twin (effects off) with the dataset: residuals, chi2/dof, heat map,
   the failures in words;
3. **diagnose** every catalog effect with the twin model (:mod:`analysis.twin_model`) and
   **add** the verdict's effect (base parameters and strength refitted);
4. **verify** on the real twin: rerun it at the refitted parameters with the added effect and
   compare again (the error must fall with the twin, not only with its emulator);
5. **reveal** the truth beside the verdict; a one-page report ``report.md`` with the figures.

    python -m analysis.hidden_demo [--secret-seed 2026] [--effect name:param=value] [--out DIR]

Twin runs are cached; the first run of the demo makes ~32 runs (~6 min on 2 idle cores).
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

from analysis.config import HIDDEN_DEMO_DIR
from analysis import twin_model
from analysis.report import hidden_demo_page
from analysis.run_configs import condition_runs



def secret_choice(secret_seed):
    """(effects spec, effect name, strength) picked by ``secret_seed``: a non-decoy candidate at
    60-90 % of its diagnose range."""
    rng = np.random.default_rng(secret_seed)
    pool = [c for c in twin_model.CANDIDATES if c.name not in twin_model.DECOYS]
    c = pool[int(rng.integers(len(pool)))]
    s = float("%.3g" % (c.s_max * rng.uniform(0.6, 0.9)))
    return c.spec(s), c.name, s


def predictions_table(model, theta, effects=None):
    """compare-style predictions (condition_id, observable, mean, sd, n_replicates, time_min) of
    the twin model; sd is the per-run sd (se * sqrt(n)), for the impact observables of jar
    tracks (analysis.flights) too."""
    mu = model.predict(theta, effects or {})
    se = model.model_se(theta)
    rows = []
    for (cid, obs), m in mu.items():
        t = np.nan
        if obs.startswith("yield_pct@"):
            t = float(obs.split("@")[1][:-3])
            obs = "yield_pct"
        rows.append({"condition_id": cid, "observable": obs, "mean": float(m),
                     "sd": float(se[(cid, obs if obs != "yield_pct" else "yield_pct@%gmin" % t)])
                     * math.sqrt(model.n_rep),
                     "n_replicates": int(model.n_rep), "time_min": t})
    return pd.DataFrame(rows)


def runs_in_pattern(condition_ids, v_in_m_s, patterns, anchor_v_in_m_s):
    """Boolean mask of the runs to keep: those in their condition's measured impact pattern
    ('late' when the approach speed is below LATE_V_IN_FRAC x the anchor's there), or all of a
    condition's runs when none is in it."""
    cid = pd.Series(list(condition_ids))
    ref = pd.Series(anchor_v_in_m_s).reindex(cid).to_numpy(float)
    late = twin_model.in_late_pattern(v_in_m_s, ref)
    want = np.array([patterns.get(c, "normal") == "late" for c in cid])
    match = late == want
    has = pd.Series(match).groupby(cid).transform("any").to_numpy()
    return match | ~has


def twin_predictions(conditions, theta, dem_effects, kin_spec, slope, intercept, yield_times,
                     replicates=2, workers=2, seed0=500, runs_dir=None, runner=None,
                     flights=False, patterns=None, library=None):
    """compare-style predictions from real twin runs (mean and sd over ``replicates`` seeds);
    yields from the runs' mean E_kin and f_col through the powder line or a kinetics effect;
    with ``flights`` also the impact observables of the runs' recordings (analysis.flights;
    rows with those observable names, none for runs without a trajectory). With ``patterns``
    (condition_id -> 'normal' / 'late', the measured impact pattern, see
    :func:`analysis.twin_model.impact_patterns`) a condition takes only its runs in that pattern
    when it has any (jar compliance makes the flight bistable: two motions are never
    averaged); ``library`` gives the anchor's approach speeds that class a run."""
    from effects import load_effects
    from analysis import kinetics
    from analysis.sweep import run_sweep
    runs = condition_runs(conditions, [seed0 + k for k in range(replicates)], theta,
                          effects=dem_effects, stated_stroke=False)
    cfgs, owner = [r.config for r in runs], [r.condition_id for r in runs]
    res = run_sweep(cfgs, runner=runner, workers=workers, runs_dir=runs_dir)
    if not res.ok:
        raise RuntimeError("verification runs failed:\n%s" % res.failed()[["run_id", "error"]])
    t = res.table.reset_index(drop=True).assign(condition_id=owner)
    fl_all = twin_model.run_flights(list(t["run_id"]), runs_dir) if flights else None
    if flights and patterns:
        summ, _ = library if library is not None else twin_model.load_library()
        ref = summ[summ["label"] == "none"].set_index("condition_id")["v_in_m_s"]
        keep = runs_in_pattern(t["condition_id"], fl_all["v_in_m_s"], patterns, ref)
        t, fl_all = t[keep].reset_index(drop=True), fl_all[keep].reset_index(drop=True)
    kin = load_effects(kin_spec, side="kinetics") if kin_spec else []
    rows = []
    cond = conditions.set_index("condition_id")
    for cid, g in t.groupby("condition_id", sort=False):
        for obs in ("v_mean_m_s", "f_col_hz"):
            rows.append({"condition_id": cid, "observable": obs, "mean": g[obs].mean(),
                         "sd": g[obs].std(ddof=1) if len(g) > 1 else np.nan,
                         "n_replicates": len(g), "time_min": np.nan})
        m = kinetics.ball_mass_kg(float(cond.loc[cid, "ball_diameter_mm"]) * 1e-3)
        v, f = g["v_mean_m_s"].mean(), g["f_col_hz"].mean()
        e_kin = 0.5 * m * v * v
        for tm in yield_times.get(cid, []):
            ts = 60.0 * tm
            x = (kin[0].yield_pct(e_kin, f, ts, slope, intercept) if kin
                 else slope * e_kin * f * ts / 1000.0 + intercept)
            v_sd = g["v_mean_m_s"].std(ddof=1) if len(g) > 1 else 0.0
            f_sd = g["f_col_hz"].std(ddof=1) if len(g) > 1 else 0.0
            x_sd = slope * ts / 1000.0 * math.hypot(m * v * f * v_sd, e_kin * f_sd)
            rows.append({"condition_id": cid, "observable": "yield_pct", "mean": float(x),
                         "sd": float(x_sd), "n_replicates": len(g), "time_min": float(tm)})
        if flights:
            fl = fl_all[fl_all["run_id"].isin(g["run_id"])].dropna()
            for k in (c for c in fl.columns if c != "run_id"):
                if len(fl):
                    rows.append({"condition_id": cid, "observable": k, "mean": fl[k].mean(),
                                 "sd": fl[k].std(ddof=1) if len(fl) > 1 else np.nan,
                                 "n_replicates": len(fl), "time_min": np.nan})
    return pd.DataFrame(rows)


def rerun_chi2(observations, pred, n_fitted):
    """chi2, dof of a diagnose observations table against twin-rerun predictions (mean, sd of
    a run, n_replicates per key; yields keyed 'yield_pct@<t>min'): sigma combines the measured sd
    and the rerun mean's se; keys the rerun lacks are left out."""
    p = pred.copy()
    p["key"] = [o if o != "yield_pct" else "yield_pct@%gmin" % t
                for o, t in zip(p["observable"], p["time_min"])]
    p = p.set_index(["condition_id", "key"])
    z = []
    for r in observations.itertuples():
        k = (r.condition_id, r.observable)
        if k not in p.index:
            continue
        q = p.loc[k]
        se = float(q["sd"]) / math.sqrt(float(q["n_replicates"])) if np.isfinite(q["sd"]) else 0.0
        z.append((r.value - float(q["mean"])) / math.hypot(r.sd, se))
    z = np.asarray(z)
    return float(np.sum(z ** 2)), int(len(z) - n_fitted)


def run_demo(out_dir=HIDDEN_DEMO_DIR, secret_seed=2026, effect_spec=None, say=print, **kw):
    """The whole loop; returns a dict of its figures (also written to summary.json).

    Everything is written to a staging folder beside ``out_dir`` and moved onto it at the end, so
    a failed run (bad effect, failed twin run) leaves the previous demo untouched. Keywords:
    workers, replicates, noise_seed, verify, runner, runs_dir, library, emulator."""
    from effects import load_effects
    from analysis.atomic_dir import output_dir
    if effect_spec is not None:
        load_effects(effect_spec)            # unknown effect / parameter: fail before any work
    final = Path(out_dir)
    with output_dir(final) as work:
        summary = _run_demo(work, secret_seed=secret_seed, effect_spec=effect_spec, say=say,
                            **kw)
    say("wrote %s/report.md (%.0f s)" % (final, summary["times"]["total_s"]))
    return summary


def _run_demo(out_dir, secret_seed=2026, effect_spec=None, workers=2, replicates=2,
              noise_seed=11, verify=True, runner=None, runs_dir=None, library=None,
              emulator=None, say=print):
    from analysis.compare import compare, write_report as write_compare
    from analysis.diagnose import add_effect, diagnose, write_diagnosis
    from analysis.hidden import make_hidden_dataset
    from analysis.measurements import load_dataset
    from analysis.plotting.hidden_plots import write_overview_figure

    t_start = time.perf_counter()
    out_dir = Path(out_dir)
    library = library or twin_model.load_library()
    theta_ref = dict(library[1]["theta_ref"])
    if effect_spec is None:
        effect_spec, _, _ = secret_choice(secret_seed)
    times = {}

    say("1/5 hide: the twin makes a dataset with a secret effect (truth sealed apart)")
    t0 = time.perf_counter()
    ds_path, truth_path = make_hidden_dataset(
        "hidden_demo", effect_spec, replicates=replicates, seed=noise_seed,
        base_config=theta_ref, runner=runner, workers=workers, runs_dir=runs_dir,
        out_dir=out_dir / "dataset", truth_dir=out_dir / "sealed")
    times["hide_s"] = time.perf_counter() - t0
    ds = load_dataset(ds_path)

    say("2/5 compare: the calibrated twin against the dataset")
    t0 = time.perf_counter()
    prob = twin_model.factory(ds, library=library, emulator=emulator)
    model = prob["model"]
    theta0 = {p.name: p.value for p in prob["base_params"]}
    cmp0 = compare(ds, predictions_table(model, theta0))
    write_compare(cmp0, ds, out_dir / "compare_before")
    say("   " + cmp0.summary(2.0).replace("\n", "\n   "))

    say("3/5 diagnose: which catalog effect explains the misfit?")
    obs = prob.get("observations", ds)
    diag = diagnose(prob["predict"], obs, prob["base_params"], prob["effects"],
                    model_se=prob["model_se"], effect_se=prob.get("effect_se"),
                    crn_correlation=prob["crn_correlation"],
                    noise_observables=prob["noise_observables"], conditions=ds.conditions)
    say("   " + diag.verdict)
    added = None
    if diag.best:
        say("4/5 add %s: refit the base parameters and its strength" % diag.best)
        added = add_effect(prob["predict"], obs, prob["base_params"], prob["effects"], diag.best,
                           model_se=prob["model_se"], effect_se=prob.get("effect_se"))
        say("   " + added.summary())
    else:
        say("4/5 nothing to add")
    write_diagnosis(diag, out_dir / "diagnose", added, ds.name, synthetic=ds.synthetic)
    times["compare_diagnose_add_s"] = time.perf_counter() - t0

    verify_row = None
    if verify and added is not None:
        say("   verify on the real twin at the refitted parameters with %s" % added.effect)
        t0 = time.perf_counter()
        p = added.after.params
        theta = dict(theta_ref, **{k: float("%.4g" % p[k]) for k in theta_ref if k in p})
        cand = twin_model.candidates()[added.effect]
        s = float(p[added.effect])
        spec = cand.spec(s) if s > 0 else {}
        dem = spec if cand.kind == "dem" else {}
        kin = spec if cand.kind == "kinetics" else {}
        pred = twin_predictions(ds.conditions, theta, dem, kin, p.get("slope_pct_per_kj", 0.0),
                                p.get("intercept_pct", 0.0), model.yield_times_min,
                                replicates=replicates, workers=workers, runner=runner,
                                runs_dir=runs_dir, flights=bool(model.flight_conditions),
                                patterns=prob.get("patterns"), library=library)
        n_fit = len(prob["base_params"]) + 1
        cmp1 = compare(ds, pred, n_fitted_params=n_fit)
        write_compare(cmp1, ds, out_dir / "compare_after_twin")
        # the staircase's chi2 is over diagnose's observations (impact observables included)
        chi2, dof = rerun_chi2(obs, pred, n_fit)
        verify_row = {"stage": "with %s (twin rerun)" % added.effect, "chi2": chi2,
                      "dof": dof, "chi2_dof": chi2 / max(dof, 1)}
        times["verify_s"] = time.perf_counter() - t0
        say("   twin rerun: chi2/dof %.2f" % verify_row["chi2_dof"])

    say("5/5 reveal")
    truth = json.loads(Path(truth_path).read_text())
    true_name = next(iter(truth["effects"]), None)
    true_s = (twin_model.candidates()[true_name].strength_of(
        next(iter(truth["effects"][true_name].values()))) if true_name else 0.0)
    tab = diag.table.set_index("effect")
    reveal = {"hidden_effect": true_name, "hidden_params": truth["effects"].get(true_name),
              "hidden_strength": true_s, "reported": diag.best, "status": diag.status,
              "true_rank": int(tab.loc[true_name, "rank"]) if true_name in tab.index else None,
              "fitted_strength": float(tab.loc[true_name, "strength"]) if true_name in tab.index
              else None,
              "fitted_strength_se": float(tab.loc[true_name, "strength_se"])
              if true_name in tab.index else None,
              "found": diag.best == true_name}
    stair = added.staircase.copy() if added is not None else pd.DataFrame(
        [{"stage": "calibrated", "chi2": diag.calibrated.chi2, "dof": diag.calibrated.dof,
          "chi2_dof": diag.calibrated.chi2_dof}])
    if verify_row:
        stair = pd.concat([stair, pd.DataFrame([verify_row])], ignore_index=True)
    stair.to_csv(out_dir / "staircase.csv", index=False)
    write_overview_figure(cmp0, stair, ds, out_dir / "overview.png")
    times["total_s"] = time.perf_counter() - t_start
    summary = {"reveal": reveal, "staircase": stair.to_dict("records"), "times": times,
               "verdict": diag.verdict}
    (out_dir / "summary.json").write_text(json.dumps(summary, indent=1, default=str))
    _write_page(out_dir, ds, cmp0, diag, added, stair, reveal, times, truth)
    say("   hidden: %s %s (strength %.3g); reported: %s -> %s"
        % (true_name, truth["effects"].get(true_name), true_s, diag.best,
           "FOUND" if reveal["found"] else "NOT FOUND"))
    return summary


def _write_page(out_dir, ds, cmp0, diag, added, stair, reveal, times, truth):
    """report.md of the demo (text: :func:`analysis.report.hidden_demo_page`)."""
    (Path(out_dir) / "report.md").write_text(hidden_demo_page(cmp0, diag, added, stair, reveal,
                                                              times))


def main(argv=None):
    from analysis.hidden import parse_effect
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 epilog="example: python -m analysis.hidden_demo "
                                 "--secret-seed 2026 --out results/hidden_demo")
    ap.add_argument("--secret-seed", type=int, default=2026,
                    help="picks the hidden effect and strength [-] (default %(default)s)")
    ap.add_argument("--effect", help="hide this effect instead (name:param=value; value in "
                    "the unit its effect declares [effects/<name>.py 'unit'])")
    ap.add_argument("--noise-seed", type=int, default=11,
                    help="seeds the dataset's measurement noise [-] (default %(default)s)")
    ap.add_argument("--workers", type=int, default=2,
                    help="parallel twin runs [processes] (default %(default)s)")
    ap.add_argument("--no-verify", action="store_true", help="skip the twin rerun")
    ap.add_argument("--out", default=str(HIDDEN_DEMO_DIR),
                    help="output folder (default: results/hidden_demo)")
    a = ap.parse_args(argv)
    try:
        spec = dict([parse_effect(a.effect)]) if a.effect else None
        run_demo(a.out, secret_seed=a.secret_seed, effect_spec=spec, workers=a.workers,
                 noise_seed=a.noise_seed, verify=not a.no_verify)
    except (FileNotFoundError, RuntimeError, ValueError) as exc:
        print("analysis.hidden_demo: error: %s" % exc, file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except KeyboardInterrupt as exc:          # SIGINT / SIGTERM: one line, 130 / 143
        from analysis.sweep import interrupted_exit
        sys.exit(interrupted_exit("analysis.hidden_demo", exc))
