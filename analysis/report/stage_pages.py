"""The pages the stages write into their own output folders, as Markdown text.

Each function takes what its stage has already computed and returns the page's text; the stage
writes it into its (atomic) output folder under the same file name as ever. Nothing here runs a
twin, fits or draws: the figures are drawn by :mod:`analysis.plotting`, the pages only link
them.

==============================================  ================================================
function                                        written by (file)
==============================================  ================================================
:func:`loop_page`                               ``analysis.loop`` (``report.md``)
:func:`demo_page`                               ``analysis.demo`` (``README.md``)
:func:`open_suite_page`                         ``analysis.open_suite`` (``README.md``)
:func:`apparatus_identification_page`           ``analysis.studies.apparatus_identification``
:func:`apparatus_screen_page`                   ``analysis.studies.apparatus_screen``
:func:`frame_equivalence_page`                  ``analysis.studies.frame_equivalence`` (``.md``)
==============================================  ================================================
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from analysis.report.markdown import frame_table_lines, has_tabulate


def _fmt_theta(t):
    return ", ".join("%s %.4g" % (k, v) for k, v in t.items())


# --------------------------------------------------------------------------------------------
# the loop
# --------------------------------------------------------------------------------------------
def _cell(x, fmt="%.4g"):
    if isinstance(x, (bool, np.bool_)):
        return str(bool(x))
    if isinstance(x, (float, np.floating)):
        return fmt % x if np.isfinite(x) else "-"
    if x is None or (not isinstance(x, str) and pd.isna(x)):
        return "-"
    return str(x)


def loop_page(res, dataset, *, fake=None, parameters=None, diagnosis=None, quoted=None,
              significance=None) -> str:
    """``report.md`` of :func:`analysis.loop.write_loop`: the verdict and which staircase rows
    it quotes, conditions, films, the staircase (each row named for what it is, the dof
    explained), parameters (stated strokes as stated, the unconstrained ones said to be so),
    candidates (in the order the page states, by columns it shows; the chi2 gain each needed),
    the significance as applied at each step and the model's run counts. ``res`` is an
    :class:`analysis.loop.LoopResult`, ``dataset`` the dataset it ran on; ``fake`` (default:
    from the runs' motion mode) marks a FAKE-twin run; ``parameters``, ``diagnosis``,
    ``quoted``, ``significance`` are what write_loop writes beside the page (default: derived
    from ``res``)."""
    from analysis.report.loop_words import FAKE, FAKE_WORDS, annotate_parameters, is_fake_run
    i = res.info
    fake = is_fake_run(res) if fake is None else bool(fake)
    synth = " (SYNTHETIC)" if dataset.meta.get("synthetic") else ""
    md = ["# The loop on %s%s%s" % (dataset.name, synth, " [%s twin]" % FAKE if fake else ""),
          ""]
    if fake:
        md += ["> **%s**" % FAKE_WORDS.replace("FAKE twin:", "FAKE TWIN:"), ""]
    md += ["**Verdict%s:** %s" % (" (%s twin)" % FAKE if fake else "", res.verdict), ""]
    stair = res.staircase.reset_index(drop=True)
    md += _verdict_context_lines(i, stair, quoted, fake)
    md += _staircase_lines(stair, quoted, fake)
    p = parameters if parameters is not None else annotate_parameters(
        res.parameters, getattr(dataset, "conditions", None))
    md += _parameter_lines(p)
    md += _candidate_lines(res, diagnosis if diagnosis is not None else res.diagnosis,
                           significance)
    if i.get("failed_runs"):
        md += ["", "%d twin run(s) failed and were left out of the model (loop.json "
               "`failed_runs`), e.g. %s: %s" % (len(i["failed_runs"]),
                                                i["failed_runs"][0]["run_id"],
                                                str(i["failed_runs"][0]["error"])[-120:])]
    md += _focus_lines(i.get("focus") or {})
    md += _rerun_rows(i.get("reruns") or [])
    md += ["", "![ranking](ranking.png)", "",
           "Model: the emulator fitted to %d twin runs at the dataset's conditions (%d new this "
           "time; waves: %s), reference point %s; wall time %.0f s."
           % (len(res.model_runs), i["new_runs"], _wave_counts(res.model_runs),
              _fmt_theta(i["reference_point"]), i["wall_s"]), ""]
    if fake:
        md += ["*%s.*" % FAKE_WORDS, ""]
    return "\n".join(md)


def _verdict_context_lines(i, stair, quoted, fake) -> list:
    """The staircase rows the verdict quotes, a pinned measurement chain, the conditions and
    the films tracked."""
    from analysis.report.loop_words import quoted_words
    md = []
    qw = quoted_words(stair, fake) if len(stair) else ""
    if qw:
        md += [qw, ""]
    pins = i.get("pinned_observation") or {}
    if pins:
        md += ["The measurement chain as videos/video.json states it, applied to every "
               "prediction and not diagnosed: %s." % "; ".join(
                   "%s (%s)" % (k, ", ".join("%s %g" % kv for kv in v.items()))
                   for k, v in pins.items()), ""]
    md += ["Velocity frame: %s. Conditions (matched by physics):" % i["velocity_frame"], ""]
    md += ["- %s: %s" % (c["condition_id"], c["label"]) for c in i["conditions"]]
    if i.get("tracking"):
        md += ["", "## Films tracked (ball and jar; tracks in tracks/)", ""]
        md += frame_table_lines(pd.DataFrame(i["tracking"]),
                                ["condition_id", "video", "n_frames", "n_lost", "n_reacquired",
                                 "m_per_px", "scale_source", "jar_n_lost"])
    return md


def _staircase_lines(stair, quoted, fake) -> list:
    """The staircase table, each row named for what it is (quoted rows starred), the dof
    explained, the figure."""
    from analysis.report.loop_words import dof_words, quoted_stages, stage_kind, stage_words
    quoted = quoted_stages(stair) if quoted is None and len(stair) else (quoted or {})
    md = ["", "## Staircase (chi2/dof)", "",
          "Each row is the model (the emulator fitted to every twin run made for this "
          "dataset, its own uncertainty in the likelihood) or the %s itself (fresh "
          "runs at the fitted point); rows in the loop's order."
          % ("FAKE twin (the analytic stand-in)" if fake else "real twin"), ""]
    qrows = {int(v): k for k, v in quoted.items()}
    cols = ["", "stage", "what it is", "chi2", "dof", "fitted parameters", "chi2/dof",
            "p_value"]
    md += ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for k, r in stair.iterrows():
        md.append("| %s | %s | %s: %s | %s | %s | %s | %s | %s |"
                  % ("*" if k in qrows else "", r["stage"], stage_kind(r["stage"], fake),
                     stage_words(r["stage"], fake), _cell(r.get("chi2")), _cell(r.get("dof"), "%d"),
                     _cell(r.get("n_params"), "%d"),
                     _cell(r["chi2_dof"], "%.3g") if float(r.get("dof", 1)) > 0 else
                     "untestable", _cell(r.get("p_value"), "%.3g")))
    md += [""] + ["- " + w for w in (dof_words(stair) if len(stair) else [])]
    return md + ["", "![staircase](staircase.png)"]


def _parameter_lines(p) -> list:
    """The parameters' table: value, se, the profile interval (open ends said), whether the
    data constrain it, the note; the rule for 'constrained'."""
    from analysis.report.loop_words import UNCONSTRAINED_RULE
    p = p.copy()
    if "note" not in p.columns:
        p["note"] = ""
    p["note"] = p["note"].fillna("")
    if "constrained" not in p.columns:
        p["constrained"] = None
    md = ["", "## Parameters", "",
          "| name | role | value | se | 95 % profile interval | constrained by the data | "
          "note |", "|---|---|---|---|---|---|---|"]
    for _, r in p.iterrows():
        c = r["constrained"]
        lo, hi = r.get("profile_lo"), r.get("profile_hi")
        iv = ("-" if lo is None or pd.isna(lo) else "%s - %s%s" % (
            _cell(lo), _cell(hi), " (open at the %s)" % (
                "lower and upper bounds" if r["profile_open"] == "lower upper"
                else "%s bound" % r["profile_open"])
            if isinstance(r.get("profile_open"), str) and r["profile_open"] else ""))
        md.append("| %s | %s | %s | %s | %s | %s | %s |"
                  % (r["name"], r["role"], _cell(r["value"]), _cell(r.get("se")), iv,
                     "-" if c is None or pd.isna(c) else ("yes" if bool(c) else "**no**"),
                     r["note"]))
    return md + ["", "The rule, once: " + UNCONSTRAINED_RULE + "."]


def _candidate_lines(res, d, significance) -> list:
    """The candidates' table in the order the page states, and the significance test as
    applied at each step (the bootstrap's false alarms beside it)."""
    from analysis.report.loop_words import step_scale
    md = ["", "## Candidates", "",
          "Order: the effects added first, in the order added (column `step`: the step that "
          "added them); then the last step's candidates, the identifiable ones first "
          "(column `identifiable`), each group by its chi2 gain (`delta_chi2`), largest "
          "first. `needed` is the chi2 gain the candidate had to exceed at its step (the test "
          "as applied, below); a candidate is significant when it is identifiable and its "
          "gain exceeds it.", ""]
    dc = ["rank", "effect", "kind", "identifiable", "significant", "delta_chi2", "needed",
          "strength", "strength_se", "p_bonferroni", "step"]
    md += ["| " + " | ".join(dc) + " |", "|" + "---|" * len(dc)]
    for _, r in d.iterrows():
        md.append("| " + " | ".join(_cell(r.get("delta_chi2_needed") if c == "needed"
                                          else r.get(c)) for c in dc) + " |")
    sig = significance
    if sig is None:
        sig = [{"step": k, "nominal_delta_chi2": float(g.threshold_delta_chi2),
                "bootstrap_scale": step_scale(res.steps, k),
                "applied_delta_chi2": float(g.threshold_delta_chi2) * step_scale(res.steps, k),
                "n_candidates": len(g.table), "alpha": float(g.alpha)}
               for k, g in enumerate(res.diagnoses, start=1)]
    boots = {int(b["step"]): b for b in (res.info.get("bootstrap") or [])}
    if sig:
        md += ["", "The significance test as applied, per step: a candidate's chi2 gain must "
               "exceed the Bonferroni threshold (the chi2_1 quantile at alpha / candidates, "
               "one-sided) times the bootstrap's scale (datasets drawn from the step's fitted "
               "model, diagnosed the same way; 1 where no draw was made), its F-test at the "
               "misfit it leaves (gain / chi2/dof after it, at the same level) and the BIC's "
               "ln n; the figure draws the first step.", ""]
        for b in sig:
            bs = boots.get(int(b["step"]))
            md.append("- step %d: %.3g (alpha %g over %d candidates) x %.2f = %.3g%s"
                      % (b["step"], b["nominal_delta_chi2"], b["alpha"], b["n_candidates"],
                         b["bootstrap_scale"], b["applied_delta_chi2"],
                         "; %d of %d bootstrap datasets named an effect at the nominal level"
                         % (bs["n_false"], bs["n_draws"]) if bs else ""))
    return md


def _focus_lines(fw) -> list:
    """The focus wave's two passes, before and after it (none without one)."""
    if not fw:
        return []
    b, a = fw["before"], fw["after"]
    return ["", "## Focus wave", "",
            "%d design points (%d twin runs) about the first pass's fit, with the effects it "
            "had found on; the emulator refitted with them, then the calibration and the "
            "selection done again (the staircase and the candidates above are that second "
            "pass)." % (fw["n_points"], fw["n_runs"]), "",
            "| pass | effects | chi2/dof (the model) | point |", "|---|---|---|---|",
            "| before the focus wave | %s | %s | %s |"
            % (", ".join(b["effects"]) or "none", _cell(b["chi2_dof"], "%.3g"),
               _fmt_theta(b["point"])),
            "| after it | %s | %s | %s |"
            % (", ".join(a["effects"]) or "none", _cell(a["chi2_dof"], "%.3g"),
               _fmt_theta(a["point"]))]


def _rerun_rows(reruns) -> list:
    """The twin reruns, one row a round: the twin's chi2/dof, the emulator's check of it, how
    far the refit moved and how far it leans on the emulator's uncertainty (loop.json
    ``reruns``)."""
    if not reruns:
        return []
    md = ["", "## Twin reruns", "",
          "Per round: the twin at the fitted point against the data; the emulator's prediction "
          "there against the rerun's means before they joined it (p >= 0.01: within its stated "
          "uncertainty); how far the refit with the rerun's runs moved the point; and how far "
          "the refitted point leans on the emulator's uncertainty - its sd as a share of the "
          "data's sd (largest over the observations) and the chi2/dof of its means with the "
          "data's sd alone. A point is sure when the share is at most 0.5 or those means fit "
          "(p >= alpha); one that is not, or a rerun the emulator missed, gets a focus wave "
          "before the next round.", "",
          "| round | twin rerun chi2/dof | emulator vs twin p | refit moved [se] | emulator sd / "
          "data sd | chi2/dof at its means, data sd alone | sure | focus wave after |",
          "|---|---|---|---|---|---|---|---|"]
    for r in reruns:
        ev, lean = r.get("emulator_vs_twin") or {}, r.get("lean") or {}
        md.append("| %d | %s | %s | %s | %s | %s | %s | %s |" % (
            r["round"], _cell(r["chi2"] / max(r["dof"], 1), "%.3g"),
            _cell(ev.get("p"), "%.2g"), _cell(r.get("moved_se"), "%.2f"),
            _cell(lean.get("share"), "%.2f"),
            _cell(lean["chi2_data"] / max(lean["dof"], 1), "%.3g") if lean else "-",
            "-" if not lean else ("yes" if lean["sure"] else "**no**"),
            "%d runs" % r["focus"]["n_runs"] if r.get("focus") else "-"))
    return md


def _wave_counts(runs) -> str:
    if "wave" not in runs.columns:
        return "-"
    n = runs.groupby(runs["wave"].astype(str), sort=False).size()
    return ", ".join("%s %d runs" % ("wave " + k if k[:1].isdigit() else k, v)
                     for k, v in n.items())


# --------------------------------------------------------------------------------------------
# demonstrations and suites
# --------------------------------------------------------------------------------------------
def demo_page(table, meta, extra=()) -> str:
    """``README.md`` of :mod:`analysis.demo`: the twin at the paper's 8 conditions beside
    Table 3 (``table``: :func:`analysis.demo.summarize_runs`), the run settings (``meta``:
    apparatus, amplitude_m, dt_s, replicates, record_s, wall_s) and the contract lines
    (``extra``)."""
    cols = ["condition_id", "v_mean_measured_m_s", "v_mean_twin_observed_m_s",
            "v_mean_twin_sd_m_s", "v_diff_pct", "f_col_measured_hz", "f_col_twin_observed_hz",
            "f_col_twin_se_hz", "f_col_diff_pct", "motion_modes", "n_replicates"]
    lines = ["# Demo: the twin at the paper's 8 conditions", "",
             "Paper contact parameters (C_R = 0.11, SF = 0.7, RF = 0.5) in %s: jar "
             "amplitude A = %.1f mm, dt = %g s, %d replicate(s) per condition, %.2f s recorded "
             "after the detected steady state. Speeds and collision frequencies pass through "
             "the same observation operator as a video (2134 fps, lab frame). Wall time %.0f s."
             % (meta.get("apparatus", "the default jar and stroke"), meta["amplitude_m"] * 1e3,
                meta["dt_s"], meta["replicates"], meta["record_s"], meta["wall_s"]), "",
             table[cols].to_markdown(index=False, floatfmt=".3g")
             if has_tabulate() else "```\n" + table[cols].to_string(index=False) + "\n```", "",
             "mean |v error| = %.2f %%, max = %.2f %%; f_col (the rate from the impact "
             "times) within 0.3 %% of the measured value at %d of %d conditions, largest "
             "|f_col diff| %.2f %%."
             % (table["v_diff_pct"].abs().mean(), table["v_diff_pct"].abs().max(),
                int((table["f_col_diff_pct"].abs() <= 0.3).sum()), len(table),
                table["f_col_diff_pct"].abs().max()),
             ""] + ["- " + x for x in extra] + ["", "![v_mean over frequency](demo.png)", "",
                                                 "## Why the paper's parameters and the "
                                                 "calibrated ones differ", "",
                                                 demo_why_words(meta), ""]
    return "\n".join(lines)


def demo_why_words(meta) -> str:
    """The demo page's two sentences on why the paper's parameters (C_R 0.11, A as in
    ``meta``) and the calibrated ones (the loop's, the measured-apparatus profile's) differ."""
    identified = "paper's DEM" in str(meta.get("apparatus", ""))
    return ("The paper's contact parameters (C_R 0.11, SF 0.7, RF 0.5) are the inputs of the "
            "paper's EDEM model, and the stroke A = %.1f mm beside them %s: they stand for the "
            "paper's simulation, not for the measurements. The calibrated parameters (the "
            "loop's in "
            "[loop/report.md](loop/report.md), the calibrated line above) are fitted to the "
            "measured column of Table 3 with this twin's own contact law, which is not EDEM's "
            "(docs/apparatus.md), and the twin has no mechanism for the measured fall of v/f "
            "with frequency, so the fit buys the speeds' level with restitution and stroke - a "
            "different target and a different contact law, not one set correcting the other."
            % (float(meta["amplitude_m"]) * 1e3,
               "was fitted so that this twin reproduces the paper's DEM column" if identified
               else "is the twin's default"))


def open_suite_page(summ, goal_lines, datasets, figure=None, notes="", *,
                    detectable_chi2) -> str:
    """``README.md`` of :mod:`analysis.open_suite`: the goal lines with their counts
    (``goal_lines``: :func:`analysis.open_suite.goal_lines`) and one row per dataset of the
    summary table ``summ``; ``datasets`` is the datasets' folder as shown on the page,
    ``figure`` the suite's PNG beside the page (None: none), ``notes`` text appended,
    ``detectable_chi2`` the goal lines' detectability bar
    (:data:`analysis.open_suite.DETECTABLE_CHI2`)."""
    md = ["# The loop on blind open-world datasets (SYNTHETIC)", "",
          "Datasets: `%s` (the twin once per condition at conditions the paper never ran, "
          "base parameters drawn from the Table-3 calibration's posterior, measurement noise, "
          "jar tracks, yields; `*_film`: the same delivered as films)." % datasets, ""]
    md += ["- " + x for x in goal_lines]
    if figure:
        md += ["", "![strengths against the truth; chi2/dof per dataset](%s)" % figure]
    md += ["", "Detectability: the chi2 the hidden effects explain in the twin's own values "
           "at the truth (no measurement noise, one realisation's chaos): the base parameters "
           "fitted on the loop's final emulator without them, less with them at their true "
           "strengths (>= %g: named with 90 %% power). Covered: every hidden strength inside "
           "its 95 %% interval." % detectable_chi2, "",
           "| dataset | hidden | detectability chi2 | found | covered | chi2/dof calibrated "
           "| last | twin rerun |", "|---|---|---|---|---|---|---|---|"]
    for r in summ.to_dict("records"):
        det = r.get("detectable_chi2", float("nan"))
        cov = r.get("covered", float("nan"))
        md.append("| %s | %s | %s | %s | %s | %.2f | %.2f | %.2f |" % (
            r["dataset"], r["hidden"], "-" if det != det else "%.1f" % det, r["found"],
            "-" if cov != cov else ("yes" if cov else "NO"), r["chi2_dof_calibrated"],
            r["chi2_dof_last"], r["chi2_dof_twin_rerun"]))
    if notes.strip():
        md += ["", notes.strip()]
    return "\n".join(md) + "\n"


# --------------------------------------------------------------------------------------------
# studies (analysis/studies) that write their own page
# --------------------------------------------------------------------------------------------
def apparatus_identification_page(cal_dir, summary, base, params, corr, residuals, mean_abs,
                                  max_abs, shape_twin, shape_target, goal_mean_pct,
                                  goal_max_pct) -> str:
    """``README.md`` beside a calibration with apparatus parameters free
    (:mod:`analysis.studies.apparatus_identification`): the posterior (``params``, the
    calibration's parameters.csv; ``corr``, the posterior correlations), the residual per
    condition (``residuals``) with its mean and max |diff| [%] against the goals, the shape
    figures of twin and target, and the calibration's figures found in ``cal_dir``."""
    cal_dir = Path(cal_dir)
    names = list(params.index)
    t = residuals
    tw, tg = shape_twin, shape_target
    lines = ["# The apparatus identified: %s" % summary.get("dataset", ""), "",
             "Calibration folder `%s` (`python -m analysis.calibrate --free ...`), fixed in "
             "every run: %s. %d twin runs in the loop's emulator of the twin, built in waves "
             "where the data are plausible; the posterior sampled on it with emcee; then the "
             "real twin at the fitted point. Regenerate this page: `python -m "
             "analysis.studies.apparatus_identification --cal %s`."
             % (cal_dir.name, ", ".join("%s %s" % kv for kv in base.items()) or "-",
                summary["n_runs"], cal_dir), "",
             "## Posterior", "",
             "| parameter | mean | sd | 95 % interval | prior range | interval / prior width |",
             "|---|---|---|---|---|---|"]
    for k, r in params.iterrows():
        width = (r["q97.5"] - r["q2.5"]) / (r["prior_upper"] - r["prior_lower"])
        lines.append("| %s | %.4g | %.2g | [%.4g, %.4g] | %.4g - %.4g | %.2f |"
                     % (k, r["mean"], r["sd"], r["q2.5"], r["q97.5"], r["prior_lower"],
                        r["prior_upper"], width))
    strong = [(a, b, corr.loc[a, b]) for i, a in enumerate(names) for b in names[i + 1:]
              if abs(corr.loc[a, b]) >= 0.5]
    lines += ["", "How unique: an interval / prior width near 1 means the speeds do not pin "
              "that parameter. Posterior correlations |r| >= 0.5 (trade-offs: moving one along "
              "the other keeps the speeds): %s." % ("; ".join("%s-%s %+.2f" % s for s in strong)
                                                    or "none"), "",
              "## Residual per condition (twin at the posterior mean)", "",
              "| condition | target v [m/s] | twin v [m/s] | twin sd | diff [%] |",
              "|---|---|---|---|---|"]
    for r in t.itertuples():
        lines.append("| %s | %.3f | %.3f | %.3f | %+.2f |"
                     % (r.condition_id, r.v_mean_measured_m_s, r.v_mean_twin_m_s,
                        r.v_mean_twin_sd_m_s, r.diff_pct))
    lines += ["", "mean |diff| %.2f %%, max %.2f %% (goal <= %.1f %% and <= %.1f %%)."
              % (mean_abs, max_abs, goal_mean_pct, goal_max_pct), "",
              "Shape: v/f [mm] 17.5 mm ball %.1f (target %.1f), 20.6 mm ball %.1f (%.1f); "
              "split %+.1f %% (%+.1f %%); 22.5 -> 30 Hz change of v/f %+.1f %% (%+.1f %%) and "
              "%+.1f %% (%+.1f %%)."
              % (tw["vf_17_5_mm"], tg["vf_17_5_mm"], tw["vf_20_6_mm"], tg["vf_20_6_mm"],
                 tw["split_pct"], tg["split_pct"], tw["trend_17_5_pct"], tg["trend_17_5_pct"],
                 tw["trend_20_6_pct"], tg["trend_20_6_pct"]), ""]
    for f in ("posterior_pairs.png", "parity.png"):
        if (cal_dir / f).exists():
            lines.append("![%s](%s)" % (f, f))
    return "\n".join(lines) + "\n"


def apparatus_screen_page(summary, seeds, out) -> str:
    """``README.md`` of :mod:`analysis.studies.apparatus_screen`: one row per variant of the
    screen ``summary`` (``seeds`` start positions each), and links to the pages of the next
    steps of ``make apparatus`` found in the folder ``out``."""
    out = Path(out)
    lines = ["# The apparatus: screen at the paper's contact parameters", "",
             "C_R 0.11, SF 0.7, RF 0.5; the 8 conditions of Table 3, %d start positions each; "
             "one change from the default twin per row. v/f in mm (mean over the conditions "
             "of each ball); split = 17.5 mm ball over 20.6 mm ball; trend = v/f at 30 Hz "
             "over v/f at 22.5 Hz; runs not in end-to-end flight are left out of the figures "
             "and counted. `python -m analysis.studies.apparatus_screen`." % seeds, "",
             "| variant | v/f 17.5 mm | v/f 20.6 mm | split % | trend 17.5 % | trend 20.6 % "
             "| mean abs diff to EDEM % | runs (not end-to-end) |",
             "|---|---|---|---|---|---|---|---|"]
    for r in summary.itertuples():
        lines.append("| %s | %.1f | %.1f | %+.1f | %+.1f | %+.1f | %.1f | %s |"
                     % (r.variant, r.vf_17_5_mm, r.vf_20_6_mm, r.split_pct, r.trend_17_5_pct,
                        r.trend_20_6_pct, r.mean_abs_diff_dem_pct,
                        "-" if np.isnan(r.runs) else "%d (%d)" % (r.runs, r.not_end_to_end)))
    lines += ["", "Next steps of `make apparatus` (docs/apparatus.md): the apparatus identified "
              "from the paper's DEM column at its contact parameters, then contact and "
              "apparatus calibrated on the measurements."]
    for sub, what in (("identify_paper_dem", "identified from the paper's DEM column"),
                      ("calibrate_measured", "calibrated on Table 3's measurements")):
        if (out / sub / "README.md").exists():
            lines.append("- [%s](%s/README.md): %s" % (sub, sub, what))
    for sd in ("0.5", "1", "1.5", "2"):
        sub = "loop_table3_end_fillet_sd%s" % sd
        if (out / sub / "report.md").exists():
            lines.append("- [%s](%s/report.md): the loop on Table 3 with the end fillet in its "
                         "catalog, v sd %s %% assumed" % (sub, sub, sd))
    return "\n".join(lines) + "\n"


def frame_equivalence_page(tab, wall_lab, wall_jar, n_seeds, compared) -> str:
    """``frame_equivalence.md`` of :mod:`analysis.studies.frame_equivalence`: the jar frame
    against the lab frame per condition (``tab``), summarised over the ``compared``
    observables' z, with the wall times per run of each frame (``wall_lab``, ``wall_jar``:
    lists of seconds, empty where the runs are not cached here)."""
    wl, wj = wall_lab, wall_jar
    zs = np.concatenate([tab[c + "_z"].dropna().to_numpy() for c in compared])
    lines = ["# Jar frame against lab frame, 8 paper conditions x %d seeds" % n_seeds, "",
             "Per condition and observable: z = (jar mean - lab mean) / se (%d seeds each; the "
             "run sd pooled over the 8 conditions and both frames). "
             "|z| > 2: %d of %d; mean z^2 %.2f (1 if the frames agree within the chaos)."
             % (n_seeds, int(np.sum(np.abs(zs) > 2)), zs.size, float(np.mean(zs ** 2))),
             "Motion modes equal at %d of %d conditions." % (
                 int((tab["modes_lab"] == tab["modes_jar"]).sum()), len(tab)),
             "Wall time per run on this machine: lab %s, jar %s." % (
                 "%.1f s (n %d)" % (np.mean(wl), len(wl)) if wl else "(lab runs not cached "
                 "here)", "%.1f s (n %d)" % (np.mean(wj), len(wj)) if wj else "-"), "",
             "| condition | v lab | v jar | z | f_col lab | f_col jar | z | v_in z | e_app z "
             "| phase z | modes lab / jar |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in tab.itertuples():
        lines.append("| %s | %.3f | %.3f | %+.1f | %.1f | %.1f | %+.1f | %+.1f | %+.1f | %+.1f "
                     "| %s / %s |" % (r.condition_id, r.v_mean_m_s_lab, r.v_mean_m_s_jar,
                                      r.v_mean_m_s_z, r.f_col_hz_lab, r.f_col_hz_jar,
                                      r.f_col_hz_z, r.v_in_m_s_z, r.e_app_z,
                                      r.impact_phase_rad_z, r.modes_lab, r.modes_jar))
    return "\n".join(lines) + "\n"


