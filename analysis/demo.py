"""The main job: the twin at the paper's 8 measured conditions, beside Table 3.

Runs the YADE twin (paper contact parameters C_R = 0.11, SF = 0.7, RF = 0.5; in the apparatus
identified from the paper's DEM column when results/apparatus/paper_apparatus.json exists, else
the default jar and amplitude) at the 8 conditions of data/measurements/paper_table3 with
``--replicates`` start positions each, passes every recording through the observation operator (camera at 2134 fps, lab
frame) and writes results/demo/:

- ``comparison.csv``: per condition the measured v_mean and f_col (Table 3), the twin's mean and
  sd over replicates (direct 3-D speed and through the observation operator), the % difference,
  the paper's own DEM speed, and the motion modes seen;
- ``demo.png``: v_mean against frequency for both balls (measured, paper DEM, this twin);
- ``README.md``: the table and the figure, one page.

Then it prints the contract lines (4-seed means)::

    paper parameters vs measured: mean |v error| X %, max Y %
    paper parameters vs paper DEM: mean |v diff| X %, max Y %
    calibrated twin vs measured: mean |v error| X %, max Y %

(the calibrated line: the twin at results/apparatus/measured_apparatus.json's parameters,
``--replicates`` seeds; that profile is committed, and a missing one is an error) and runs the
loop (:mod:`analysis.loop`) twice from the committed run table (data/twin_runs): on Table 3
into results/demo/loop/ and on a blind dataset with a hidden effect at conditions the paper
never ran into results/demo/blind_loop/ (:data:`DEMO_LOOPS`). Where this machine's floating
point lands a fit elsewhere than the machine that made the table did (a flat likelihood: both
frictions at their bounds on Table 3), the focus wave and the reruns about it are new runs:
each loop makes at most ``--loop-budget-runs`` of them (0: the committed runs only) and prints
its plan instead when it needs more.

    python -m analysis.demo [--replicates 4] [--workers 2] [--record-s 0.5] [--no-loop]
                            [--loop-budget-runs 150]

The two loops replay the committed emulator fits (data/twin_runs/emulator_fits/,
:mod:`analysis.fit_cache`); ``python -m analysis.demo --remake-fits`` (make demo-fits) remakes
them from the committed runs after the emulator or :data:`DEMO_LOOPS` change.
"""
import argparse
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

from analysis.config import (DEMO_DIR, MEASURED_APPARATUS_PROFILE, PAPER_APPARATUS_PROFILE,
                             PAPER_TABLE3_DIR, RESULTS_DIR, twin_config)
from analysis.run_configs import condition_configs


def measured_table(dataset_dir=PAPER_TABLE3_DIR):
    """A measurement dataset (Table 3 by default) as one wide table: condition_id,
    frequency_hz, ball_diameter_mm and _m, the summary's columns (the paper's DEM column);
    ``attrs["velocity_frame"]``. DatasetError naming the folder, file, row and column of a bad
    value or a condition without a summary row."""
    from analysis.measurements import load_dataset, summary_wide
    return summary_wide(load_dataset(dataset_dir), source=dataset_dir)


def demo_configs(conditions, replicates, record_s, base=None):
    """Run configs at every condition x seed (:func:`analysis.run_configs.condition_configs`,
    ball in mm, seeds 0 .. replicates - 1); ``base`` (a profile's run-config fragment: the
    apparatus, contact law, contact parameters) and ``record_s`` under the condition keys. The
    stroke is the profile's (or the default): a stated ``amplitude_mm`` is not applied."""
    return condition_configs(conditions, range(replicates),
                             base_config=dict(base or {}, record_s=record_s),
                             stated_stroke=False)


#: the paper's contact parameters (its Table 2)
PAPER_CONTACT = {"restitution": 0.11, "static_friction": 0.7, "rolling_friction": 0.5}


def load_profile(path):
    """A twin-of-the-mill profile's run-config fragment (``config``) and its description, or
    (None, reason) when the file does not exist. The fragment is validated as a run config."""
    import json
    from pathlib import Path
    path = Path(path)
    if not path.exists():
        return None, "%s not found" % path
    prof = json.loads(path.read_text())
    cfg = dict(prof["config"])
    twin_config.complete_config(dict(cfg))     # ConfigError when the profile is not a config
    return cfg, "%s (fitted %s on %s)" % (path.name, ", ".join(prof.get("free", [])),
                                          prof.get("dataset", "?"))


def summarize_runs(conditions, configs, sweep_table):
    """Per-condition replicate statistics of the twin beside the measurements."""
    from analysis.observe import observe_recording
    rows = []
    t = sweep_table.reset_index(drop=True)
    for c in conditions.itertuples():
        sel = [i for i, cfg in enumerate(configs)
               if cfg["frequency_hz"] == c.frequency_hz
               and abs(cfg["ball_diameter_m"] - c.ball_diameter_mm * 1e-3) < 1e-9]
        ok = [i for i in sel if t.loc[i, "status"] in ("done", "cached")]
        v = np.array([t.loc[i, "v_mean_m_s"] for i in ok], float)
        f = np.array([t.loc[i, "f_col_hz"] for i in ok], float)
        v_obs, f_obs, f_se = [], [], []
        for i in ok:
            o = observe_recording(t.loc[i, "run_dir"])
            v_obs.append(o.v_mean_m_s)
            f_obs.append(o.f_col_hz)
            f_se.append(o.f_col_se_hz)
        modes = "/".join(sorted(set(str(t.loc[i, "motion_mode"]) for i in ok)))
        sd = lambda x: float(np.std(x, ddof=1)) if len(x) > 1 else float("nan")  # noqa: E731
        row = {
            "condition_id": c.condition_id, "frequency_hz": c.frequency_hz,
            "ball_diameter_mm": c.ball_diameter_mm,
            "v_mean_measured_m_s": c.v_mean_m_s, "v_mean_dem_paper_m_s": c.v_mean_dem_paper_m_s,
            "v_mean_twin_m_s": float(np.mean(v)) if len(v) else float("nan"),
            "v_mean_twin_sd_m_s": sd(v),
            "v_mean_twin_observed_m_s": float(np.mean(v_obs)) if v_obs else float("nan"),
            "f_col_measured_hz": c.f_col_hz,
            "f_col_twin_hz": float(np.mean(f)) if len(f) else float("nan"),
            "f_col_twin_observed_hz": float(np.mean(f_obs)) if f_obs else float("nan"),
            "f_col_twin_se_hz": (float(np.sqrt(np.sum(np.square(f_se)))) / len(f_se)
                                 if f_se else float("nan")),
            "n_replicates": len(ok), "n_failed": len(sel) - len(ok), "motion_modes": modes,
        }
        row["v_diff_pct"] = 100 * (row["v_mean_twin_observed_m_s"] / c.v_mean_m_s - 1)
        row["f_col_diff_pct"] = 100 * (row["f_col_twin_observed_hz"] / c.f_col_hz - 1)
        rows.append(row)
    return pd.DataFrame(rows)


def write_page(table, out_dir, meta, extra=()):
    """README.md of the demo into ``out_dir`` (text: :func:`analysis.report.demo_page`)."""
    from analysis.report import demo_page
    (out_dir / "README.md").write_text(demo_page(table, meta, extra))


#: the loops the demo shows, from the committed run table (data/twin_runs): (sub-folder, dataset,
#: what it is, extra options of python -m analysis.loop)
DEMO_LOOPS = (
    ("loop", PAPER_TABLE3_DIR, "Table 3, the paper's measurements (v sd 1.5 % assumed: Table 3 "
     "states none)", ()),
    ("blind_loop", RESULTS_DIR / "open_world" / "effects" / "eff_p01", "a blind dataset at six conditions the paper never ran, an arc motion of the "
     "jar hidden (truth in results/open_world/effects/truth)", ("--per-wave", "6",
                                                               "--null-draws", "10")),
)


#: new twin runs each demo loop may make where the committed table lacks them (this machine's
#: fit landed elsewhere): a focus wave and two reruns at Table 3's 8 conditions are 96
DEMO_LOOP_BUDGET_RUNS = 150


def demo_loops(out, workers, budget_runs=DEMO_LOOP_BUDGET_RUNS) -> list:
    """The loop on each of :data:`DEMO_LOOPS` from the cache and the committed run table,
    making at most ``budget_runs`` new twin runs (``--budget-runs``). A loop that needs more is
    not run; the line says what it would cost (``make loop`` runs it)."""
    from analysis import loop
    lines = []
    for sub, ds, words, extra in DEMO_LOOPS:
        args = ["--dataset", str(ds), "--out", str(Path(out) / sub), "--workers", str(workers),
                *extra]
        print("the loop on %s -> %s/%s" % (words, out, sub))
        rc = loop.main(args + ["--budget-runs", str(int(budget_runs))])
        if rc == 3:
            loop.main(args + ["--dry-run"])
            lines.append("the loop on %s: not shown - it needs more than %d new twin runs "
                         "(the plan above; run it with: python -m analysis.loop %s)"
                         % (words, budget_runs, " ".join(args)))
        elif rc != 0:
            lines.append("the loop on %s failed (exit %d)" % (words, rc))
        else:
            lines.append("the loop on %s: %s/%s/report.md" % (words, out, sub))
    return lines


def remake_demo_fits(workers=1, log=print) -> int:
    """Run :data:`DEMO_LOOPS` from the committed run table in an empty runs folder (no new
    twin run: a missing one is a :class:`analysis.twin_runs.BudgetError`); the emulator fits
    they used replace data/twin_runs/emulator_fits/, what a fresh clone's demo replays.
    Returns the number of fits."""
    import shutil
    import tempfile
    from analysis import loop
    from analysis.fit_cache import FOLDER, replace_fits
    tmp = Path(tempfile.mkdtemp(prefix="demo-fits-"))
    try:
        for sub, ds, words, extra in DEMO_LOOPS:
            log("the loop on %s" % words)
            loop.run_committed(["--dataset", str(ds), "--out", str(tmp / "out" / sub),
                                "--workers", str(workers), *extra], tmp / "runs", log=log,
                               committed_fits=False)
        return replace_fits(tmp / "runs" / FOLDER)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def main(argv=None):
    p = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0],
        epilog="example: python -m analysis.demo --replicates 4 --workers 2")
    p.add_argument("--replicates", type=int, default=4,
                   help="twin runs per condition at the paper's parameters [seeds]")
    p.add_argument("--workers", type=int, default=2, help="parallel twin runs [processes]")
    p.add_argument("--record-s", type=float, default=0.5, help="recorded time per run [s]")
    p.add_argument("--out", default=str(DEMO_DIR), help="output folder")
    p.add_argument("--no-loop", action="store_true",
                   help="skip the loop on Table 3 (python -m analysis.loop)")
    p.add_argument("--loop-budget-runs", type=int, default=DEMO_LOOP_BUDGET_RUNS,
                   help="new twin runs each loop may make where the committed run table lacks "
                   "them [runs] (default %(default)s; 0: the committed runs only)")
    p.add_argument("--remake-fits", action="store_true",
                   help="only run the two loops from the committed runs and write the emulator "
                   "fits they use to data/twin_runs/emulator_fits/ (no new twin run)")
    a = p.parse_args(argv)
    if a.remake_fits:
        from analysis.atomic_dir import OutputError
        from analysis.fit_cache import COMMITTED_FITS
        from analysis.twin_runs import BudgetError
        try:
            n = remake_demo_fits(a.workers, log=lambda s: print(s, file=sys.stderr))
        except (BudgetError, OutputError) as exc:
            print("analysis.demo: error: %s" % exc, file=sys.stderr)
            return 2
        print("wrote %d emulator fits to %s" % (n, COMMITTED_FITS))
        return 0
    if a.replicates < 1 or a.workers < 1 or a.record_s <= 0:
        print("analysis.demo: error: replicates, workers and record-s must be positive",
              file=sys.stderr)
        return 2
    if a.loop_budget_runs < 0:
        print("analysis.demo: error: --loop-budget-runs must be >= 0, got %d"
              % a.loop_budget_runs, file=sys.stderr)
        return 2
    from pathlib import Path
    from analysis.atomic_dir import OutputError, check_out_dir, output_dir
    from analysis.plotting.demo_plots import write_demo_figure
    from analysis.sweep import run_sweep
    try:
        check_out_dir(a.out)
    except OutputError as exc:
        print("analysis.demo: error: %s" % exc, file=sys.stderr)
        return 2
    t0 = time.time()
    cond = measured_table()
    try:
        paper_base, paper_src = load_profile(PAPER_APPARATUS_PROFILE)
        cal_base, cal_src = load_profile(MEASURED_APPARATUS_PROFILE)
    except (ValueError, KeyError, OSError) as exc:
        print("analysis.demo: error: a twin-of-the-mill profile is unusable: %s" % exc,
              file=sys.stderr)
        return 2
    if cal_base is None:
        print("analysis.demo: error: the calibrated twin's profile is missing: %s (it is "
              "committed; `make apparatus` makes it)" % cal_src, file=sys.stderr)
        return 2
    if paper_base is not None:
        off = {k: paper_base.get(k) for k, v in PAPER_CONTACT.items() if paper_base.get(k) != v}
        if off:
            print("analysis.demo: error: %s does not hold the paper's contact parameters: %s"
                  % (PAPER_APPARATUS_PROFILE, off), file=sys.stderr)
            return 2
        paper_words = "the apparatus identified from the paper's DEM column, %s" % paper_src
    else:
        paper_words = "the default jar and stroke (%s)" % paper_src
    configs = demo_configs(cond, a.replicates, a.record_s, paper_base)
    cal_configs = demo_configs(cond, a.replicates, a.record_s, cal_base)
    res = run_sweep(configs + cal_configs, workers=a.workers)
    table = summarize_runs(cond, configs, res.table.iloc[:len(configs)])
    dem = 100 * (table["v_mean_twin_observed_m_s"] / table["v_mean_dem_paper_m_s"] - 1)
    table["v_diff_dem_paper_pct"] = dem
    ct = summarize_runs(cond, cal_configs, res.table.iloc[len(configs):].reset_index(drop=True))
    cal = ct[["condition_id", "frequency_hz", "ball_diameter_mm", "v_mean_measured_m_s",
              "v_mean_twin_observed_m_s", "v_mean_twin_sd_m_s", "v_diff_pct",
              "n_replicates", "motion_modes"]]
    cal_line = ("calibrated twin vs measured: mean |v error| %.2f %%, max %.2f %%"
                % (ct["v_diff_pct"].abs().mean(), ct["v_diff_pct"].abs().max()))
    cal_words = ("the twin at the contact and apparatus parameters calibrated on Table 3, "
                 "%s, %d seeds per condition" % (cal_src, a.replicates))
    paper_meas = ("paper parameters vs measured: mean |v error| %.2f %%, max %.2f %%"
                  % (table["v_diff_pct"].abs().mean(), table["v_diff_pct"].abs().max()))
    paper_dem = ("paper parameters vs paper DEM: mean |v diff| %.2f %%, max %.2f %%"
                 % (dem.abs().mean(), dem.abs().max()))
    out = Path(a.out)
    with output_dir(out) as tmp:
        table.to_csv(tmp / "comparison.csv", index=False, float_format="%.4g")
        cal.to_csv(tmp / "calibrated.csv", index=False, float_format="%.4g")
        write_demo_figure(table, tmp / "demo.png")
        dflt = twin_config.default_config()
        amp = (paper_base or {}).get("amplitude_m", dflt["amplitude_m"])
        write_page(table, tmp, {"amplitude_m": amp, "dt_s": dflt["dt_s"],
                                "replicates": a.replicates, "record_s": a.record_s,
                                "wall_s": time.time() - t0, "apparatus": paper_words},
                   extra=[paper_meas, paper_dem, cal_line + " (%s)" % cal_words])
    show = ["condition_id", "v_mean_measured_m_s", "v_mean_twin_observed_m_s",
            "v_mean_twin_sd_m_s", "v_diff_pct", "v_mean_dem_paper_m_s", "f_col_measured_hz",
            "f_col_twin_observed_hz", "motion_modes"]
    print(table[show].to_string(index=False, float_format=lambda x: "%.3f" % x))
    print(paper_meas)
    print(paper_dem)
    print(cal_line)
    if not res.ok:
        print("analysis.demo: %d run(s) failed:\n%s" % (res.n_failed, res.failed()[["run_id", "error"]]
                                                        .to_string(index=False)), file=sys.stderr)
        return 1
    if not a.no_loop:
        for line in demo_loops(out, a.workers, a.loop_budget_runs):
            print(line)
    print("wrote %s (%.0f s)" % (out, time.time() - t0))
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except KeyboardInterrupt as exc:          # SIGINT / SIGTERM: one line, 130 / 143
        from analysis.sweep import interrupted_exit
        sys.exit(interrupted_exit("analysis.demo", exc))
