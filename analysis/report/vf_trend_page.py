"""The page of :mod:`analysis.studies.vf_trend` (results/studies/vf_trend/README.md)."""
from __future__ import annotations

import numpy as np

from analysis.report.markdown import md_table

TITLE = "# What makes v/f fall in a rigid harmonic jar"
#: the largest lever scale the page calls within reach (3x the variant's change)
LEVER_MAX = 3.0


def _pm(x, se, nd=1):
    if not np.isfinite(x):
        return "-"
    if not np.isfinite(se):
        return "%+.*f" % (nd, x)
    return "%+.*f +- %.*f" % (nd, x, nd, se)


def _f1(x):
    return "%.1f" % x if np.isfinite(x) else "-"


def _ci(lo, hi):
    return "[%+.1f, %+.1f]" % (lo, hi) if np.isfinite(lo) and np.isfinite(hi) else "-"


def _names(xs):
    xs = list(xs)
    return ", ".join(xs) if xs else "none"


def conclusions(trend, verd, info, finished_only=True):
    """The sentences of the page's conclusion (numbers from the tables; ``info``: the study's
    constants, :func:`analysis.studies.vf_trend.study_info`)."""
    EDEM_TREND_PCT, MATCH_POINTS = info["EDEM_TREND_PCT"], info["MATCH_POINTS"]
    e17, e20 = EDEM_TREND_PCT[17.5], EDEM_TREND_PCT[20.6]
    v = verd[verd["finished"]] if finished_only else verd
    out = []
    d = v[v["variant"] == "default"]
    if len(d):
        d = d.iloc[0]
        out.append("The default twin's v/f changes by %s %% (17.5 mm) and %s %% (20.6 mm) from "
                   "22.5 to 30 Hz; EDEM's falls by %.1f %% and %.1f %%."
                   % (_pm(d.change_17_5_pct, d.se_17_5_pct), _pm(d.change_20_6_pct,
                                                                 d.se_20_6_pct), -e17, -e20))
    t = trend[trend["variant"] != "default"]
    t = t[t["variant"].isin(v["variant"])]
    sig = {}
    for name, g in t.groupby("variant", sort=False):
        z = (g["shift_from_default_pct_points"] / g["shift_se_pct_points"]).to_numpy(float)
        sig[name] = z
    both_down = [n for n, z in sig.items() if np.all(z < -2)]
    one_down = [n for n, z in sig.items() if np.any(z < -2) and not np.all(z < -2)]
    up = [n for n, z in sig.items() if np.any(z > 2)]
    flat = [n for n, z in sig.items() if np.all(np.abs(z) <= 2)]
    out.append("Lower v/f trend than the default by more than 2 se for BOTH balls: %s; for one "
               "ball only: %s; higher for at least one ball: %s; no change beyond 2 se: %s."
               % (_names(both_down), _names(one_down), _names(up), _names(flat)))
    gives = v[v["gives_edem_pair"]]["variant"]
    out.append("Variants whose changes are within %g points of EDEM's %.1f %% and %.1f %% at "
               "once: %s." % (MATCH_POINTS, e17, e20, _names(gives)))
    lv = v[(v["variant"] != "default") & (v["lever_scale"] > 0)
           & (v["lever_miss_pct_points"] <= MATCH_POINTS)]
    near = lv[(lv["lever_scale"] <= LEVER_MAX) & lv["variant"].isin(
        [n for n, z in sig.items() if np.any(np.abs(z) > 2)])]
    far = lv[~lv["variant"].isin(near["variant"])]
    words = lambda t: "; ".join("%s (k %.1f, miss %.1f points)" % (  # noqa: E731
        r.variant, r.lever_scale, r.lever_miss_pct_points) for r in t.itertuples())
    out.append("Levers whose shift from the default points at EDEM's pair, so that the same "
               "change pushed k times as far (linear extrapolation; k = 1 is the variant as "
               "run) would come within %g points of both, with k <= %g and a shift beyond "
               "2 se: %s." % (MATCH_POINTS, LEVER_MAX, words(near) or "none"))
    if len(far):
        out.append("The same only with k > %g or a shift within 2 se (an extrapolation far "
                   "beyond what was run, or noise): %s." % (LEVER_MAX, words(far)))
    none = trend[~trend["has_trend"].astype(bool)] if "has_trend" in trend else trend[:0]
    if len(none):
        out.append("No trend (fewer than three of its runs in end-to-end flight, the only "
                   "ones used; a rerun would not change that): %s."
                   % "; ".join("%s, %.1f mm ball (%d of %d runs in another mode)"
                               % (r.variant, r.ball_diameter_mm, r.not_end_to_end, r.runs_done)
                               for r in none.itertuples()))
    return out


def vf_trend_page(res, table, seeds, info, partial=False, figure=True) -> str:
    """The page's text; ``info``: the study's constants
    (:func:`analysis.studies.vf_trend.study_info`)."""
    verd, defs = res["verdicts"], res["definitions"]
    ok = table[table["status"] == "ok"]
    asked = list(dict.fromkeys(table["variant"]))
    fin = list(verd.loc[verd["finished"], "variant"]) if len(verd) else []
    ran = set(ok["variant"])
    L = _intro_lines(seeds, info) + _run_lines(table, ok, seeds, info)
    partly = [v for v in asked if v not in fin and v in ran]
    not_run = [v for v in asked if v not in ran]
    if partly or not_run:
        L += ["**Unfinished**%s; the same command resumes and fills them in. Finished: %s. "
              "Partly run (in the tables with the seeds they have): %s. Not yet run (left out "
              "of the tables): %s."
              % (" (this page was written from the cache only, `--cached-only`, while the "
                 "runs went on)" if partial else "", _names(fin), _names(partly),
                 _names(not_run)), ""]
    L += [METHOD_WORDS, ""]
    if len(verd):
        L += _trend_lines(res["trend"], verd, ran, info, figure)
    if len(defs):
        L += _definition_lines(defs, info)
    bv = res.get("by_variant")
    if bv is not None and len(bv):
        L += by_variant_lines(bv, info["EDEM_TREND_PCT"], info["EDEM_VF_MM"],
                              info["MATCH_POINTS"])
    L += ["## Files", "",
          "`trend.csv` (one row per variant and ball), `verdicts.csv` (one row per variant), "
          "`speed_definitions.csv`, `definitions_by_variant.csv` (every variant x definition: "
          "change +- se per ball), `runs.csv` (every run: run id, seed, status, motion mode, "
          "v/f), `vf_trend.png`. Runs are cached by run id in results/runs/; "
          "`--dry-run` prints what is cached.", "",
          "Variants (run config changes): " + "; ".join(
              "%s: `%s`" % (k, v[1] or "{}") for k, v in info["VARIANTS"].items()
              if k in asked) + "."]
    return "\n".join(L).rstrip() + "\n"


#: how the page's changes, se, intervals and levers are computed
METHOD_WORDS = (
    "The change of v/f is exp(D) - 1 with D the difference of the mean ln(v/f) at 30 "
    "and at 22.5 Hz; its standard error comes from the seed scatter (the pooled sd of "
    "ln(v/f) over both frequencies, se(D) = s sqrt(1/n1 + 1/n2), propagated by the "
    "delta method), the 95 % interval from Student's t with n1 + n2 - 2 degrees of "
    "freedom. A shift from the default adds both se in quadrature. The lever columns "
    "scale the variant's shift s = (s17, s20) by k = s.n / s.s towards the needed shift "
    "n = EDEM - default and give the distance left |n - k s|: small when the variant moves "
    "the two balls in EDEM's proportion.")


def _intro_lines(seeds, info) -> list:
    """The title, how the page was made and the question."""
    EDEM_TREND_PCT, EDEM_VF_MM = info["EDEM_TREND_PCT"], info["EDEM_VF_MM"]
    return [TITLE, "",
            "*Generated by `python -m analysis.studies.vf_trend --out results/studies/vf_trend "
            "--seeds %d` (`make vf-study`); do not edit by hand.*" % seeds, "",
            "The paper's EDEM column (Table 3) is a rigid jar moving harmonically with "
            "frequency-independent contact parameters, and its v/f falls from 22.5 to 30 Hz: "
            "%.1f -> %.1f mm (%+.1f %%) for the 17.5 mm ball, %.1f -> %.1f mm (%+.1f %%) for "
            "the 20.6 mm ball. Which change of the twin's geometry, contact or drive makes that?"
            % (*EDEM_VF_MM[17.5], EDEM_TREND_PCT[17.5], *EDEM_VF_MM[20.6],
               EDEM_TREND_PCT[20.6]), ""]


def _run_lines(table, ok, seeds, info) -> list:
    """What was run: the variants' base, the balls and frequencies, the runs' counts."""
    PAPER_CONTACT = info["PAPER_CONTACT"]
    n_e2e = int((ok["motion_mode"] == "end_to_end").sum())
    return ["## What was run", "",
            "Each variant changes one thing (or a pair) from the default twin (D 28 mm, fillet "
            "5 mm, 25 mL, A 13.5 mm, straight stroke, YADE's rolling spring) at the paper's "
            "contact parameters (restitution %g, static friction %g, rolling friction %g) in "
            "the jar frame (the arc in the lab frame). Both balls (17.5 and 20.6 mm) at %g and "
            "%g Hz, %d start positions (seeds) each: %d runs asked for, %d finished (%d in "
            "end-to-end flight, the only ones used; the others are counted in `trend.csv`)."
            % (PAPER_CONTACT["restitution"], PAPER_CONTACT["static_friction"],
               PAPER_CONTACT["rolling_friction"], *info["FREQUENCIES_HZ"], seeds, len(table),
               len(ok), n_e2e), ""]


def _trend_row(i, r, tw) -> list:
    """One variant's row of the trend table (``tw``: trend.csv pivoted by ball)."""
    def at(col, d):
        return tw.loc[r.variant, (col, d)]
    return [str(i), r.variant, r.group,
            _pm(r.change_17_5_pct, r.se_17_5_pct) + " " + _ci(at("ci95_lo_pct", 17.5),
                                                              at("ci95_hi_pct", 17.5)),
            _pm(r.change_20_6_pct, r.se_20_6_pct) + " " + _ci(at("ci95_lo_pct", 20.6),
                                                              at("ci95_hi_pct", 20.6)),
            "%s / %s" % tuple(_pm(at("shift_from_default_pct_points", d),
                                  at("shift_se_pct_points", d)) for d in (17.5, 20.6)),
            "%s / %s" % (_f1(at("vf_22_5hz_mm", 17.5)), _f1(at("vf_22_5hz_mm", 20.6))),
            "%d / %d" % (at("not_end_to_end", 17.5), at("not_end_to_end", 20.6)),
            "yes" if r.gives_edem_pair else "no",
            "-" if not np.isfinite(r.lever_scale) else "%.1f / %.1f" % (
                r.lever_scale, r.lever_miss_pct_points),
            "yes" if r.finished else "**no**"]


def _trend_lines(trend, verd, ran, info, figure) -> list:
    """The change of v/f per variant against EDEM's, the figure and the conclusions."""
    EDEM_TREND_PCT, EDEM_VF_MM = info["EDEM_TREND_PCT"], info["EDEM_VF_MM"]
    tw = trend.pivot(index="variant", columns="ball_diameter_mm")
    rows = [_trend_row(i, r, tw)
            for i, r in enumerate(verd[verd["variant"].isin(ran)].itertuples(), 1)]
    rows.append(["", "paper's EDEM column", "-", "%+.1f" % EDEM_TREND_PCT[17.5],
                 "%+.1f" % EDEM_TREND_PCT[20.6], "-", "%.1f / %.1f" % (
                     EDEM_VF_MM[17.5][0], EDEM_VF_MM[20.6][0]), "-", "-", "-", "-"])
    L = ["## Change of v/f from 22.5 to 30 Hz", "",
         md_table(["#", "variant", "group", "17.5 mm: change +- se [95 % CI] [%]",
                   "20.6 mm: change +- se [95 % CI] [%]",
                   "shift from default 17.5 / 20.6 [points]",
                   "v/f at 22.5 Hz 17.5 / 20.6 [mm]", "runs not end-to-end",
                   "EDEM pair within 2 points", "lever k / miss [points]", "finished"],
                  rows), ""]
    if figure:
        L += ["![change of v/f per variant](vf_trend.png)", ""]
    return L + ["## What it says", ""] + ["- " + s for s in conclusions(trend, verd, info)] + [""]


def _definition_lines(defs, info) -> list:
    """The default twin's recordings read with each definition of the mean speed."""
    rows = []
    for key in info["SPEED_DEFINITIONS"]:
        g = defs[defs["definition"] == key].set_index("ball_diameter_mm")
        if g.empty:
            continue
        rows.append([key, info["SPEED_DEFINITIONS"][key]] + [
            "%s / %s" % (_f1(g.loc[d, "vf_22_5hz_mm"]), _f1(g.loc[d, "vf_30hz_mm"]))
            for d in (17.5, 20.6)] + [
            "%s / %s" % tuple(_pm(g.loc[d, "level_vs_3d_all_pct"], np.nan)
                              for d in (17.5, 20.6))] + [
            _pm(g.loc[d, "change_pct"], g.loc[d, "se_pct"]) for d in (17.5, 20.6)] + [
            "%s / %s" % tuple(_pm(g.loc[d, "change_minus_3d_all_pct_points"],
                                  g.loc[d, "change_minus_3d_all_se_pct_points"], 2)
                              for d in (17.5, 20.6))])
    L = ["## How a mean speed is defined (the default twin's recordings)", "",
         "The same recordings (default variant, end-to-end runs; the recording holds the "
         "lab-frame state at 2134 frames/s and every wall contact's start and end) read "
         "with several definitions of the mean speed. The last column is the change of "
         "the ratio (definition / 3-D all frames) run by run, so the seed scatter common "
         "to both cancels: the definition's own effect on the trend.", "",
         md_table(["definition", "what", "17.5 mm: v/f 22.5 / 30 Hz [mm]",
                   "20.6 mm: v/f 22.5 / 30 Hz [mm]",
                   "level vs 3d_all 17.5 / 20.6 [%]", "17.5 mm change +- se [%]",
                   "20.6 mm change +- se [%]",
                   "change minus 3d_all's 17.5 / 20.6 [points]"], rows), ""]
    return L + definitions_words(defs, info["EDEM_TREND_PCT"])


def definitions_words(defs, EDEM_TREND_PCT):
    z = defs["change_minus_3d_all_pct_points"] / defs["change_minus_3d_all_se_pct_points"]
    big = defs[(z.abs() > 2) & (defs["definition"] != "3d_all")]
    lines = ["- Definitions that move the 22.5 -> 30 Hz change by more than 2 se (paired): "]
    if big.empty:
        lines[0] += "none."
    else:
        lines[0] += "; ".join("%s on the %.1f mm ball %+.2f points" % (
            r.definition, r.ball_diameter_mm, r.change_minus_3d_all_pct_points)
            for r in big.itertuples()) + "."
    w = defs.pivot(index="definition", columns="ball_diameter_mm",
                   values="change_minus_3d_all_pct_points")
    need = {d: EDEM_TREND_PCT[d] - defs[(defs["definition"] == "3d_all")
                                        & (defs["ball_diameter_mm"] == d)]["change_pct"].iloc[0]
            for d in (17.5, 20.6)}
    lines.append("- Needed from the default twin's 3-D mean to EDEM: %+.1f points (17.5 mm) and "
                 "%+.1f points (20.6 mm); the largest definition effects: %s." % (
                     need[17.5], need[20.6], "; ".join(
                         "%s %+.2f / %+.2f" % (k, w.loc[k, 17.5], w.loc[k, 20.6])
                         for k in w.abs().max(axis=1).sort_values(ascending=False).index[:3])))
    return lines + [""]


#: the definitions shown in the page's variant x definition table
BY_VARIANT_SHOWN = ("3d_all", "3d_free_flight", "3d_saved_5ms", "chord_5ms", "chord_10ms")


def by_variant_lines(bv, EDEM_TREND_PCT, EDEM_VF_MM, match_points):
    """Section: every variant read with the main definitions, and the pairs that give EDEM's
    changes at once."""
    rows = []
    for name in dict.fromkeys(bv["variant"]):
        g = bv[bv["variant"] == name].set_index("definition")
        rows.append([name] + ["%s / %s" % (_pm(g.loc[k, "change_17_5_pct"], np.nan),
                                          _pm(g.loc[k, "change_20_6_pct"], np.nan))
                              if k in g.index else "-" for k in BY_VARIANT_SHOWN])
    L = ["## Each variant read with each definition", "",
         "Change of v/f from 22.5 to 30 Hz [%], 17.5 mm / 20.6 mm ball (the se of each is in "
         "`definitions_by_variant.csv`; about the size of the 3-D one's in the first table, "
         "larger for the sparse 10 ms samples).", "",
         md_table(["variant"] + list(BY_VARIANT_SHOWN), rows), ""]
    hit = bv[bv["gives_edem_pair"]]
    if hit.empty:
        L += ["- No variant read with any of the definitions gives EDEM's %+.1f %% and "
              "%+.1f %% within %g points at once." % (EDEM_TREND_PCT[17.5],
                                                      EDEM_TREND_PCT[20.6], match_points), ""]
    else:
        L += ["- Within %g points of EDEM's %+.1f %% and %+.1f %% at once (v/f at 22.5 Hz "
              "beside EDEM's %.1f / %.1f mm): %s." % (
                  match_points, EDEM_TREND_PCT[17.5], EDEM_TREND_PCT[20.6],
                  EDEM_VF_MM[17.5][0], EDEM_VF_MM[20.6][0], "; ".join(
                      "%s read as %s: %s %% / %s %% (v/f %.1f / %.1f mm)" % (
                          r.variant, r.definition, _pm(r.change_17_5_pct, r.se_17_5_pct),
                          _pm(r.change_20_6_pct, r.se_20_6_pct), r.vf_22_5hz_17_5_mm,
                          r.vf_22_5hz_20_6_mm) for r in hit.itertuples())),
              "- %d variant x definition pairs were compared, and the sparse definitions (10 ms: "
              "about 50 samples per run) carry se of 1-2 points, so a hit or two is expected by "
              "chance; a hit names a mechanism only when its level (v/f) fits EDEM's as well "
              "and its neighbours (the same variant at 5 ms, the same definition at the "
              "variant's other level) lean the same way." % len(bv), ""]
    return L
