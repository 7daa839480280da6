"""The signature library of :mod:`analysis.twin_model`: the twin at the reference parameters
(:func:`reference_parameters`) without effects (the anchor) and with every DEM candidate at its
signature strengths, run (cached), summarised and written to ``results/signatures``
(:func:`build_library`, :func:`refresh_flights`), read back (:func:`load_library`) and matched to
a dataset's conditions (:func:`library_at`); the impact pattern rule (:func:`in_late_pattern`).

    python -m analysis.twin_model --build [--replicates 2] [--workers 2]   # the library
    python -m analysis.twin_model --flights      # impact observables of its cached runs
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd

from analysis.config import PAPER_TABLE3_DIR, RESULTS_DIR
from analysis.run_configs import condition_runs
from analysis.catalog import CANDIDATES

SIGNATURE_DIR = RESULTS_DIR / "signatures"
CALIBRATION_DIR = RESULTS_DIR / "calibration"
DESIGN_FLIGHTS_FILE = "design_flights.csv"
#: a run whose approach speed (analysis.flights v_in) is below this fraction of the anchor's at
#: its condition is in the 'late' impact pattern (the ball meets a wall moving its way)
LATE_V_IN_FRAC = 0.6   # impact observables of the calibration's runs


def reference_parameters(calibration_dir=CALIBRATION_DIR):
    """theta_ref: the calibration's posterior mean (restitution, static_friction,
    rolling_friction, amplitude_m), rounded to 4 significant digits (stable run ids)."""
    p = Path(calibration_dir) / "summary.json"
    if not p.exists():
        raise FileNotFoundError("%s missing: run the calibration first (make calibrate)" % p)
    params = json.loads(p.read_text())["params"]
    return {k: float("%.4g" % v) for k, v in params.items()}


# --------------------------------------------------------------------------- the library

def library_configs(conditions, theta_ref, replicates=2, seed0=0, base=None,
                    anchor_replicates=None, levels=None):
    """(label, effect, strength, condition_id, config) rows of the signature library: the anchor
    (label 'none', ``anchor_replicates`` seeds, default ``replicates``) and every DEM candidate
    at each of its signature strengths (``levels`` x s_max; default each candidate's
    ``signature_levels``) with the first ``replicates`` of the same seeds (more where the
    candidate asks for more: ``Candidate.replicates``)."""
    rows = []
    variants = [("none", None, 0.0, None, anchor_replicates or replicates)]
    variants += [(c.name, c.name, fr * c.s_max, c.spec(fr * c.s_max),
                  max(replicates, c.replicates or 0)) for c in CANDIDATES
                 if c.kind == "dem" for fr in (levels or c.signature_levels)]
    for label, eff, s, spec, n_seeds in variants:
        seeds = [seed0 + k for k in range(n_seeds)]
        rows += [(label, eff, s, r.condition_id, r.config) for r in
                 condition_runs(conditions, seeds, theta_ref, base, spec, stated_stroke=False)]
    return rows


def in_late_pattern(v_in_m_s, anchor_v_in_m_s):
    """True where a run's (or a track's) approach speed is below LATE_V_IN_FRAC x the library
    anchor's at its condition: the 'late' impact pattern (the ball meets a wall moving its way).
    The one rule that classes library runs, measured tracks and verification reruns alike."""
    return np.asarray(v_in_m_s, float) < LATE_V_IN_FRAC * np.asarray(anchor_v_in_m_s, float)


from analysis.twin_runs import run_flights  # noqa: E402,F401  (one declaration)


def add_flight_columns(runs: pd.DataFrame, runs_dir=None) -> pd.DataFrame:
    """``runs`` with the impact observables of its run ids as columns (recomputed)."""
    from analysis.flights import FLIGHT_OBSERVABLES
    fl = run_flights(list(runs["run_id"]), runs_dir)
    out = runs.drop(columns=[c for c in FLIGHT_OBSERVABLES if c in runs.columns])
    return pd.concat([out.reset_index(drop=True),
                      fl[list(FLIGHT_OBSERVABLES)].reset_index(drop=True)], axis=1)


def summarise_library(runs: pd.DataFrame) -> pd.DataFrame:
    """Per (label, strength, condition): mean, sd and n of v_mean and f_col (and of the impact
    observables when ``runs`` has them: columns <name> and <name>_sd), and the change from the
    anchor (dv_pct, df_col_hz)."""
    from analysis.flights import FLIGHT_OBSERVABLES
    g = runs.groupby(["label", "strength", "condition_id"], sort=False)
    aggs = dict(n=("v_mean_m_s", "size"),
                v_mean_m_s=("v_mean_m_s", "mean"), v_sd_m_s=("v_mean_m_s", "std"),
                f_col_hz=("f_col_hz", "mean"), f_col_sd_hz=("f_col_hz", "std"))
    for k in FLIGHT_OBSERVABLES:
        if k in runs.columns:
            aggs[k] = (k, "mean")
            aggs[k + "_sd"] = (k, "std")
    s = g.agg(**aggs).reset_index()
    a = s[s["label"] == "none"].set_index("condition_id")
    s["dv_pct"] = 100 * (s["v_mean_m_s"] / a.loc[s["condition_id"], "v_mean_m_s"].to_numpy() - 1)
    s["df_col_hz"] = s["f_col_hz"] - a.loc[s["condition_id"], "f_col_hz"].to_numpy()
    if "v_in_m_s" in runs.columns and runs["v_in_m_s"].notna().any():
        # impact pattern of each run: 'late' when the ball meets the wall at less than
        # LATE_V_IN_FRAC of the anchor's approach speed there (jar compliance makes the flight
        # bistable: 4.4 against 1.3 m/s at 30 Hz, 20.6 mm); a level whose seeds differ is
        # averaged over two motions - flagged, never silent
        ref = a["v_in_m_s"]
        late = pd.Series(in_late_pattern(runs["v_in_m_s"], ref.reindex(runs["condition_id"])),
                         index=runs.index)
        n_late = late.groupby([runs["label"], runs["strength"], runs["condition_id"]]).sum()
        key = pd.MultiIndex.from_frame(s[["label", "strength", "condition_id"]])
        s["n_late_pattern"] = n_late.reindex(key).to_numpy().astype(int)
        cols = ["v_mean_m_s", "f_col_hz"] + [k for k in FLIGHT_OBSERVABLES if k in runs.columns]
        pat = np.where(late, "late", "normal")
        for p in ("normal", "late"):
            m = runs[pat == p].groupby(["label", "strength", "condition_id"])[cols].mean()
            m = m.reindex(key)
            for c in cols:
                s[c + "@" + p] = m[c].to_numpy()
    return s


def build_library(out_dir=SIGNATURE_DIR, replicates=2, workers=2, runs_dir=None, runner=None,
                  conditions=None, theta_ref=None, base=None, anchor_replicates=4,
                  levels=None):
    """Run (cached) and write the signature library: signature_runs.csv, signatures.csv,
    signatures.png, library.json. Returns the summary table."""
    from analysis.atomic_dir import output_dir
    from analysis.measurements import load_dataset
    from analysis.sweep import run_sweep

    if conditions is None:
        conditions = load_dataset(PAPER_TABLE3_DIR).conditions
    theta_ref = dict(theta_ref or reference_parameters())
    rows = library_configs(conditions, theta_ref, replicates=replicates, base=base,
                           anchor_replicates=max(anchor_replicates or 0, replicates),
                           levels=levels)
    res = run_sweep([r[4] for r in rows], runner=runner, workers=workers, runs_dir=runs_dir)
    if not res.ok:
        raise RuntimeError("signature library: %d twin run(s) failed:\n%s"
                           % (res.n_failed, res.failed()[["run_id", "error"]].to_string()))
    t = res.table.reset_index(drop=True)
    runs = pd.DataFrame({"label": [r[0] for r in rows], "strength": [r[2] for r in rows],
                         "condition_id": [r[3] for r in rows],
                         "seed": [r[4]["seed"] for r in rows]})
    for c in ("frequency_hz", "ball_diameter_m", "v_mean_m_s", "f_col_hz", "motion_mode",
              "run_id"):
        if c in t.columns:
            runs[c] = t[c].to_numpy()
    runs = add_flight_columns(runs, runs_dir)
    summ = summarise_library(runs)
    design = design_flights(runs_dir=runs_dir)
    out_dir = Path(out_dir)
    with output_dir(out_dir) as tmp:
        if design is not None:
            design.to_csv(tmp / DESIGN_FLIGHTS_FILE, index=False)
        runs.to_csv(tmp / "signature_runs.csv", index=False)
        summ.to_csv(tmp / "signatures.csv", index=False)
        meta = {"theta_ref": theta_ref, "replicates": replicates,
                "anchor_replicates": max(anchor_replicates or 0, replicates),
                "levels": {c.name: list(levels or c.signature_levels) for c in CANDIDATES
                           if c.kind == "dem"},
                "base_config": base or {},
                "candidates": [c.__dict__ | {"fixed": dict(c.fixed)} for c in CANDIDATES],
                "conditions": conditions[["condition_id", "frequency_hz",
                                          "ball_diameter_mm"]].to_dict("records")}
        (tmp / "library.json").write_text(json.dumps(meta, indent=1))
        plot_library(summ, tmp / "signatures.png")
        write_page(summ, meta, tmp)
    return summ


def design_flights(calibration_dir=CALIBRATION_DIR, runs_dir=None):
    """The calibration's design runs (inputs) with their impact observables, or None when the
    calibration has no design table: the training set of the impact observables' GP."""
    p = Path(calibration_dir) / "design_runs.csv"
    if not p.exists():
        return None
    d = pd.read_csv(p)
    d = d[d["run_id"].notna()].reset_index(drop=True)
    keep = ["restitution", "static_friction", "rolling_friction", "amplitude_m",
            "frequency_hz", "ball_diameter_m", "seed", "motion_mode", "run_id"]
    return add_flight_columns(d[[c for c in keep if c in d.columns]], runs_dir)


def refresh_flights(lib_dir=SIGNATURE_DIR, runs_dir=None, calibration_dir=CALIBRATION_DIR):
    """Recompute the impact observables of an existing library's runs (no new twin runs):
    rewrites signature_runs.csv, signatures.csv and design_flights.csv."""
    lib_dir = Path(lib_dir)
    f = lib_dir / "signature_runs.csv"
    if not f.exists():
        raise FileNotFoundError("signature library %s missing: run `make signatures`" % f)
    runs = add_flight_columns(pd.read_csv(f), runs_dir)
    summ = summarise_library(runs)
    design = design_flights(calibration_dir, runs_dir)
    for name, table in (("signature_runs.csv", runs), ("signatures.csv", summ),
                        (DESIGN_FLIGHTS_FILE, design)):
        if table is None:
            continue
        tmp = lib_dir / (name + ".tmp")
        table.to_csv(tmp, index=False)
        tmp.replace(lib_dir / name)
    meta = json.loads((lib_dir / "library.json").read_text())
    write_page(summ, meta, lib_dir)
    return summ


def top_level(summ):
    """The library summary at each label's largest strength (the anchor and one signature per
    effect)."""
    top = summ.groupby("label", sort=False)["strength"].transform("max")
    return summ[summ["strength"] == top].reset_index(drop=True)


def plot_library(summ, path):
    """Write the library's figure to ``path`` (PNG): change of v_mean [%] per condition for
    every DEM effect at its signature strength, with the anchor's +-2 se band (drawn by
    :func:`analysis.plotting.signature_plots.write_signatures_figure`)."""
    from analysis.plotting.signature_plots import write_signatures_figure
    write_signatures_figure(top_level(summ), path)


def write_page(summ, meta, folder):
    """README.md of the library (text: :func:`analysis.report.signatures_page`)."""
    from analysis.report import signatures_page
    (Path(folder) / "README.md").write_text(signatures_page(summ, top_level(summ), meta,
                                                            LATE_V_IN_FRAC))


def library_at(conditions, library):
    """The library's summary rows at ``conditions``, matched by physics (frequency, ball
    diameter, stroke where stated - never by the id text) and relabelled with the dataset's
    condition ids. Raises ValueError naming the conditions the library has no runs at."""
    from analysis.conditions import label, match_conditions, physics_table
    summ, meta = library
    if meta.get("conditions"):
        amp_mm = 1e3 * float(meta["theta_ref"]["amplitude_m"])
        m = match_conditions(conditions, pd.DataFrame(meta["conditions"]),
                             default_amplitude_mm=amp_mm)
    else:       # a library that does not state its physics: ids are all there is
        ids = set(summ["condition_id"])
        m = {c: (c if c in ids else None) for c in conditions["condition_id"]}
    missing = [c for c, k in m.items() if k is None]
    if missing:
        ph = physics_table(conditions).set_index("condition_id")
        words = ["%s (%s)" % (c, label(ph.loc[c, "frequency_hz"], ph.loc[c, "ball_diameter_mm"],
                                       ph.loc[c, "amplitude_mm"])) for c in missing]
        raise ValueError("the signature library has no runs at condition(s) %s; `python -m "
                         "analysis.loop --dataset DIR` builds the runs a dataset's conditions "
                         "need" % ", ".join(words))
    parts = []
    for cid, lib_id in m.items():
        parts.append(summ[summ["condition_id"] == lib_id].assign(condition_id=cid))
    return pd.concat(parts, ignore_index=True)


def load_library(lib_dir=SIGNATURE_DIR):
    """(summary table, library.json dict) of a built signature library."""
    lib_dir = Path(lib_dir)
    f = lib_dir / "signatures.csv"
    if not f.exists():
        raise FileNotFoundError("signature library %s missing: run `make signatures`" % f)
    return pd.read_csv(f), json.loads((lib_dir / "library.json").read_text())
