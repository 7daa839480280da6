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
:func:`hidden_suite_page`,                      ``analysis.hidden_suite`` (``README.md``; the
:func:`hidden_suite_comparison_section`         section is appended with ``--also-without-tracks``)
:func:`hidden_demo_page`                        ``analysis.hidden_demo`` (``report.md``)
:func:`open_suite_page`                         ``analysis.open_suite`` (``README.md``)
:func:`comparison_page`                         ``analysis.compare`` (``comparison.md``)
:func:`diagnosis_page`                          ``analysis.diagnose`` (``diagnosis.md``)
:func:`signatures_page`                         ``analysis.twin_model`` (signature library
                                                ``README.md``)
:func:`apparatus_identification_page`           ``analysis.studies.apparatus_identification``
:func:`apparatus_screen_page`                   ``analysis.studies.apparatus_screen``
:func:`frame_equivalence_page`                  ``analysis.studies.frame_equivalence`` (``.md``)
:func:`paper_diagnosis_page`                    ``analysis.studies.paper_diagnosis``
==============================================  ================================================
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd

from analysis.report.markdown import frame_table_lines, has_tabulate


def _fmt_theta(t):
    return ", ".join("%s %.4g" % (k, v) for k, v in t.items())


def _pct(x):
    return "n/a" if x is None else "%.0f %%" % (100 * x)


def _candidate_table_lines(table, cols):
    """diagnose's candidate table: floats with 3 significant digits."""
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for _, r in table.iterrows():
        lines.append("| " + " | ".join(("%.3g" % r[c]) if isinstance(r[c], float) else str(r[c])
                                      for c in cols) + " |")
    return lines


# --------------------------------------------------------------------------------------------
# the loop, compare, diagnose
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
    from analysis.report.loop_words import (FAKE, FAKE_WORDS, UNCONSTRAINED_RULE,
                                            annotate_parameters, dof_words, is_fake_run,
                                            quoted_stages, quoted_words, stage_kind,
                                            stage_words, step_scale)
    i = res.info
    fake = is_fake_run(res) if fake is None else bool(fake)
    synth = " (SYNTHETIC)" if dataset.meta.get("synthetic") else ""
    md = ["# The loop on %s%s%s" % (dataset.name, synth, " [%s twin]" % FAKE if fake else ""),
          ""]
    if fake:
        md += ["> **%s**" % FAKE_WORDS.replace("FAKE twin:", "FAKE TWIN:"), ""]
    md += ["**Verdict%s:** %s" % (" (%s twin)" % FAKE if fake else "", res.verdict), ""]
    stair = res.staircase.reset_index(drop=True)
    quoted = quoted_stages(stair) if quoted is None and len(stair) else (quoted or {})
    qw = quoted_words(stair) if len(stair) else ""
    if qw:
        md += [qw, ""]
    md += ["Velocity frame: %s. Conditions (matched by physics):" % i["velocity_frame"], ""]
    md += ["- %s: %s" % (c["condition_id"], c["label"]) for c in i["conditions"]]
    if i.get("tracking"):
        md += ["", "## Films tracked (ball and jar; tracks in tracks/)", ""]
        md += frame_table_lines(pd.DataFrame(i["tracking"]),
                                ["condition_id", "video", "n_frames", "n_lost", "n_reacquired",
                                 "m_per_px", "scale_source", "jar_n_lost"])
    md += ["", "## Staircase (chi2/dof)", "",
           "Each row is the model (the emulator fitted to every twin run made for this "
           "dataset, its own uncertainty in the likelihood) or the real twin itself (fresh "
           "runs at the fitted point); rows in the loop's order.", ""]
    qrows = {int(v): k for k, v in quoted.items()}
    cols = ["", "stage", "what it is", "chi2", "dof", "fitted parameters", "chi2/dof",
            "p_value"]
    md += ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for k, r in stair.iterrows():
        md.append("| %s | %s | %s: %s | %s | %s | %s | %s | %s |"
                  % ("*" if k in qrows else "", r["stage"], stage_kind(r["stage"]),
                     stage_words(r["stage"]), _cell(r.get("chi2")), _cell(r.get("dof"), "%d"),
                     _cell(r.get("n_params"), "%d"),
                     _cell(r["chi2_dof"], "%.3g") if float(r.get("dof", 1)) > 0 else
                     "untestable", _cell(r.get("p_value"), "%.3g")))
    md += [""] + ["- " + w for w in (dof_words(stair) if len(stair) else [])]
    md += ["", "![staircase](staircase.png)", "", "## Parameters", ""]
    p = parameters if parameters is not None else annotate_parameters(
        res.parameters, getattr(dataset, "conditions", None))
    p = p.copy()
    if "note" not in p.columns:
        p["note"] = ""
    p["note"] = p["note"].fillna("")
    if "constrained" not in p.columns:
        p["constrained"] = None
    md += ["| name | role | value | se | 95 % profile interval | constrained by the data | "
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
    md += ["", "The rule, once: " + UNCONSTRAINED_RULE + ".", "", "## Candidates", ""]
    d = diagnosis if diagnosis is not None else res.diagnosis
    md += ["Order: the effects added first, in the order added (column `step`: the step that "
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
    boots = {int(b["step"]): b for b in (i.get("bootstrap") or [])}
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
    md += ["", "![ranking](ranking.png)", "",
           "Model: the emulator fitted to %d twin runs at the dataset's conditions (%d new this "
           "time; waves: %s), reference point %s; wall time %.0f s."
           % (len(res.model_runs), i["new_runs"], _wave_counts(res.model_runs),
              _fmt_theta(i["reference_point"]), i["wall_s"]), ""]
    if fake:
        md += ["*%s.*" % FAKE_WORDS, ""]
    return "\n".join(md)


def _wave_counts(runs) -> str:
    if "wave" not in runs.columns:
        return "-"
    n = runs.groupby(runs["wave"].astype(str), sort=False).size()
    return ", ".join("%s %d runs" % ("wave " + k if k[:1].isdigit() else k, v)
                     for k, v in n.items())


def comparison_page(cmp, dataset, figures=()) -> str:
    """``comparison.md`` of :func:`analysis.compare.write_report`: headline, plain-words lines,
    the table, figures. ``cmp`` is an :class:`analysis.compare.Comparison`."""
    t = cmp.table
    synth = getattr(dataset, "synthetic", False)
    out = ["# Twin vs %s: %s" % ("SYNTHETIC data" if synth else "measurements", dataset.name),
           ""]
    if synth:
        out += ["> **SYNTHETIC DATA**: this dataset says it is synthetic (dataset.json "
                "`\"synthetic\": true`): its 'measured' values were generated, not measured.", ""]
    out += ["Source: %s (velocity frame: %s)." % (dataset.source, dataset.velocity_frame), ""]
    out += [cmp.summary(), ""]
    if t["measured_sd_default"].any():
        out.append("Measured sd missing for %d row(s): default uncertainty used (see "
                   "analysis/measurements.py)." % int(t["measured_sd_default"].sum()))
    if t["model_sd_default"].any():
        out.append("Twin replicate sd missing for %d row(s): default used." %
                   int(t["model_sd_default"].sum()))
    if t.get("one_realisation", pd.Series(False, index=t.index)).any():
        out.append("Impact observables (analysis.flights) come from one measured track each: "
                   "their sigma also holds one twin run's sd; diff % is left out for them.")
    out += ["", "| condition | observable | %s | model (mean +- se, n) | diff %% | z |"
            % ("SYNTHETIC 'measured'" if synth else "measured"),
            "|---|---|---|---|---|---|"]
    for _, r in t.iterrows():
        obs = r["observable"] + ("" if not np.isfinite(r["time_min"]) else
                                 " @ %g min" % r["time_min"])
        rel = ("%+.1f" % r["rel_residual_pct"] if np.isfinite(r["rel_residual_pct"])
               else "-")
        out.append("| %s | %s | %.4g +- %.2g | %.4g +- %.2g (%d) | %s | %+.2f |"
                   % (r["label"], obs, r["measured"], r["measured_sd"], r["model_mean"],
                      r["model_se"], r["n_replicates"], rel, r["z"]))
    out.append("")
    for f in figures:
        out += ["![%s](%s)" % (Path(f).stem, Path(f).name), ""]
    return "\n".join(out)


def diagnosis_page(diag, added=None, dataset_name: str = "", synthetic: bool = False) -> str:
    """``diagnosis.md`` of :func:`analysis.diagnose.write_diagnosis`: the verdict, the ranked
    candidates and, with ``added`` (an :class:`analysis.diagnose.AddEffectResult`), the effect
    switched on. ``synthetic`` (the dataset's own flag) marks the page SYNTHETIC."""
    cols = ["rank", "effect", "kind", "delta_chi2", "p_bonferroni", "strength",
            "strength_se", "footprint", "absorbed_frac", "identifiable", "significant"]
    md = ["# Which effect is missing? %s%s" % (dataset_name,
                                               " (SYNTHETIC data)" if synthetic else ""), ""]
    if synthetic:
        md += ["> **SYNTHETIC DATA**: the dataset says it is synthetic (dataset.json "
               "`\"synthetic\": true`), not measured.", ""]
    md += ["**Verdict:** %s" % diag.verdict, ""]
    md += _candidate_table_lines(diag.table, cols)
    md += ["", "![ranking](ranking.png)", ""]
    if added is not None:
        md += ["## Adding %s" % added.effect, "", added.summary(), "",
               "![staircase](staircase.png)", ""]
    return "\n".join(md)


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


def hidden_suite_page(summ, pe) -> str:
    """``README.md`` of :func:`analysis.hidden_suite.write_report`: the suite's figures against
    their goals (``summ``: :func:`analysis.hidden_suite.summarise`) and the per-case table
    (``pe``: :func:`analysis.hidden_suite.per_effect`)."""
    lines = ["# Hidden-effect suite", "",
             "Datasets made by the real twin at the calibrated parameters with one catalog effect "
             "hidden (or none), diagnosed blind with `analysis.twin_model` (see "
             "`analysis/hidden_suite.py`). SYNTHETIC data throughout. Each dataset holds "
             "v_mean and f_col (noise 1.5 % and 1 /s plus the twin's scatter), yields at "
             "2.5-10 min (1 point) and a track of the ball and the jar per condition (2134 "
             "frames/s, 5 um tracking noise), which the diagnosis reads into impact "
             "observables (`analysis.flights`).", "",
             "| figure | value | goal |", "|---|---|---|",
             "| datasets (effect / none) | %d / %d | |" % (summ["n_effect_datasets"],
                                                       summ["n_null_datasets"]),
             "| effect datasets moving an observable >= 3 sigma (raw, before recalibration) "
             "| %d | |" % summ["n_effect_datasets_ge_3sigma_raw"],
             "| ... of those, true effect ranked first | %s | |" % _pct(summ["rank1_rate_raw"]),
             "| effect datasets moving an observable >= 3 sigma after the best recalibration "
             "without the effect (the identifiable part) | %d | |"
             % summ["n_effect_datasets_ge_3sigma"],
             "| ... of those, true effect ranked first | %s | >= 90 %% |" % _pct(summ["rank1_rate"]),
             "| true effect reported (significant) | %s | |" % _pct(summ["true_reported_rate"]),
             "| decoy (air drag) significant | %d | 0 |" % summ["decoy_significant"],
             "| no-effect datasets: nothing missing | %d / %d | all |"
             % (summ["null_nothing_missing"], summ["n_null_datasets"]),
             "| added effects starting from chi2/dof >= 4.5 that end <= 1.5 | %d / %d | all |"
             % (summ["added_reaching_1.5"], summ["n_added_from_ge_4.5"]),
             "| median time per diagnosis + add | %.1f s | |"
             % summ["median_seconds_per_diagnosis"], "",
             "## Per case", "", pe.to_markdown(index=False, floatfmt=".3g")
             if hasattr(pe, "to_markdown") and has_tabulate()
             else "```\n" + pe.to_string(index=False, float_format=lambda x: "%.3g" % x)
             + "\n```",
             "", "![confusion](confusion.png)", ""]
    return "\n".join(lines)


def hidden_suite_comparison_section(summ, summ0, pe, pe0) -> str:
    """The section :mod:`analysis.hidden_suite` appends to its page with
    ``--also-without-tracks``: the same datasets' figures with (``summ``, ``pe``) and without
    (``summ0``, ``pe0``) the jar tracks."""
    keys = [("rank1_rate", "true effect ranked first (datasets >= 3 sigma after "
             "recalibration)", _pct), ("n_effect_datasets_ge_3sigma", "... how many", str),
            ("rank1_rate_raw", "true effect ranked first (datasets >= 3 sigma raw)", _pct),
            ("decoy_significant", "decoy significant", str),
            ("null_nothing_missing", "no-effect datasets: nothing missing", str),
            ("added_reaching_1.5", "added from chi2/dof >= 4.5 ending <= 1.5", str),
            ("n_added_from_ge_4.5", "... how many start >= 4.5", str)]
    lines = ["", "## With and without the jar tracks", "",
             "The same datasets diagnosed on v_mean, f_col and the yields alone "
             "(`without_tracks/`), against the default that also reads the impact observables "
             "of the jar tracks (`analysis.flights`):", "",
             "| figure | with jar tracks | without |", "|---|---|---|"]
    for k, label, f in keys:
        lines.append("| %s | %s | %s |" % (label, f(summ[k]), f(summ0[k])))
    m = pe[["case", "rank1_rate"]].merge(pe0[["case", "rank1_rate"]], on="case",
                                         suffixes=("_with", "_without"))
    lines += ["", "Rank-1 rate per case (all 5 noise seeds): " + "; ".join(
        "%s %.0f %% / %.0f %%" % (r.case, 100 * r.rank1_rate_with, 100 * r.rank1_rate_without)
        for r in m.itertuples()) + ".", ""]
    return "\n".join(lines)


def hidden_demo_page(cmp0, diag, added, stair, reveal, times) -> str:
    """``report.md`` of :mod:`analysis.hidden_demo`: compare (``cmp0``, the calibrated twin
    without effects), diagnose (``diag``), add and verify (``added``, the staircase ``stair``),
    and the reveal of the hidden effect (``reveal``), with the stages' wall times."""
    cols = ["rank", "effect", "kind", "delta_chi2", "p_bonferroni", "strength", "strength_se",
            "absorbed_frac", "identifiable", "significant"]
    lines = ["# Hidden-effect demo (SYNTHETIC data from the twin)", "",
             "A secret effect was switched on in the twin; the dataset (v_mean, f_col, yields at "
             "8 conditions, with noise; a track of the ball and the jar per condition, read by "
             "analysis.flights into impact observables) was then compared, diagnosed and "
             "corrected blind. Compare, diagnose and the chi2/dof staircase all read the "
             "impact observables beside v_mean, f_col and the yields.", "",
             "## 1. Compare: the calibrated twin without effects", "",
             "chi2/dof = %.2f (dof %d). Where it fails:" % (cmp0.chi2 / max(cmp0.dof, 1),
                                                           cmp0.dof), "", "```",
             cmp0.summary(2.0), "```", "", "![overview](overview.png)", "",
             "## 2. Diagnose", "", "**Verdict:** " + diag.verdict, ""]
    lines += _candidate_table_lines(diag.table, cols)
    lines += ["", "![ranking](diagnose/ranking.png)", "", "## 3. Add and verify", ""]
    if added is not None:
        lines += [added.summary(), ""]
    lines += ["| stage | chi2 | dof | chi2/dof |", "|---|---|---|---|"]
    for r in stair.itertuples():
        lines.append("| %s | %.1f | %d | %.2f |" % (r.stage, r.chi2, r.dof, r.chi2_dof))
    lines += ["", "The last row reruns the real twin at the refitted parameters with the added "
              "effect (not the emulator).", "", "## 4. Reveal", "",
              "| | |", "|---|---|",
              "| hidden effect | %s %s |" % (reveal["hidden_effect"], reveal["hidden_params"]),
              "| hidden strength (diagnose coordinate) | %.3g |" % reveal["hidden_strength"],
              "| reported | %s (%s) |" % (reveal["reported"], reveal["status"]),
              "| rank of the hidden effect | %s |" % reveal["true_rank"],
              "| its fitted strength | %s |" % (
                  "%.3g +- %.2g" % (reveal["fitted_strength"], reveal["fitted_strength_se"])
                  if reveal["fitted_strength"] is not None else "-"),
              "| found | %s |" % ("yes" if reveal["found"] else "NO"), "",
              "Times: " + ", ".join("%s %.0f s" % (k, v) for k, v in times.items()), ""]
    return "\n".join(lines)


def open_suite_page(summ, goal_lines, datasets, figure=None, notes="") -> str:
    """``README.md`` of :mod:`analysis.open_suite`: the goal lines with their counts
    (``goal_lines``: :func:`analysis.open_suite.goal_lines`) and one row per dataset of the
    summary table ``summ``; ``datasets`` is the datasets' folder as shown on the page,
    ``figure`` the suite's PNG beside the page (None: none), ``notes`` text appended."""
    md = ["# The loop on blind open-world datasets (SYNTHETIC)", "",
          "Datasets: `%s` (the twin once per condition at conditions the paper never ran, "
          "off-anchor base parameters, measurement noise, jar tracks, yields; `*_film`: the "
          "same delivered as films)." % datasets, ""]
    md += ["- " + x for x in goal_lines]
    if figure:
        md += ["", "![strengths against the truth; chi2/dof per dataset](%s)" % figure]
    md += ["", "| dataset | hidden | found | chi2/dof calibrated | last | twin rerun |",
           "|---|---|---|---|---|---|"]
    for r in summ.itertuples():
        md.append("| %s | %s | %s | %.2f | %.2f | %.2f |" % (
            r.dataset, r.hidden, r.found, r.chi2_dof_calibrated, r.chi2_dof_last,
            r.chi2_dof_twin_rerun))
    if notes.strip():
        md += ["", notes.strip()]
    return "\n".join(md) + "\n"


def signatures_page(summ, top, meta, late_v_in_frac) -> str:
    """``README.md`` of the signature library (:mod:`analysis.twin_model`): what it is, the
    signatures table, the impact observables, the levels in the 'late' pattern, the figure.
    ``summ`` is the library summary (every level), ``top`` its rows at each label's largest
    strength (:func:`analysis.twin_model.top_level`), ``meta`` the library.json contents and
    ``late_v_in_frac`` the approach-speed fraction that defines the 'late' pattern."""
    from analysis.flights import FLIGHT_OBSERVABLES
    from analysis.catalog import Candidate
    full = summ
    summ = top
    cands = {c["name"]: c for c in meta["candidates"]}
    a = summ[summ["label"] == "none"]
    rel = 100 * float(np.sqrt(np.nanmean((a["v_sd_m_s"] / a["v_mean_m_s"]) ** 2)))
    piv = summ.pivot(index="condition_id", columns="label", values="dv_pct")
    piv = piv.loc[list(a["condition_id"]), [c for c in piv.columns if c != "none"]]
    lines = ["# Effect signatures of the twin", "",
             "The twin at the calibrated parameters %s, every DEM catalog effect at the top of "
             "its diagnose range, %d seeds per condition (the same seeds as the anchor without "
             "effects). Regenerate with `make signatures` (`analysis/twin_model/`); used by "
             "`analysis.twin_model.TwinModel` (diagnose's model), the hidden-effect suite and "
             "`make hidden-demo`." % (meta["theta_ref"], meta["replicates"]), "",
             "Replicate scatter of one run's v_mean at the anchor: %.2f %% (pooled over the "
             "conditions); a difference of two %d-seed means has a standard error of %.2f %%."
             % (rel, meta["replicates"], rel * math.sqrt(2.0 / meta["replicates"])), "",
             "Change of v_mean [%] against the anchor:", "",
             "| condition | " + " | ".join("%s (%s = %g)" % (
                 c, cands[c]["param"], Candidate(**dict(cands[c], fixed=())).param_value(
                     cands[c]["s_max"])) for c in piv.columns) + " |",
             "|---|" + "---|" * len(piv.columns)]
    for cid, r in piv.iterrows():
        lines.append("| %s | " % cid + " | ".join("%+.2f" % v for v in r) + " |")
    df = summ.pivot(index="condition_id", columns="label", values="df_col_hz")
    lines += ["", "Change of f_col [1/s] (a 0.5 s record counts in steps of 2 /s):", "",
              "| condition | " + " | ".join(piv.columns) + " |", "|---|" + "---|" * len(piv.columns)]
    for cid in piv.index:
        lines.append("| %s | " % cid + " | ".join("%+.1f" % df.loc[cid, c] for c in piv.columns)
                     + " |")
    if all(k in summ.columns and summ[k].notna().any() for k in FLIGHT_OBSERVABLES):
        a = summ[summ["label"] == "none"].set_index("condition_id")
        lines += ["", "Impact observables of the jar tracks (`analysis.flights`), mean over the "
                  "conditions: the anchor, and each effect's change at the top of its range "
                  "in units of one run's scatter (pooled over labels) - what a jar track "
                  "adds to v_mean and f_col:", "",
                  "| | " + " | ".join(FLIGHT_OBSERVABLES) + " |",
                  "|---|" + "---|" * len(FLIGHT_OBSERVABLES),
                  "| anchor | " + " | ".join("%.4g" % a[k].mean() for k in FLIGHT_OBSERVABLES)
                  + " |"]
        pooled = {k: float(np.sqrt(np.nanmean(summ[k + "_sd"] ** 2))) for k in
                  FLIGHT_OBSERVABLES}
        for lab in piv.columns:
            d = summ[summ["label"] == lab].set_index("condition_id").loc[a.index]
            cells = []
            for k in FLIGHT_OBSERVABLES:
                dz = (d[k] - a[k]) / pooled[k] if pooled[k] > 0 else (d[k] - a[k]) * np.nan
                cells.append("%+.1f" % float(dz.mean()))
            lines.append("| %s | " % lab + " | ".join(cells) + " |")
    if "n_late_pattern" in full.columns:
        late = full[full["n_late_pattern"] > 0]
        if len(late):
            lines += ["", "Levels where runs hit the wall in the 'late' pattern (approach speed "
                      "< %.0f %% of the anchor's: a second steady flight; **mixed** = the seeds "
                      "differ, so the level's mean averages two motions):" % (
                          100 * late_v_in_frac), "",
                      "| effect | strength | condition | late / runs | v_mean [m/s] |",
                      "|---|---|---|---|---|"]
            for r in late.itertuples():
                lines.append("| %s | %.4g | %s | %d / %d%s | %.3f |" % (
                    r.label, r.strength, r.condition_id, r.n_late_pattern, r.n,
                    " (**mixed**)" if r.n_late_pattern < r.n else "", r.v_mean_m_s))
    lines += ["", "![signatures](signatures.png)", ""]
    return "\n".join(lines)


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
             "every run: %s. %d parameter sets, %d twin runs (%d failed); the posterior of a "
             "GP emulator of the twin sampled with emcee; then the real twin at the posterior "
             "mean. Regenerate this page: `python -m analysis.studies.apparatus_identification "
             "--cal %s`." % (cal_dir.name, ", ".join("%s %s" % kv for kv in base.items()) or
                             "-", summary["n_parameter_sets"], summary["n_runs"],
                             summary["n_failed_runs"], cal_dir), "",
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


def paper_diagnosis_page(diag, added, table, summary, name) -> str:
    """``README.md`` of :mod:`analysis.studies.paper_diagnosis`: the verdict on Table 3, the
    effect added (``added``, named ``name``), the Table-3-style ``table`` (index condition_id)
    and the mean |v error| lines of ``summary``."""
    lines = ["# Which effect is missing on the paper's Table 3?", "",
             "The issue-6 loop on the real measurements (v_mean sd 1.5 %, f_col sd 1 /s "
             "assumed; Table 3 gives none). Model: `analysis.twin_model` (anchor at the "
             "calibrated parameters, restitution and amplitude refitted). Regenerate: "
             "`python -m analysis.studies.paper_diagnosis`.", "",
             "**Verdict:** " + diag.verdict, "", "![ranking](diagnose/ranking.png)", ""]
    if added is not None:
        lines += ["**Added:** " + added.summary(), ""]
    cols = [c for c in table.columns if "sd" not in c]
    lines += ["| condition | " + " | ".join(cols) + " |", "|---|" + "---|" * len(cols)]
    for cid, r in table.iterrows():
        lines.append("| %s | " % cid + " | ".join("%.3f" % r[c] if "err" not in c
                                                  else "%+.2f" % r[c] for c in cols) + " |")
    lines += ["", "mean |v error|: calibrated twin %.2f %% (max %.2f %%)"
              % (summary["mean_abs_v_err_calibrated_pct"],
                 summary["max_abs_v_err_calibrated_pct"])]
    if "mean_abs_v_err_with_effect_pct" in summary:
        lines[-1] += ("; twin rerun with %s: %.2f %% (max %.2f %%)"
                      % (name, summary["mean_abs_v_err_with_effect_pct"],
                         summary["max_abs_v_err_with_effect_pct"]))
    lines.append("")
    return "\n".join(lines)


