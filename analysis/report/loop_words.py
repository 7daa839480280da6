"""What the loop's report says about its own numbers, declared once for its page, its figures
and its loop.json: what each staircase stage is (the model, the model shifted onto the twin's
reruns, or the real twin), which stages the verdict quotes, why the dof changes, the chi2 gain
each candidate needed (the significance test as applied), whether a run was made by the FAKE
twin, which parameters the data do not constrain and the strokes a dataset states.

Nothing here runs, fits or draws; :mod:`analysis.loop` (``write_loop``), the loop's page
(:func:`analysis.report.loop_page`) and its figures
(:func:`analysis.plotting.loop_plots.write_loop_figures`) read these.
"""
from __future__ import annotations

import math

import numpy as np
import pandas as pd

#: the word every page, figure and JSON of a loop run on the FAKE analytic twin carries
FAKE = "FAKE"
#: what that word stands for, in one line
FAKE_WORDS = ("FAKE twin: every twin run of this loop was made by the analytic stand-in "
              "(`--fake`, analysis/fake_twin.py), not by the DEM twin; its numbers say nothing "
              "about a mill")

#: what a staircase bar is
MODEL, TWIN, FAKE_TWIN = "model", "real twin", "FAKE twin"
#: legend words of the kinds
KIND_WORDS = {MODEL: "model (the emulator fitted to the dataset's twin runs)",
              TWIN: "real twin (fresh runs at the fitted point)",
              FAKE_TWIN: "FAKE twin (the analytic stand-in's fresh runs at the fitted point)"}

#: a parameter is "not constrained by the data" when its standard error is at least this
#: fraction of its prior sd (the Gaussian prior's sd where the fit has one, else the sd of a
#: flat prior over its bounds, (upper - lower) / sqrt(12)): the data narrow the prior by less
#: than 30 %
UNCONSTRAINED_SE_RATIO = 0.7
UNCONSTRAINED_RULE = ("a parameter is marked *not constrained by the data* when its spread - "
                      "the larger of its standard error and its 95 %% profile interval's width "
                      "/ 3.92 (a flat ridge the local se does not see) - is at least %.0f %% of "
                      "its prior sd (the Gaussian prior's sd where the fit has one - the "
                      "frictions -, else the sd of a flat prior over its bounds, (upper - "
                      "lower) / sqrt(12)): its interval is about as wide as what was assumed "
                      "before the data" % (100 * UNCONSTRAINED_SE_RATIO))


def spread_of(se, lo=float("nan"), hi=float("nan")) -> float:
    """A fitted parameter's spread: the larger of its standard error and the width of its
    95 % profile interval / (2 x 1.96) (NaN when neither is finite)."""
    w = (float(hi) - float(lo)) / 3.92 if np.isfinite(lo) and np.isfinite(hi) else np.nan
    vals = [v for v in (float(se), w) if np.isfinite(v)]
    return max(vals) if vals else float("nan")


def is_constrained(se, sd, lo=float("nan"), hi=float("nan")) -> bool:
    """:data:`UNCONSTRAINED_RULE`: the spread (:func:`spread_of`) below
    :data:`UNCONSTRAINED_SE_RATIO` of the prior sd ``sd``."""
    s = spread_of(se, lo, hi)
    return bool(np.isfinite(s) and s < UNCONSTRAINED_SE_RATIO * sd)


# ------------------------------------------------------------------------------- the FAKE twin

def is_fake_run(res) -> bool:
    """The loop's twin runs were made by the FAKE twin (their motion mode is 'fake')."""
    return fake_runs(getattr(res, "model_runs", None), getattr(res, "rerun_runs", None))


def fake_runs(*tables) -> bool:
    """Any of the run ``tables`` (None allowed) holds a FAKE twin run (motion mode 'fake')."""
    return any(t is not None and len(t) and "motion_mode" in t.columns
               and (t["motion_mode"].astype(str) == "fake").any() for t in tables)


# ------------------------------------------------------------------------------- the staircase

def stage_kind(stage: str, fake: bool = False) -> str:
    """:data:`MODEL` or :data:`TWIN` for a staircase stage name (:data:`FAKE_TWIN` for a
    rerun of a ``fake`` loop: its fresh runs are the analytic stand-in's, not the DEM's)."""
    if not str(stage).startswith("twin rerun"):
        return MODEL
    return FAKE_TWIN if fake else TWIN


def stage_words(stage: str, fake: bool = False) -> str:
    """What a staircase stage is, in a few words (``fake``: a FAKE-twin loop's)."""
    s = str(stage)
    if s == "baseline":
        return "the model at the reference point, nothing fitted"
    if s == "calibrated":
        return "the model, base parameters fitted"
    if s.startswith("+ "):
        return "%s added: its strength fitted with the base parameters" % s[2:]
    if s == "twin rerun":
        return ("the %s twin rerun at the fitted point, with the effects found (if any)"
                % ("FAKE" if fake else "real"))
    if s == "refitted on the twin reruns":
        return ("the emulator refitted with the rerun's runs, the base parameters and "
                "strengths fitted again")
    return s


def quoted_stages(staircase) -> dict:
    """{role: row index} of the staircase rows the loop's verdict quotes: 'calibrated' (the
    last),
    'final' (the last model row, when an effect was added or the twin was rerun) and 'twin
    rerun' (the last real-twin rerun)."""
    st = [str(s) for s in staircase["stage"]]
    out = {}
    if "calibrated" in st:      # the last: a focus wave after a rerun calibrates again
        out["calibrated"] = len(st) - 1 - st[::-1].index("calibrated")
    model = [i for i, s in enumerate(st) if stage_kind(s) == MODEL and s != "baseline"]
    if model and model[-1] != out.get("calibrated"):
        out["final"] = model[-1]
    if "twin rerun" in st:
        out["twin rerun"] = len(st) - 1 - st[::-1].index("twin rerun")
    return out


def quoted_words(staircase, fake: bool = False) -> str:
    """One sentence naming the stages whose chi2/dof the verdict quotes."""
    q = quoted_stages(staircase)
    if not q:
        return ""
    st = list(staircase["stage"])
    cd = list(staircase["chi2_dof"])
    parts = []
    for role, i in q.items():
        parts.append("%s chi2/dof %s is the row `%s` (%s)"
                     % ({"calibrated": "the 'calibrated'", "final": "the final",
                         "twin rerun": "the twin rerun's"}[role], _f2(cd[i]), st[i],
                        stage_words(st[i], fake)))
    return "The verdict quotes (marked * in the table and the figure): " + "; ".join(parts) + "."


def _f2(x):
    try:
        x = float(x)
    except (TypeError, ValueError):
        return "-"
    return "%.2f" % x if math.isfinite(x) else "-"


def dof_words(staircase) -> list:
    """Sentences explaining the staircase's dof and its chi2/dof moves that come from them:
    dof = observations - fitted parameters; where the dof falls the chi2/dof can rise while the
    chi2 falls; the twin-corrected and twin rows are scored with the rerun means' noise."""
    st = staircase.reset_index(drop=True)
    if not len(st):
        return []
    dof0 = int(st["dof"].iloc[0])
    np0 = int(st["n_params"].iloc[0]) if "n_params" in st else 0
    n_obs = dof0 + np0
    out = ["dof = observations - fitted parameters: %d observations; the baseline fits "
           "nothing (dof %d), the calibration fits the base parameters, each added effect one "
           "strength more."
           % (n_obs, dof0)]
    for i in range(1, len(st)):
        a, b = st.iloc[i - 1], st.iloc[i]
        if int(b["dof"]) < int(a["dof"]) and float(b["chi2_dof"]) > float(a["chi2_dof"]) \
                and float(b["chi2"]) <= float(a["chi2"]):
            out.append("From `%s` to `%s` the chi2 falls (%.4g -> %.4g) but the chi2/dof rises "
                       "(%s -> %s): the dof falls %d -> %d (%d parameter(s) fitted); with few "
                       "observations per parameter the calibration cannot lower chi2/dof."
                       % (a["stage"], b["stage"], float(a["chi2"]), float(b["chi2"]),
                          _f2(a["chi2_dof"]), _f2(b["chi2_dof"]), int(a["dof"]), int(b["dof"]),
                          int(a["dof"]) - int(b["dof"])))
    if any(stage_kind(s) != MODEL for s in st["stage"]):
        out.append("The twin rerun rows are scored with the noise of the reruns' means "
                   "instead of the emulator's, against the twin itself: where one lies above "
                   "the model row before it, the twin disagrees with the emulator at that "
                   "point (the refit after it uses the rerun's runs).")
    if (st["dof"] <= 0).any():
        out.append("A row with dof 0 or less cannot be tested (its chi2/dof is left empty).")
    return out


# ------------------------------------------------------------------------------- significance

def needed_gains(diagnosis, scale: float = 1.0) -> pd.Series:
    """The chi2 gain each candidate of ``diagnosis`` needed to be significant, as the
    significance test applies it (analysis.diagnose, and the loop's bootstrap): the larger of
    the Bonferroni threshold times the bootstrap's ``scale`` (the line of the ranking figure),
    the gain its F-test needed at the misfit the candidate leaves (chi2/dof after it,
    F_1,dof quantile at the same Bonferroni level) and the BIC's ln n. Indexed by effect.

    A candidate is significant exactly when it is identifiable and its gain exceeds this."""
    from scipy import stats
    t = diagnosis.table
    thr = float(diagnosis.threshold_delta_chi2)
    c = float(scale) if scale is not None and np.isfinite(scale) else 1.0
    need = pd.Series(c * thr, index=t["effect"].to_numpy(), dtype=float)
    cal = getattr(diagnosis, "calibrated", None)
    fits = getattr(diagnosis, "fits", None) or {}
    k = max(len(t), 1)
    level = min(2.0 * float(diagnosis.alpha) / k, 1.0)
    if cal is not None and getattr(cal, "params", None) is not None:
        n = int(cal.dof) + len(cal.params)
        if n > 1:
            need = need.clip(lower=math.log(n))
    if "chi2_dof_after" in t.columns:
        for name, cd in zip(t["effect"], t["chi2_dof_after"]):
            f = fits.get(name)
            if f is None or not np.isfinite(cd):
                continue
            dof = max(int(f.dof), 1)
            need[name] = max(need[name], float(stats.f.isf(level, 1, dof)) * float(cd))
    return need


def applied_threshold(diagnosis, scale: float = 1.0) -> float:
    """The chi2 gain every candidate of the step needed at least (the line of the ranking
    figure): the Bonferroni threshold times the bootstrap's scale, and at least the BIC's
    ln n; a candidate's own F-test can ask more (:func:`needed_gains`)."""
    thr = float(diagnosis.threshold_delta_chi2) * (float(scale) if scale is not None
                                                   and np.isfinite(scale) else 1.0)
    cal = getattr(diagnosis, "calibrated", None)
    if cal is not None and getattr(cal, "params", None) is not None:
        n = int(cal.dof) + len(cal.params)
        if n > 1:
            thr = max(thr, math.log(n))
    return float(thr)


def step_scale(steps, step: int) -> float:
    """The bootstrap's threshold scale applied at ``step`` (steps.csv's threshold_scale)."""
    if steps is None or not len(steps) or "threshold_scale" not in steps.columns:
        return 1.0
    s = steps.loc[steps["step"] == step, "threshold_scale"]
    v = float(s.iloc[0]) if len(s) else 1.0
    return v if np.isfinite(v) else 1.0


# ------------------------------------------------------------------------------- parameters

def stated_strokes_mm(conditions) -> dict:
    """{condition_id: stated half stroke [mm]} of the conditions that state one."""
    if conditions is None or "amplitude_mm" not in getattr(conditions, "columns", ()):
        return {}
    a = pd.to_numeric(conditions["amplitude_mm"], errors="coerce")
    return {str(c): float(v) for c, v in zip(conditions["condition_id"], a) if np.isfinite(v)}


def stated_stroke_words(conditions) -> str:
    """'12.0 mm at every condition' or '12.0 mm at a, b; 13.0 mm at c' (empty: none stated)."""
    s = stated_strokes_mm(conditions)
    if not s:
        return ""
    by = {}
    for c, v in s.items():
        by.setdefault(round(v, 6), []).append(c)
    n = len(conditions)
    if len(by) == 1 and len(s) == n:
        return "%g mm at every condition" % next(iter(by))
    return "; ".join("%g mm at %s" % (v, ", ".join(cs)) for v, cs in by.items())


def prior_sd(name, bounds=None, priors=None) -> float:
    """The prior sd of a fitted parameter: the Gaussian prior's where it has one, else a flat
    prior's over its bounds; NaN when neither is known."""
    if priors and name in priors:
        return float(priors[name][1])
    if bounds and name in bounds:
        lo, hi = bounds[name][:2]
        return (float(hi) - float(lo)) / math.sqrt(12.0)
    return float("nan")


def annotate_parameters(parameters, conditions=None, *, bounds=None, priors=None):
    """parameters.csv as the report states it: a held stroke the dataset states carries the
    stated value (not the anchor's), a stroke stated at some conditions says so, and a column
    ``constrained`` (True / False / empty for held rows) by :data:`UNCONSTRAINED_SE_RATIO`,
    the note saying 'not constrained by the data' where it is False."""
    p = parameters.copy()
    if "note" not in p.columns:
        p["note"] = ""
    p["note"] = p["note"].fillna("").astype(str)
    p["value"] = p["value"].astype(float)
    stated = stated_strokes_mm(conditions)
    words = stated_stroke_words(conditions)
    constrained = []
    for i, r in p.iterrows():
        name, role = str(r["name"]), str(r["role"])
        note = [r["note"]] if r["note"] else []
        if name == "amplitude_m" and role == "held" and stated:
            vals = sorted(set(round(v, 9) for v in stated.values()))
            p.at[i, "value"] = vals[0] * 1e-3 if len(vals) == 1 else float("nan")
            note = ["stated by the dataset (amplitude_mm): %s; not fitted" % words]
        elif name == "amplitude_m" and role == "base" and stated:
            note.append("fitted for the conditions that state no stroke; stated: %s" % words)
        c = None
        if role != "held":
            se, lo, hi = pd.to_numeric(pd.Series([r.get("se"), r.get("profile_lo"),
                                                  r.get("profile_hi")]), errors="coerce")
            sd = prior_sd(name, bounds, priors)
            if np.isfinite(sd) and sd > 0:
                c = is_constrained(se, sd, lo, hi)
                if not c:
                    sp = spread_of(se, lo, hi)
                    note.append("not constrained by the data (spread %s of the prior sd %.3g)"
                                % ("%.0f %%" % (100 * sp / sd) if np.isfinite(sp) else
                                   "unknown", sd))
        constrained.append(c)
        p.at[i, "note"] = "; ".join(n for n in note if n)
    p["constrained"] = pd.array(constrained, dtype="boolean")
    return p


# ------------------------------------------------------------------------------- JSON

def json_clean(o):
    """``o`` with every non-finite float (NaN, inf) as None and numpy / pandas values as plain
    Python, recursively: what ``json.dumps(..., allow_nan=False)`` takes (valid JSON)."""
    if isinstance(o, dict):
        return {str(k): json_clean(v) for k, v in o.items()}
    if isinstance(o, (list, tuple, set)):
        return [json_clean(v) for v in o]
    if isinstance(o, (pd.DataFrame,)):
        return json_clean(o.to_dict("records"))
    if isinstance(o, pd.Series):
        return json_clean(o.to_dict())
    if isinstance(o, np.ndarray):
        return json_clean(o.tolist())
    if isinstance(o, (bool, np.bool_)):
        return bool(o)
    if isinstance(o, (int, np.integer)):
        return int(o)
    if isinstance(o, (float, np.floating)):
        return float(o) if math.isfinite(float(o)) else None
    if o is None or isinstance(o, str):
        return o
    try:
        if pd.isna(o):
            return None
    except (TypeError, ValueError):
        pass
    return str(o)
