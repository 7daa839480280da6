"""The hidden-effect suite: does diagnose name the effect that was hidden in the data?

Every case is a hidden-effect dataset (:func:`analysis.hidden.make_hidden_dataset`) made by the
real twin at the calibrated parameters with one catalog effect switched on (or none), 8 Table-3
conditions x 1 run (the twin's scatter is in the reported sd), plus measurement noise (v 1.5 %, f_col 1 /s, yields 1 percentage
point at 2.5-10 min); several noise seeds per twin data set. Each dataset is diagnosed blind with
the twin model (:mod:`analysis.twin_model`), the verdict's effect is added, and the outcome is
scored against the truth:

* rank-1 rate of the true effect (goal >= 90 %) and how often it is significant;
* the decoy (air drag) reported significant: goal never;
* datasets without a hidden effect: "nothing missing" (goal: all of them);
* chi2/dof calibrated -> with the added effect (goal <= 1.5 from >= 3x that);
* the hidden effect's size: the largest shift of an observable, in sigma, against the twin
  without it (cases must move some observable by >= 3 sigma).

    python -m analysis.hidden_suite [--noise-seeds 5] [--workers 2] [--out results/hidden_suite]

Twin runs are cached (results/runs), so a rerun or a killed suite runs no twin again. The
command builds the suite in a temporary folder beside ``--out`` and swaps it in when complete
(a failed or killed suite leaves the earlier one as it was); a rerun without ``--fresh`` starts
from the earlier suite's rows (suite_rows.csv) and datasets and diagnoses only what is new.
"""
from __future__ import annotations

import argparse
import json
import shutil
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

from analysis.config import RESULTS_DIR
from analysis import twin_model
from analysis.report import hidden_suite_comparison_section, hidden_suite_page

SUITE_DIR = RESULTS_DIR / "hidden_suite"


def suite_cases(dem_fracs=(0.35, 0.7), kin_fracs=(0.5, 0.9), include_null=True):
    """(label, effects spec, true effect or None, strength coordinate) of the suite.

    DEM effects at ``dem_fracs`` of their diagnose range (one twin data set each), kinetics
    effects at ``kin_fracs`` (on the no-effect twin runs), the decoy never hidden (it is
    physically negligible: a dataset with it is a no-effect dataset)."""
    out = []
    if include_null:
        out.append(("none", {}, None, 0.0))
    for c in twin_model.CANDIDATES:
        if c.name in twin_model.DECOYS:
            continue
        for fr in (dem_fracs if c.kind == "dem" else kin_fracs):
            s = fr * c.s_max
            out.append(("%s@%g" % (c.name, fr), c.spec(s), c.name, s))
    return out


def score_case(ds_path, truth_path, model_kwargs, alpha=0.01):
    """Diagnose one dataset blind, add the verdict's effect, score against the truth (a dict)."""
    from analysis.diagnose import add_effect, diagnose
    from analysis.measurements import load_dataset
    ds = load_dataset(ds_path)
    truth = json.loads(Path(truth_path).read_text())
    prob = twin_model.factory(ds, **model_kwargs)
    t0 = time.perf_counter()
    obs = prob.get("observations", ds)
    diag = diagnose(prob["predict"], obs, prob["base_params"], prob["effects"],
                    model_se=prob["model_se"], effect_se=prob.get("effect_se"),
                    crn_correlation=prob["crn_correlation"],
                    noise_observables=prob["noise_observables"], conditions=ds.conditions,
                    alpha=alpha)
    true = [k for k in truth["effects"]]
    true = true[0] if true else None
    tab = diag.table.set_index("effect")
    row = {"dataset": ds.name, "synthetic": ds.synthetic, "true_effect": true or "none",
           "rank1": diag.table.iloc[0]["effect"], "status": diag.status,
           "reported": diag.best or "", "verdict": diag.verdict,
           "chi2_dof_calibrated": diag.calibrated.chi2_dof,
           "chi2_dof_baseline": diag.baseline.chi2_dof,
           "decoy_significant": bool(any(tab.loc[d, "significant"] for d in twin_model.DECOYS
                                         if d in tab.index)),
           "n_significant": int(diag.table["significant"].sum()),
           "true_rank": np.nan, "true_significant": False, "true_strength_fit": np.nan,
           "true_strength_se": np.nan, "chi2_dof_after_add": np.nan}
    if true:
        row.update(true_rank=int(tab.loc[true, "rank"]),
                   true_significant=bool(tab.loc[true, "significant"]),
                   true_strength_fit=float(tab.loc[true, "strength"]),
                   true_strength_se=float(tab.loc[true, "strength_se"]))
    row["shift_sigma_max"] = shift_sigma(prob, ds, truth)
    row["shift_sigma_projected"] = projected_shift_sigma(prob, ds, truth)
    row["n_observables"] = int(len(obs)) if isinstance(obs, pd.DataFrame) else np.nan
    if diag.best:
        add = add_effect(prob["predict"], obs, prob["base_params"], prob["effects"], diag.best,
                         model_se=prob["model_se"], effect_se=prob.get("effect_se"))
        row["chi2_dof_after_add"] = float(add.staircase["chi2_dof"].iloc[-1])
    row["seconds"] = time.perf_counter() - t0
    return row


def truth_values(truth):
    """{(condition_id, observable): noise-free truth} of a hidden dataset's truth file (twin
    means, impact observables of its runs, yields)."""
    true = {}
    for cid, m in truth["twin_means"].items():
        true[(cid, "v_mean_m_s")] = m["v_mean_m_s"]
        true[(cid, "f_col_hz")] = m["f_col_hz"]
        for t, y in zip(truth["kinetics"]["yield_times_min"],
                        truth["kinetics"]["yields_true"].get(cid, [])):
            true[(cid, "yield_pct@%gmin" % t)] = y
    for cid, m in truth.get("twin_flights", {}).items():
        for k, v in m.items():
            true[(cid, k)] = v
    return true


def _truth_problem(prob, ds, truth):
    """A diagnose problem whose observations are the noise-free truth (sd and model noise as in
    the dataset's own problem)."""
    from analysis.diagnose import Problem, observations_from_dataset
    obs = prob.get("observations")
    obs = (observations_from_dataset(ds) if obs is None else obs).copy()
    true = truth_values(truth)
    keep = [(c, o) in true for c, o in zip(obs["condition_id"], obs["observable"])]
    obs = obs[keep].reset_index(drop=True)
    obs["value"] = [true[(c, o)] for c, o in zip(obs["condition_id"], obs["observable"])]
    return Problem(prob["predict"], obs, prob["base_params"], prob["effects"],
                    prob["model_se"], None, 1e-3, None)


def shift_sigma(prob, ds, truth):
    """Largest |truth - twin without the effect| / sigma over the observables: the hidden
    effect's size in units of the comparison's noise (the twin without it = the model at
    theta_ref with the truth's powder line)."""
    pr = _truth_problem(prob, ds, truth)
    theta = dict(prob["model"].theta_ref, slope_pct_per_kj=truth["kinetics"]["slope_pct_per_kj"],
                 intercept_pct=truth["kinetics"]["intercept_pct"])
    theta = {p.name: theta[p.name] for p in prob["base_params"]}
    return float(np.max(np.abs(pr.y - pr.mu(theta, {})) / pr.sigma))


def projected_shift_sigma(prob, ds, truth):
    """The hidden effect's size that no recalibration can absorb: the largest |z| left when the
    base parameters (without any effect) are fitted to the noise-free truth."""
    pr = _truth_problem(prob, ds, truth)
    fit = pr.fit({p.name: p.value for p in prob["base_params"]})
    return float(np.max(np.abs(fit.residuals.to_numpy())))


def inputs():
    """What the suite reads (the signature library, the calibration): never an output."""
    from analysis.config import CALIBRATION_DIR
    return [twin_model.SIGNATURE_DIR, CALIBRATION_DIR]


def run_suite(out_dir=SUITE_DIR, noise_seeds=range(5), twin_seed=7, workers=2, cases=None,
              runner=None, runs_dir=None, library=None, emulator=None, progress=True,
              replicates=1, flights=True):
    """Make, diagnose and score every case x noise seed; returns the rows table.

    ``replicates`` twin runs per condition (default 1: a measurement is one realisation of the
    chaotic mill; the twin's scatter, known from the library's anchor, goes into the reported
    sd). ``flights``: the diagnosis also reads the impact observables of the datasets' jar
    tracks (analysis.flights); False diagnoses on v_mean, f_col and the yields alone."""
    from tqdm.auto import tqdm
    from analysis.hidden import make_hidden_dataset
    out_dir = Path(out_dir)
    ds_root = out_dir / "datasets"
    out_dir.mkdir(parents=True, exist_ok=True)
    rows_file = out_dir / "suite_rows.csv"
    done = read_rows(rows_file) if rows_file.exists() else pd.DataFrame()
    done_names = set(done["dataset"]) if len(done) else set()
    cases = suite_cases() if cases is None else cases
    if library is None:
        library = twin_model.load_library()
    theta_ref = dict(library[1]["theta_ref"])
    if emulator is None:
        emulator = twin_model.base_emulator()
    model_kwargs = {"library": library, "emulator": emulator, "flights": flights}
    if flights:
        model_kwargs["flight_emulator"] = twin_model.flight_emulator()
    anchor = twin_model.TwinModel(pd.DataFrame(library[1]["conditions"]), {},
                                  library=library, emulator=emulator)
    twin_sd = anchor.twin_scatter()
    jobs = [(c, s) for c in cases for s in noise_seeds]
    bar = tqdm(jobs, desc="hidden suite", unit="dataset", disable=not progress)
    for (label, spec, true, s), seed in bar:
        name = "suite_%s_n%d" % (label.replace("@", "_"), seed)
        if name in done_names:
            continue
        ds_path, truth_path = make_hidden_dataset(
            name, spec, replicates=replicates, seed=seed, twin_seed=twin_seed,
            base_config=theta_ref, runner=runner, workers=workers, runs_dir=runs_dir,
            out_dir=ds_root / name, truth_dir=out_dir / "truth", progress=False, **twin_sd)
        row = score_case(ds_path, truth_path, model_kwargs)
        row.update(case=label, noise_seed=seed, strength_true=s)
        done = pd.concat([done, pd.DataFrame([row])], ignore_index=True)
        tmp = rows_file.with_suffix(".tmp")
        done.to_csv(tmp, index=False)
        tmp.replace(rows_file)
    return read_rows(rows_file)


def read_rows(path):
    """The suite table as written (empty 'reported' = nothing reported)."""
    rows = pd.read_csv(path)
    rows["reported"] = rows["reported"].fillna("").astype(str)
    return rows


def summarise(rows: pd.DataFrame) -> dict:
    """The goal figures of a suite table."""
    eff = rows[rows["true_effect"] != "none"]
    nul = rows[rows["true_effect"] == "none"]
    big = eff[eff["shift_sigma_projected"] >= 3.0]
    raw = eff[eff["shift_sigma_max"] >= 3.0]
    added = rows[rows["chi2_dof_after_add"].notna()] if "chi2_dof_after_add" in rows else rows[:0]
    qual = added[added["chi2_dof_calibrated"] >= 4.5]
    out = {"n_datasets": int(len(rows)), "n_effect_datasets": int(len(eff)),
           "n_effect_datasets_ge_3sigma_raw": int(len(raw)),
           "rank1_rate_raw": (float((raw["rank1"] == raw["true_effect"]).mean())
                              if len(raw) else None),
           "n_effect_datasets_ge_3sigma": int(len(big)),
           "rank1_rate": float((big["rank1"] == big["true_effect"]).mean()) if len(big) else None,
           "true_reported_rate": (float((big["reported"] == big["true_effect"]).mean())
                                  if len(big) else None),
           "decoy_significant": int(rows["decoy_significant"].sum()),
           "n_null_datasets": int(len(nul)),
           "null_nothing_missing": int((nul["status"] == "nothing_missing").sum()),
           "n_added": int(len(added)),
           "n_added_from_ge_4.5": int(len(qual)),
           "added_reaching_1.5": int((qual["chi2_dof_after_add"] <= 1.5).sum()),
           "median_seconds_per_diagnosis": float(rows["seconds"].median())}
    return out


def per_effect(rows):
    eff = rows[rows["true_effect"] != "none"].copy()
    eff["rank1_ok"] = eff["rank1"] == eff["true_effect"]
    eff["reported_ok"] = eff["reported"] == eff["true_effect"]
    g = eff.groupby("case", sort=False)
    return g.agg(n=("dataset", "size"), shift_sigma=("shift_sigma_max", "median"),
                 shift_sigma_projected=("shift_sigma_projected", "median"),
                 rank1_rate=("rank1_ok", "mean"), reported_rate=("reported_ok", "mean"),
                 chi2_dof_calibrated=("chi2_dof_calibrated", "median"),
                 chi2_dof_after_add=("chi2_dof_after_add", "median")).reset_index()


def confusion_matrix(rows) -> pd.DataFrame:
    """Share of each hidden effect's datasets by what diagnose reported.

    Rows: the hidden effects in the order of ``rows``; columns: those, then any other reported
    effect (sorted), then 'nothing'; values: fraction of the row's datasets [-]."""
    truths = list(dict.fromkeys(rows["true_effect"]))
    said = [n for n in truths] + sorted(set(rows["reported"].replace("", "nothing"))
                                        - set(truths) - {"nothing"}) + ["nothing"]
    M = np.zeros((len(truths), len(said)))
    for r in rows.itertuples():
        j = said.index(r.reported if r.reported else "nothing")
        M[truths.index(r.true_effect), j] += 1
    M /= np.maximum(M.sum(1, keepdims=True), 1)
    return pd.DataFrame(M, index=truths, columns=said)


def write_report(rows, out_dir=SUITE_DIR, synthetic: bool | None = None):
    """summary.json, per_effect.csv, confusion.png and README.md (the report page).

    ``synthetic``: mark the figure SYNTHETIC; None reads the rows' ``synthetic`` column (each
    dataset's own flag); rows written before that column existed count as synthetic, since the
    suite only scores datasets made by :mod:`analysis.hidden`, which are synthetic."""
    from analysis.plotting.hidden_plots import write_confusion_figure
    out_dir = Path(out_dir)
    summ = summarise(rows)
    pe = per_effect(rows)
    (out_dir / "summary.json").write_text(json.dumps(summ, indent=1))
    pe.to_csv(out_dir / "per_effect.csv", index=False)
    if synthetic is None:
        synthetic = (bool(rows["synthetic"].fillna(True).astype(bool).any())
                     if "synthetic" in rows else True)
    write_confusion_figure(confusion_matrix(rows), out_dir / "confusion.png",
                           synthetic=synthetic)
    (out_dir / "README.md").write_text(hidden_suite_page(summ, pe))
    return summ


def _append_comparison(page, summ, summ0, pe, pe0):
    """Add the same datasets' figures without the jar tracks to the suite page (text:
    :func:`analysis.report.hidden_suite_comparison_section`)."""
    with open(page, "a") as fh:
        fh.write(hidden_suite_comparison_section(summ, summ0, pe, pe0))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 epilog="example: python -m analysis.hidden_suite "
                                 "--noise-seeds 5 --fresh --also-without-tracks")
    ap.add_argument("--noise-seeds", type=int, default=5,
                    help="measurement-noise draws per twin data set, seeds 0..N-1 [seeds] "
                    "(default %(default)s)")
    ap.add_argument("--twin-seed", type=int, default=7,
                    help="seeds the twin runs' start positions [-] (default %(default)s)")
    ap.add_argument("--workers", type=int, default=2,
                    help="parallel twin runs [processes] (default %(default)s)")
    ap.add_argument("--out", default=str(SUITE_DIR),
                    help="output folder (default: results/hidden_suite)")
    ap.add_argument("--fresh", action="store_true", help="forget earlier suite rows")
    ap.add_argument("--no-flights", action="store_true",
                    help="diagnose on v_mean, f_col and yields only (ignore the jar tracks)")
    ap.add_argument("--also-without-tracks", action="store_true",
                    help="then score the same datasets again without the jar tracks (into "
                    "OUT/without_tracks) and put both on the page")
    a = ap.parse_args(argv)
    if a.noise_seeds < 1:
        print("analysis.hidden_suite: error: --noise-seeds must be >= 1", file=sys.stderr)
        return 2
    from analysis.atomic_dir import MARKER, check_out_dir, output_dir
    out = Path(a.out)
    protected = inputs()
    t0 = time.perf_counter()
    try:
        check_out_dir(out, protected)   # before anything is read, removed or run
        with output_dir(out, protected) as tmp:
            if not a.fresh and out.is_dir():
                # resume: the earlier suite's rows and datasets are reused, not recomputed
                shutil.copytree(out, tmp, dirs_exist_ok=True,
                                ignore=lambda d, names: [MARKER] if Path(d) == out else [])
            rows = run_suite(tmp, noise_seeds=range(a.noise_seeds), twin_seed=a.twin_seed,
                             workers=a.workers, flights=not a.no_flights)
            summ = write_report(rows, tmp)
            if a.also_without_tracks and not a.no_flights:
                sub = tmp / "without_tracks"
                rows0 = run_suite(sub, noise_seeds=range(a.noise_seeds), twin_seed=a.twin_seed,
                                  workers=a.workers, flights=False)
                summ0 = write_report(rows0, sub)
                _append_comparison(tmp / "README.md", summ, summ0, per_effect(rows),
                                   per_effect(rows0))
    except (FileNotFoundError, RuntimeError, ValueError) as exc:  # OutputError: ValueError
        print("analysis.hidden_suite: error: %s" % exc, file=sys.stderr)
        return 2
    print(per_effect(rows).to_string(index=False))
    for k, v in summ.items():
        print("%-32s %s" % (k, v))
    print("suite wall time %.0f s (twin runs cached in results/runs)" % (time.perf_counter() - t0))
    return 0


if __name__ == "__main__":
    sys.exit(main())
