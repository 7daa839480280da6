"""Where a twin run's time goes: YADE's engine timers over whole runs of the real scene.

    python -m analysis.bench.profile [--out results/bench/scene_profile.csv]

Runs ``yade_scripts/profile_scene.py`` (the scene of mill.py with ``O.timingEnabled``) for two
cases - the paper's dt = 5e-7 s with the 'free' protocol (0.1 s, the ball mostly in flight)
and a whole default mill run (ramp, settle, 0.5 s record at the default dt) - in the lab and
the jar frame (run config ``frame``), and prints, per
engine, its share of the step time in flight and in contact (the contact monitor's in-contact
sampling) and its microseconds per step. The Python monitors are the PyRunners 'sampler' (the
trajectory) and 'contacts' (the contact monitor, the protocol and the steady-state test);
'profile_probe' is the profiler's own. Writes the table as CSV (one row per case, state and
engine). Runs go to a temporary folder; nothing is cached. ``--out`` follows the project's
file rule before any run (:func:`analysis.atomic_dir.check_out_file`: never a file this command
did not write, nothing in the repository outside ``results/``) and is written atomically.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import pandas as pd

from analysis.config import REPO_ROOT, RESULTS_DIR, YADE_SCRIPTS_DIR, twin_config
from analysis.twin import yade_executable

OUT = RESULTS_DIR / "bench" / "scene_profile.csv"
#: the columns of the table this command writes (how it recognises its own earlier file)
COLUMNS = ("case", "state", "steps", "engine", "share", "us_per_step", "calls")
_FREE = {"protocol": "free", "dt_s": 5e-7, "frequency_hz": 25.0, "ball_start": "random",
         "record_s": 0.1, "seed": 3}
_MILL = {"frequency_hz": 25.0, "record_s": 0.5, "seed": 3}
CASES = {
    "lab frame, free dt 5e-7 s, 0.1 s": dict(_FREE, frame="lab"),
    "jar frame, free dt 5e-7 s, 0.1 s": dict(_FREE, frame="jar"),
    "lab frame, mill default dt, whole run": dict(_MILL, frame="lab"),
    "jar frame, mill default dt, whole run": dict(_MILL, frame="jar"),
}


def profile_case(cfg: dict, tmp: Path) -> dict:
    full = twin_config.complete_config(dict(cfg))
    p_cfg, p_out = tmp / "run.json", tmp / "profile.json"
    p_cfg.write_text(json.dumps(full))
    cmd = [yade_executable(), "-n", "-x", str(YADE_SCRIPTS_DIR / "profile_scene.py"),
           "--config", str(p_cfg), "--out", str(p_out)]
    proc = subprocess.run(cmd, cwd=str(REPO_ROOT), capture_output=True, text=True,
                          env=dict(os.environ, OMP_NUM_THREADS="1"), stdin=subprocess.DEVNULL)
    if proc.returncode != 0 or not p_out.is_file():
        raise RuntimeError("profile_scene.py failed (exit %d): %s"
                           % (proc.returncode, (proc.stderr or proc.stdout)[-400:]))
    return json.loads(p_out.read_text())


def table(case: str, prof: dict) -> pd.DataFrame:
    rows = []
    for state, engines in prof["engines"].items():
        steps = prof["state_steps"][state]
        tot = sum(v["ns"] for v in engines.values())
        for name, v in engines.items():
            rows.append({"case": case, "state": state, "steps": steps, "engine": name,
                         "share": v["ns"] / tot if tot else float("nan"),
                         "us_per_step": v["ns"] / 1e3 / steps if steps else float("nan"),
                         "calls": v["calls"]})
    return pd.DataFrame(rows, columns=list(COLUMNS))


def check_out(out):
    """The file rule for ``--out`` (raises :class:`analysis.atomic_dir.OutputError`)."""
    from analysis.atomic_dir import check_out_file, own_csv
    return check_out_file(out, is_own=own_csv(COLUMNS), flag="--out")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 epilog="example: python -m analysis.bench.profile --out "
                                 "results/bench/scene_profile.csv")
    ap.add_argument("--out", default=str(OUT), help="CSV of the table")
    a = ap.parse_args(argv)
    from analysis.atomic_dir import OutputError, atomic_file
    try:
        check_out(a.out)
    except OutputError as exc:
        print("analysis.bench.profile: error: %s" % exc, file=sys.stderr)
        return 2
    parts = []
    with tempfile.TemporaryDirectory(prefix="bench-profile-") as tmp:
        for case, cfg in CASES.items():
            prof = profile_case(cfg, Path(tmp))
            t = table(case, prof)
            parts.append(t)
            print("== %s: %d steps in %.1f s (%.0f steps/s, timers on; %d facets; flight %d "
                  "steps, contact %d steps; the probe's own %.2f s)"
                  % (case, prof["steps"], prof["wall_s"], prof["steps"] / prof["wall_s"],
                     prof["n_facets"], prof["state_steps"]["flight"],
                     prof["state_steps"]["contact"], prof["probe_s"]))
            piv = t.pivot_table(index="engine", columns="state",
                                values=["share", "us_per_step"], sort=False)
            print(piv.to_string(float_format=lambda x: "%.3f" % x))
    try:
        out = check_out(a.out)              # again: it may have appeared during the runs
    except OutputError as exc:
        print("analysis.bench.profile: error: %s" % exc, file=sys.stderr)
        return 2
    with atomic_file(out) as tmp_out:
        pd.concat(parts, ignore_index=True).to_csv(tmp_out, index=False)
    print("wrote %s" % a.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
