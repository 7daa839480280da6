"""What makes v/f fall in a rigid harmonic jar: the change of v/f from 22.5 to 30 Hz, variant by
variant, with its standard error from the seed scatter; and how a mean speed is defined.

The paper's EDEM column (Table 3) has v/f (mean speed over mill frequency) falling 6.9 % from
22.5 to 30 Hz for the 17.5 mm ball and 4.2 % for the 20.6 mm one; the default twin's is flat.
At the paper's contact parameters (C_R 0.11, SF 0.7, RF 0.5; jar frame, as
:mod:`analysis.studies.apparatus_screen`), each variant changes ONE thing from the default twin
- a group the motion depends on (g / (A w^2) through the stroke, d / D through the jar diameter,
(L - d) / A through the jar length, the end shape from a small fillet to a dome), a contact
parameter, the rolling model, the drive (straight or on the arm's arc) - or a pair of them, and
runs both balls at 22.5 and 30 Hz with ``--seeds`` start positions each (cached by run id
through :class:`analysis.twin_runs.TwinRuns`; a kill loses at most the running run, the same
command resumes).

Per variant and ball: the relative change of v/f from 22.5 to 30 Hz [%] (:func:`trend`: the
difference of the mean log v/f of the two frequencies, pooled seed sd, Student t with its
degrees of freedom), the shift from the default, and whether the variant - or the same lever
scaled (:func:`lever_reach`) - gives EDEM's -6.9 % and -4.2 % at once. Only runs in end-to-end
flight (the mode the paper measured) enter; the others are counted.

Second table: several definitions of "the mean speed" (:func:`speed_definitions`: time average
over saved frames of the 3-D speed or of |v_x|, with and without the time in contact, the jar
frame, speeds saved every 5 / 10 ms, chords between positions saved every 5 / 10 ms) measured on
the default twin's recordings, each with its own 22.5 -> 30 Hz change; and the same for every
variant (``definitions_by_variant.csv``: which mechanism read with which definition gives
EDEM's pair).

    python -m analysis.studies.vf_trend --out results/studies/vf_trend [--workers 1]
        [--seeds 3] [--dry-run] [--variants NAME ...] [--runs-only | --cached-only]

Writes (atomically, :func:`analysis.atomic_dir.output_dir`) the files of :data:`OUT_FILES`
into ``--out``.
"""
from __future__ import annotations

import argparse
import functools
import math
import sys
from pathlib import Path

import numpy as np
import pandas as pd

PROG = "python -m analysis.studies.vf_trend"
#: the contact parameters of the paper (Table 2), as in the apparatus screen
PAPER_CONTACT = {"restitution": 0.11, "static_friction": 0.7, "rolling_friction": 0.5}
FREQUENCIES_HZ = (22.5, 30.0)
DIAMETERS_MM = (17.5, 20.6)
#: the paper's EDEM column (Table 3): mean speed [m/s] at 22.5 and 30 Hz per ball, its v/f [mm]
#: and the change of v/f [%] (-6.9 % and -4.2 %)
EDEM_V_M_S = {17.5: (2.07, 2.57), 20.6: (1.95, 2.49)}
EDEM_VF_MM = {d: tuple(1e3 * v / f for v, f in zip(vs, (22.5, 30.0)))
              for d, vs in EDEM_V_M_S.items()}
EDEM_TREND_PCT = {d: 100.0 * (b / a - 1.0) for d, (a, b) in EDEM_VF_MM.items()}
#: "gives EDEM's trend": both balls within this many percentage points (issue 26's goal)
MATCH_POINTS = 2.0
#: the parametric default jar (the committed STL's dimensions, D 28 mm, 25 mL)
D_DEFAULT_M = 0.028
_PARAM_JAR = {"jar_inner_diameter_m": D_DEFAULT_M}
_ARC = lambda c: {"frame": "lab", "effects": {"arc_motion": {"curvature_1_m": c, "tilt": 0.0}}}  # noqa: E731

#: the variants, in run order (the priority when time is short: one level of every group
#: first, then second levels, the arc, the pairs): name -> (group, change of the run config
#: from the default twin at the paper's contact parameters in the jar frame)
VARIANTS = {
    "default": ("default", {}),
    "fillet 10 mm": ("end shape", {**_PARAM_JAR, "jar_fillet_radius_m": 0.010}),
    "fillet 13 mm (domed)": ("end shape", {**_PARAM_JAR, "jar_fillet_radius_m": 0.013}),
    "A 12 mm": ("g/(A w^2)", {"amplitude_m": 0.012}),
    "restitution 0.3": ("restitution", {"restitution": 0.3}),
    "rolling constant_torque (EDEM)": ("rolling model", {"rolling_model": "constant_torque"}),
    "D 32 mm": ("d/D", {"jar_inner_diameter_m": 0.032}),
    "L 50 mm": ("(L-d)/A", {**_PARAM_JAR, "jar_inner_length_m": 0.050}),
    "static friction 0.3": ("friction", {"static_friction": 0.3}),
    "rolling friction 0.1": ("friction", {"rolling_friction": 0.1}),
    "fillet 2 mm": ("end shape", {**_PARAM_JAR, "jar_fillet_radius_m": 0.002}),
    "A 15 mm": ("g/(A w^2)", {"amplitude_m": 0.015}),
    "D 24 mm": ("d/D", {"jar_inner_diameter_m": 0.024}),
    "arc, pivot above (c -10 1/m)": ("drive", _ARC(-10.0)),
    "fillet 13 mm x A 12 mm": ("pair", {**_PARAM_JAR, "jar_fillet_radius_m": 0.013,
                                        "amplitude_m": 0.012}),
    "fillet 13 mm x constant_torque": ("pair", {**_PARAM_JAR, "jar_fillet_radius_m": 0.013,
                                                "rolling_model": "constant_torque"}),
    "arc, pivot below (c +10 1/m)": ("drive", _ARC(10.0)),
    "restitution 0.5": ("restitution", {"restitution": 0.5}),
    "L 38 mm": ("(L-d)/A", {**_PARAM_JAR, "jar_inner_length_m": 0.038}),
    "static friction 1.0": ("friction", {"static_friction": 1.0}),
    "rolling friction 1.0": ("friction", {"rolling_friction": 1.0}),
}


class StudyInputError(ValueError):
    """Bad command-line input (one line, exit code 2, before any run)."""


# --------------------------------------------------------------------------------- the design

def conditions() -> pd.DataFrame:
    """The 4 conditions: both balls at 22.5 and 30 Hz (ids as Table 3's)."""
    rows = [{"condition_id": "f%g_d%g" % (f, d), "frequency_hz": float(f),
             "ball_diameter_mm": float(d)} for d in DIAMETERS_MM for f in FREQUENCIES_HZ]
    return pd.DataFrame(rows)


def design(variants=None, seeds=3) -> pd.DataFrame:
    """One row per run: variant, group, condition_id, frequency_hz, ball_diameter_mm, seed,
    config (variant outer, condition, seed inner: the order the runs go in)."""
    from analysis.run_configs import condition_runs
    names = list(VARIANTS) if variants is None else list(variants)
    cond = conditions()
    rows = []
    for name in names:
        group, change = VARIANTS[name]
        base = {"frame": "jar", **PAPER_CONTACT, **change}
        for r in condition_runs(cond, range(seeds), base_config=base, stated_stroke=False):
            c = cond.set_index("condition_id").loc[r.condition_id]
            rows.append({"variant": name, "group": group, "condition_id": r.condition_id,
                         "frequency_hz": float(c.frequency_hz),
                         "ball_diameter_mm": float(c.ball_diameter_mm), "seed": r.seed,
                         "config": r.config})
    return pd.DataFrame(rows)


def check_design(runs: pd.DataFrame):
    """Every config valid (twin_config's checks) - raises StudyInputError naming the variant."""
    from analysis.config import twin_config
    for name, g in runs.groupby("variant", sort=False):
        for cfg in g["config"]:
            try:
                twin_config.complete_config(dict(cfg))
            except twin_config.ConfigError as exc:
                raise StudyInputError("variant %r: invalid run config: %s" % (name, exc))


# ------------------------------------------------------------------------- the trend estimator

@functools.lru_cache(maxsize=None)
def _t_quantile(p, dof):
    from scipy import stats
    return float(stats.t.ppf(p, dof))


def trend(y_low, y_high, level=0.95) -> dict:
    """Relative change from the low to the high frequency, from replicate values of v/f.

    The change is estimated on the log scale: D = mean(ln y_high) - mean(ln y_low), with the
    pooled sd s of ln y over both groups (the seed scatter, assumed equal at both frequencies),
    se(D) = s sqrt(1/n_low + 1/n_high) and dof = n_low + n_high - 2; the relative change is
    r = exp(D) - 1, its se exp(D) se(D) (delta method), its ``level`` interval
    exp(D -+ t_dof se(D)) - 1 (exact for normal log v/f).

    Returns
    -------
    dict: change_pct, se_pct, lo_pct, hi_pct, dof, n_low, n_high (NaN where a group has no
    value; se NaN when dof < 1)
    """
    a = np.log(np.asarray(y_low, float))
    b = np.log(np.asarray(y_high, float))
    a, b = a[np.isfinite(a)], b[np.isfinite(b)]
    out = {"change_pct": np.nan, "se_pct": np.nan, "lo_pct": np.nan, "hi_pct": np.nan,
           "dof": max(len(a) + len(b) - 2, 0), "n_low": len(a), "n_high": len(b)}
    if len(a) == 0 or len(b) == 0:
        return out
    d = b.mean() - a.mean()
    out["change_pct"] = 100.0 * math.expm1(d)
    dof = out["dof"]
    if dof >= 1:
        ss = ((a - a.mean()) ** 2).sum() + ((b - b.mean()) ** 2).sum()
        se = math.sqrt(ss / dof) * math.sqrt(1.0 / len(a) + 1.0 / len(b))
        t = _t_quantile(0.5 + level / 2.0, dof)
        out.update(se_pct=100.0 * math.exp(d) * se, lo_pct=100.0 * math.expm1(d - t * se),
                   hi_pct=100.0 * math.expm1(d + t * se))
    return out


def shift(change, se, change_ref, se_ref):
    """(change - change_ref, its se) for independent estimates [percentage points]."""
    return change - change_ref, math.hypot(se, se_ref)


def lever_reach(shift_small, shift_large, need_small, need_large):
    """How far a lever's shift (s17, s20) must be scaled to reach the needed shift (n17, n20),
    k = s.n / s.s, and the distance left |n - k s| [points]; (NaN, NaN) for a null shift."""
    s = np.array([shift_small, shift_large], float)
    n = np.array([need_small, need_large], float)
    ss = float(s @ s)
    if not np.isfinite(ss) or ss == 0.0:
        return float("nan"), float("nan")
    k = float(s @ n) / ss
    return k, float(np.linalg.norm(n - k * s))


# --------------------------------------------------------------------------- speed definitions

#: name -> what it is (the columns of speed_definitions.csv and the page's table)
SPEED_DEFINITIONS = {
    "3d_all": "3-D speed |v|, time average over all saved frames (the twin's v_mean)",
    "vx_all": "axial speed |v_x|, all saved frames",
    "3d_no_end_contact": "3-D |v|, frames during an end-wall contact left out",
    "vx_no_end_contact": "|v_x|, frames during an end-wall contact left out",
    "3d_free_flight": "3-D |v|, frames during any wall contact (ends and cylinder) left out",
    "3d_jar_frame": "3-D speed relative to the jar, all saved frames",
    "3d_saved_5ms": "3-D |v| at frames saved every 5 ms (nearest recorded frame)",
    "3d_saved_10ms": "3-D |v| at frames saved every 10 ms",
    "chord_5ms": "chord speed |r(t + 5 ms) - r(t)| / 5 ms from positions saved every 5 ms",
    "chord_10ms": "chord speed from positions saved every 10 ms",
}


def _in_intervals(t, starts, ends):
    """Mask of the times t inside any closed interval [start, end]."""
    t = np.asarray(t, float)
    if len(starts) == 0:
        return np.zeros(len(t), bool)
    order = np.argsort(starts)
    s, e = np.asarray(starts, float)[order], np.asarray(ends, float)[order]
    e = np.maximum.accumulate(e)              # overlapping events: the running end
    k = np.searchsorted(s, t, side="right") - 1
    inside = np.zeros(len(t), bool)
    ok = k >= 0
    inside[ok] = t[ok] <= e[k[ok]]
    return inside


def _saved_every(t, dt_save):
    """Indices of the frames nearest to t0, t0 + dt_save, ... (each at most once)."""
    t = np.asarray(t, float)
    want = np.arange(t[0], t[-1] + 1e-12, dt_save)
    idx = np.clip(np.searchsorted(t, want), 1, len(t) - 1)
    idx = np.where(np.abs(t[idx - 1] - want) <= np.abs(t[idx] - want), idx - 1, idx)
    return np.unique(idx)


def speed_definitions(trajectory: pd.DataFrame, impacts: pd.DataFrame) -> dict:
    """Each definition of :data:`SPEED_DEFINITIONS` [m/s] on one recording (the trajectory and
    impacts tables of the recording contract, docs/reference.md): plain means over the saved
    frames (equally spaced in time, so time averages), contact masks from the impact events'
    [t_start, t_end]."""
    t = trajectory["t_s"].to_numpy(float)
    v = trajectory[["vx_m_s", "vy_m_s", "vz_m_s"]].to_numpy(float)
    r = trajectory[["x_m", "y_m", "z_m"]].to_numpy(float)
    s3 = np.linalg.norm(v, axis=1)
    vx = np.abs(v[:, 0])
    vrel = v.copy()
    vrel[:, 0] -= trajectory["jar_vx_m_s"].to_numpy(float)
    where = impacts["where"].astype(str).to_numpy()
    t0 = impacts["t_start_s"].to_numpy(float)
    t1 = impacts["t_end_s"].to_numpy(float)
    end = where == "end_cap"
    in_end = _in_intervals(t, t0[end], t1[end])
    in_any = _in_intervals(t, t0, t1)
    out = {"3d_all": s3.mean(), "vx_all": vx.mean(),
           "3d_no_end_contact": s3[~in_end].mean(), "vx_no_end_contact": vx[~in_end].mean(),
           "3d_free_flight": s3[~in_any].mean() if (~in_any).any() else np.nan,
           "3d_jar_frame": np.linalg.norm(vrel, axis=1).mean()}
    for ms in (5, 10):
        i = _saved_every(t, ms * 1e-3)
        out["3d_saved_%dms" % ms] = s3[i].mean()
        dr = np.linalg.norm(np.diff(r[i], axis=0), axis=1)
        out["chord_%dms" % ms] = (dr / np.diff(t[i])).mean() if len(i) > 1 else np.nan
    return {k: float(out[k]) for k in SPEED_DEFINITIONS}


def recording_definitions(run_dir) -> dict:
    from analysis.observe import load_recording
    rec = load_recording(run_dir)
    return speed_definitions(rec.trajectory, rec.impacts)


# ------------------------------------------------------------------------------------ the runs

def run_table(runs: pd.DataFrame, workers=1, cached_only=False, log=None):
    """The design's runs with their observables (:class:`analysis.twin_runs.TwinRuns`: cached,
    committed or run now). ``cached_only``: only the runs already cached or committed, nothing
    is started. Returns (table with run_id, status, v_mean_m_s, motion_mode, run_dir; failed
    runs with status 'failed')."""
    from analysis.config import RUNS_DIR
    from analysis.twin_runs import TwinRuns
    tr = TwinRuns(workers=workers, base_config={"frame": "jar"}, log=log)
    configs, ids = tr._ids(runs)
    cached, committed, _ = tr._split(configs, ids)
    sub = runs[cached | committed] if cached_only else runs
    done = tr(sub) if len(sub) else sub.assign(run_id=[], v_mean_m_s=[], motion_mode=[])
    out = runs.drop(columns="config").copy()
    out["run_id"] = ids
    got = done.drop_duplicates("run_id").set_index("run_id")
    failed = set(tr.failed["run_id"]) if len(tr.failed) else set()
    out["status"] = ["failed" if i in failed else ("ok" if i in got.index else "missing")
                     for i in out["run_id"]]
    for c in ("v_mean_m_s", "f_col_hz", "motion_mode"):
        out[c] = [got[c].get(i, np.nan) if i in got.index else np.nan for i in out["run_id"]]
    out["recording"] = [(RUNS_DIR / i / "trajectory.csv").is_file() for i in out["run_id"]]
    out["vf_mm"] = 1e3 * out["v_mean_m_s"].astype(float) / out["frequency_hz"]
    return out


def plan_words(runs: pd.DataFrame, workers=1) -> str:
    """What the design costs (nothing runs): per variant and in total."""
    from analysis.twin_runs import TwinRuns
    tr = TwinRuns(workers=workers, base_config={"frame": "jar"})
    lines = []
    for name, g in runs.groupby("variant", sort=False):
        p = tr.plan(g)
        lines.append("  %-34s %3d runs, %3d cached, %3d committed, %3d new"
                     % (name, p.runs, p.cached, p.committed, p.new))
    p = tr.plan(runs)
    lab = runs["config"].map(lambda c: c.get("frame") == "lab")
    lab_new = tr.plan(runs[lab]).new if lab.any() else 0
    from analysis.twin_runs import run_wall_s
    est = (p.new - lab_new) * run_wall_s({"frame": "jar"}) + lab_new * run_wall_s({})
    lines.append("total: %d runs needed, %d cached, %d from the committed run table, %d new "
                 "(%d of them lab frame), about %.0f min of twin time on %d worker(s)"
                 % (p.runs, p.cached, p.committed, p.new, lab_new, est / 60 / max(workers, 1),
                    workers))
    return "\n".join(lines)



# ---------------------------------------------------------------------------------- summaries

def _cells(table: pd.DataFrame, variant: str, d: float, value="vf_mm"):
    """(values at 22.5 Hz, values at 30 Hz, runs not in end-to-end flight) of one variant and
    ball: finished runs in end-to-end flight only."""
    g = table[(table["variant"] == variant) & (table["ball_diameter_mm"] == d)
              & (table["status"] == "ok")]
    ok = g[g["motion_mode"] == "end_to_end"]
    lo, hi = FREQUENCIES_HZ
    return (ok.loc[ok["frequency_hz"] == lo, value].to_numpy(float),
            ok.loc[ok["frequency_hz"] == hi, value].to_numpy(float), int(len(g) - len(ok)))


def trend_table(table: pd.DataFrame, seeds: int) -> pd.DataFrame:
    """One row per variant and ball (see the module doc; columns carry their units)."""
    rows = []
    for name in [v for v in VARIANTS if v in set(table["variant"])]:
        for d in DIAMETERS_MM:
            a, b, other = _cells(table, name, d)
            t = trend(a, b)
            n_runs = int(((table["variant"] == name) & (table["ball_diameter_mm"] == d)
                          & (table["status"] == "ok")).sum())
            rows.append({"variant": name, "group": VARIANTS[name][0],
                         "ball_diameter_mm": d,
                         "vf_22_5hz_mm": float(np.exp(np.log(a).mean())) if len(a) else np.nan,
                         "vf_30hz_mm": float(np.exp(np.log(b).mean())) if len(b) else np.nan,
                         "change_pct": t["change_pct"], "se_pct": t["se_pct"],
                         "ci95_lo_pct": t["lo_pct"], "ci95_hi_pct": t["hi_pct"],
                         "dof": t["dof"], "n_22_5hz": t["n_low"], "n_30hz": t["n_high"],
                         "runs_done": n_runs, "runs_planned": 2 * seeds,
                         "not_end_to_end": other,
                         # every run done (a ball out of end-to-end flight in them all
                         # is finished without a trend: rerunning does not change that)
                         "finished": bool(n_runs == 2 * seeds),
                         "has_trend": bool(t["dof"] >= 1),
                         "edem_change_pct": EDEM_TREND_PCT[d]})
    out = pd.DataFrame(rows)
    if out.empty:
        return out
    out["diff_to_edem_pct_points"] = out["change_pct"] - out["edem_change_pct"]
    ref = out[out["variant"] == "default"].set_index("ball_diameter_mm")
    sh, se = [], []
    for r in out.itertuples():
        if r.ball_diameter_mm in ref.index and r.variant != "default":
            x = shift(r.change_pct, r.se_pct, ref.loc[r.ball_diameter_mm, "change_pct"],
                      ref.loc[r.ball_diameter_mm, "se_pct"])
        else:
            x = (np.nan, np.nan)
        sh.append(x[0])
        se.append(x[1])
    out["shift_from_default_pct_points"] = sh
    out["shift_se_pct_points"] = se
    return out


def verdicts(trend_t: pd.DataFrame) -> pd.DataFrame:
    """Per variant: both balls' change and se, whether it gives EDEM's pair within
    :data:`MATCH_POINTS` ("gives"), and the lever scaled to the pair (:func:`lever_reach` on the
    shifts from the default, needed shift = EDEM - default)."""
    if trend_t.empty:
        return pd.DataFrame()
    w = trend_t.pivot(index="variant", columns="ball_diameter_mm")
    ref = trend_t[trend_t["variant"] == "default"].set_index("ball_diameter_mm")
    rows = []
    for name in [v for v in VARIANTS if v in w.index]:
        c17, c20 = w.loc[name, ("change_pct", 17.5)], w.loc[name, ("change_pct", 20.6)]
        s17, s20 = w.loc[name, ("se_pct", 17.5)], w.loc[name, ("se_pct", 20.6)]
        row = {"variant": name, "group": VARIANTS[name][0],
               "change_17_5_pct": c17, "se_17_5_pct": s17,
               "change_20_6_pct": c20, "se_20_6_pct": s20,
               "finished": bool(w.loc[name, ("finished", 17.5)]
                                and w.loc[name, ("finished", 20.6)]),
               "gives_edem_pair": bool(abs(c17 - EDEM_TREND_PCT[17.5]) <= MATCH_POINTS
                                       and abs(c20 - EDEM_TREND_PCT[20.6]) <= MATCH_POINTS),
               "lever_scale": np.nan, "lever_miss_pct_points": np.nan}
        if name != "default" and len(ref) == 2:
            need = [EDEM_TREND_PCT[d] - ref.loc[d, "change_pct"] for d in DIAMETERS_MM]
            sh = [w.loc[name, ("shift_from_default_pct_points", d)] for d in DIAMETERS_MM]
            row["lever_scale"], row["lever_miss_pct_points"] = lever_reach(*sh, *need)
        rows.append(row)
    return pd.DataFrame(rows)


def run_definitions(table: pd.DataFrame) -> pd.DataFrame:
    """Every speed definition [v/f in mm] of every finished end-to-end run whose recording is
    in the cache: variant, run_id, frequency_hz, ball_diameter_mm and one column per
    definition."""
    from analysis.config import RUNS_DIR
    ok = table[(table["status"] == "ok") & (table["motion_mode"] == "end_to_end")
               & table["recording"].astype(bool)]
    per = []
    for r in ok.itertuples():
        defs = recording_definitions(RUNS_DIR / r.run_id)
        per.append({"variant": r.variant, "run_id": r.run_id, "frequency_hz": r.frequency_hz,
                    "ball_diameter_mm": r.ball_diameter_mm,
                    **{k: 1e3 * v / r.frequency_hz for k, v in defs.items()}})
    return pd.DataFrame(per, columns=["variant", "run_id", "frequency_hz", "ball_diameter_mm",
                                      *SPEED_DEFINITIONS])


def _def_trends(g, key, d):
    """(trend of definition ``key``, trend of its ratio to 3d_all, level ratios) for ball d."""
    lo, hi = FREQUENCIES_HZ
    g = g[g["ball_diameter_mm"] == d]
    a = g.loc[g["frequency_hz"] == lo, key].to_numpy(float)
    b = g.loc[g["frequency_hz"] == hi, key].to_numpy(float)
    ra = a / g.loc[g["frequency_hz"] == lo, "3d_all"].to_numpy(float)
    rb = b / g.loc[g["frequency_hz"] == hi, "3d_all"].to_numpy(float)
    return a, b, trend(a, b), trend(ra, rb), np.concatenate([ra, rb])


def definitions_table(per: pd.DataFrame, variant="default") -> pd.DataFrame:
    """Each speed definition on the variant's recordings (:func:`run_definitions`): v/f per
    ball and frequency, its level against the twin's v_mean (3-D, all frames), its
    22.5 -> 30 Hz change with se, and that change's difference to the 3-D one (paired by run:
    the trend of the ratio, its se)."""
    g = per[per["variant"] == variant]
    if g.empty:
        return pd.DataFrame()
    rows = []
    for key, what in SPEED_DEFINITIONS.items():
        for d in DIAMETERS_MM:
            a, b, t, tr, ratio = _def_trends(g, key, d)
            rows.append({"definition": key, "what": what, "ball_diameter_mm": d,
                         "vf_22_5hz_mm": float(np.exp(np.log(a).mean())) if len(a) else np.nan,
                         "vf_30hz_mm": float(np.exp(np.log(b).mean())) if len(b) else np.nan,
                         "level_vs_3d_all_pct": 100 * (float(np.exp(np.log(ratio).mean())) - 1)
                         if len(ratio) else np.nan,
                         "change_pct": t["change_pct"], "se_pct": t["se_pct"],
                         "change_minus_3d_all_pct_points": tr["change_pct"],
                         "change_minus_3d_all_se_pct_points": tr["se_pct"],
                         "n_22_5hz": t["n_low"], "n_30hz": t["n_high"],
                         "edem_change_pct": EDEM_TREND_PCT[d]})
    return pd.DataFrame(rows)


def definitions_by_variant(per: pd.DataFrame) -> pd.DataFrame:
    """Every variant x speed definition: per ball the v/f at 22.5 Hz [mm] and its change to
    30 Hz with se, and whether the pair is within :data:`MATCH_POINTS` of EDEM's."""
    rows = []
    for name in [v for v in VARIANTS if v in set(per["variant"])]:
        g = per[per["variant"] == name]
        for key in SPEED_DEFINITIONS:
            row = {"variant": name, "definition": key}
            for d, tag in ((17.5, "17_5"), (20.6, "20_6")):
                a, _, t, _, _ = _def_trends(g, key, d)
                row["vf_22_5hz_%s_mm" % tag] = float(np.exp(np.log(a).mean())) if len(a) \
                    else np.nan
                row["change_%s_pct" % tag] = t["change_pct"]
                row["se_%s_pct" % tag] = t["se_pct"]
                row["dof_%s" % tag] = t["dof"]
            row["gives_edem_pair"] = bool(
                abs(row["change_17_5_pct"] - EDEM_TREND_PCT[17.5]) <= MATCH_POINTS
                and abs(row["change_20_6_pct"] - EDEM_TREND_PCT[20.6]) <= MATCH_POINTS)
            rows.append(row)
    return pd.DataFrame(rows)


def summarize(table: pd.DataFrame, seeds: int) -> dict:
    t = trend_table(table, seeds)
    per = run_definitions(table)
    return {"trend": t, "verdicts": verdicts(t), "definitions": definitions_table(per),
            "by_variant": definitions_by_variant(per)}


#: the files the study writes into --out
OUT_FILES = ("trend.csv", "verdicts.csv", "speed_definitions.csv",
             "definitions_by_variant.csv", "runs.csv", "vf_trend.png", "README.md")


def write(res: dict, table: pd.DataFrame, seeds: int, out: Path, partial=False):
    """All files into a staging folder, then swapped in (analysis.atomic_dir.output_dir)."""
    from analysis.atomic_dir import output_dir
    from analysis.plotting.vf_trend_plots import write_vf_trend_figure
    from analysis.report.vf_trend_page import vf_trend_page
    with output_dir(out) as tmp:
        res["trend"].to_csv(tmp / "trend.csv", index=False, float_format="%.4g")
        res["verdicts"].to_csv(tmp / "verdicts.csv", index=False, float_format="%.4g")
        res["definitions"].to_csv(tmp / "speed_definitions.csv", index=False,
                                  float_format="%.5g")
        res["by_variant"].to_csv(tmp / "definitions_by_variant.csv", index=False,
                                 float_format="%.4g")
        table.to_csv(tmp / "runs.csv", index=False, float_format="%.6g")
        fig = None
        if not res["trend"].empty:
            fig = write_vf_trend_figure(res["trend"], tmp / "vf_trend.png", EDEM_TREND_PCT,
                                        MATCH_POINTS)
        (tmp / "README.md").write_text(vf_trend_page(res, table, seeds, study_info(),
                                                     partial=partial, figure=fig is not None))


def study_info() -> dict:
    """The constants the page quotes."""
    return {"EDEM_TREND_PCT": EDEM_TREND_PCT, "EDEM_VF_MM": EDEM_VF_MM,
            "FREQUENCIES_HZ": FREQUENCIES_HZ, "PAPER_CONTACT": PAPER_CONTACT,
            "SPEED_DEFINITIONS": SPEED_DEFINITIONS, "VARIANTS": VARIANTS,
            "MATCH_POINTS": MATCH_POINTS}


# ------------------------------------------------------------------------------------- the CLI

def parse_args(argv=None):
    p = argparse.ArgumentParser(
        prog=PROG, description=__doc__.split("\n\n")[0],
        epilog="example: %s --out results/studies/vf_trend --workers 1 --seeds 3 --dry-run"
        % PROG)
    p.add_argument("--out", default="results/studies/vf_trend",
                   help="output folder (default %(default)s)")
    p.add_argument("--workers", type=int, default=1,
                   help="parallel twin runs [processes] (default %(default)s)")
    p.add_argument("--seeds", type=int, default=3,
                   help="start positions per variant, ball and frequency [seeds], >= 2 "
                   "(default %(default)s)")
    p.add_argument("--variants", nargs="+", metavar="NAME",
                   help="only these variants (names as listed by --list; default all; "
                   "'default' is always added)")
    p.add_argument("--list", action="store_true", help="list the variants and exit")
    p.add_argument("--dry-run", action="store_true",
                   help="print how many runs are needed and cached, run nothing")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--runs-only", action="store_true",
                   help="run the twin runs into the cache and write nothing else")
    g.add_argument("--cached-only", action="store_true",
                   help="start no twin run: the page from the runs already cached (variants "
                   "with missing runs are marked unfinished)")
    return p, p.parse_args(argv)


def check_args(a):
    """Raise StudyInputError for bad input (before any run)."""
    if a.workers < 1:
        raise StudyInputError("--workers must be >= 1, got %d" % a.workers)
    if a.seeds < 2:
        raise StudyInputError("--seeds must be >= 2 (the standard error comes from the seed "
                              "scatter), got %d" % a.seeds)
    if a.seeds > 50:
        raise StudyInputError("--seeds %d is more than this study means to run (at most 50)"
                              % a.seeds)
    names = None
    if a.variants:
        unknown = [v for v in a.variants if v not in VARIANTS]
        if unknown:
            raise StudyInputError("unknown variant(s) %s; known: %s" % (
                ", ".join(repr(v) for v in unknown), ", ".join(repr(v) for v in VARIANTS)))
        names = ["default"] + [v for v in VARIANTS if v in a.variants and v != "default"]
    from analysis.atomic_dir import OutputError, check_out_dir
    try:
        check_out_dir(a.out)
    except OutputError as exc:
        raise StudyInputError(str(exc))
    return names


def main(argv=None):
    p, a = parse_args(argv)
    if a.list:
        for name, (group, change) in VARIANTS.items():
            print("%-34s %-14s %s" % (name, group, change))
        return 0
    try:
        names = check_args(a)
        runs = design(names, a.seeds)
        check_design(runs)
    except StudyInputError as exc:
        print("%s: error: %s" % (PROG, exc), file=sys.stderr)
        return 2
    if a.dry_run:
        print(plan_words(runs, a.workers))
        return 0
    from analysis.sweep import SweepInterrupted
    try:
        table = run_table(runs, a.workers, cached_only=a.cached_only)
    except SweepInterrupted as exc:
        print("%s: interrupted (%s): finished runs are cached; the same command resumes"
              % (PROG, exc), file=sys.stderr)
        return 130
    if a.runs_only:
        n_ok = int((table["status"] == "ok").sum())
        print("%d of %d runs in the cache (nothing else written)" % (n_ok, len(table)))
        return 0
    res = summarize(table, a.seeds)
    write(res, table, a.seeds, Path(a.out), partial=a.cached_only)
    if len(res["verdicts"]):
        print(res["verdicts"].to_string(index=False, float_format=lambda x: "%.2f" % x))
    print("wrote", a.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
