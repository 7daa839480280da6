"""Run the YADE twin as a subprocess and read its recordings.

``analysis/`` never imports yade: :func:`run_twin` writes the config to a JSON file and starts
``yade -n -x yade_scripts/mill.py --config cfg.json --out results/runs/<run-id>``. The run id is a
hash of the complete config and of the STL's bytes, so a config that was run before is read from
its folder instead of being recomputed (a folder counts as complete when it has meta.json; the
scene writes into a temporary folder and renames it when done, so a killed run leaves nothing that
looks complete).

Environment: ``YADE`` names the yade executable (default ``yade`` on PATH).

Usage::

    python -m analysis.twin --frequency-hz 25 --ball-diameter-mm 20.6 [--set key=value ...]
"""
import argparse
import functools
import json
import os
import shutil
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from analysis.config import MILL_SCRIPT, REPO_ROOT, RUNS_DIR, twin_config

#: the recording's columns (declared in yade_scripts/twin_config.py, which the scene imports)
TRAJECTORY_COLUMNS = list(twin_config.TRAJECTORY_COLUMNS)
IMPACT_COLUMNS = list(twin_config.IMPACT_COLUMNS)


class TwinRunError(RuntimeError):
    """YADE failed: bad config (exit 2), the run failed (exit 3), or YADE itself crashed."""


class TwinRunKilled(TwinRunError):
    """YADE was ended by a signal from outside (a kill, the machine's OOM killer): not the
    run's own failure, so no sweep records it as failed for good (``transient``)."""

    transient = True


@dataclass
class Recording:
    """One twin run read from disk.

    Attributes
    ----------
    path : Path - the run folder
    meta : dict - meta.json (config, versions, timings, steady state, summary)
    trajectory : DataFrame - TRAJECTORY_COLUMNS, one row per output frame (lab frame)
    impacts : DataFrame - IMPACT_COLUMNS, one row per ball-wall contact event
    """
    path: Path
    meta: dict
    trajectory: pd.DataFrame
    impacts: pd.DataFrame

    @property
    def config(self):
        return self.meta["config"]

    @property
    def summary(self):
        return self.meta["summary"]


def yade_executable():
    exe = os.environ.get("YADE", "yade")
    if shutil.which(exe) is None:
        raise TwinRunError("YADE executable %r not found: install Debian's package "
                           "(sudo apt-get install -y yade) or set YADE=/path/to/yade "
                           "(`make setup` does this)" % exe)
    return exe


def run_dir_for(config, runs_dir=None):
    """Folder a config's recording lives in (complete or not)."""
    return Path(runs_dir or RUNS_DIR) / twin_config.run_id(config, str(REPO_ROOT))


def is_complete(run_dir):
    return (Path(run_dir) / "meta.json").is_file()


@functools.lru_cache(maxsize=8)
def _jar_info(path, units, mtime_ns, size):
    """Measured jar of one STL file version (cached by path, units, mtime and size)."""
    from geometry.stl_io import measure_jar

    return measure_jar(path, units)[1]


@functools.lru_cache(maxsize=32)
def _parametric_jar_info(dims):
    """Measured parametric jar of the dimensions ``dims`` (sorted (key, value) pairs)."""
    from geometry.jar import mesh_for_config

    try:
        return mesh_for_config(dict(dims), None)[1]
    except ValueError as exc:
        raise twin_config.ConfigError("parametric jar: %s" % exc)


def check_ball_fits_jar(cfg):
    """Check, without YADE, that the config's ball can move in the config's jar.

    Reads the jar STL named by ``cfg['stl_path']`` (relative to the repository root) and applies
    the scene's own rule (:func:`geometry.stl_io.ball_fit_error`, the one yade_scripts/mill.py
    enforces), so an impossible ball is refused before a YADE process starts.

    Parameters
    ----------
    cfg : dict - a complete run config (:func:`twin_config.complete_config`)

    Raises
    ------
    twin_config.ConfigError - the STL cannot be read or measured, or the ball does not fit
    """
    from geometry.stl_io import MeshError, ball_fit_error

    from effects import jar_config
    cfg = jar_config(cfg)          # effects that change the jar (ConfigError when they cannot)
    if twin_config.parametric_jar(cfg) is not None:
        info = _parametric_jar_info(tuple(sorted(twin_config.parametric_jar(cfg).items())))
        problem = ball_fit_error(cfg["ball_diameter_m"], info)
        if problem:
            raise twin_config.ConfigError("ball_diameter_m = %g m does not fit the parametric "
                                          "jar: %s" % (cfg["ball_diameter_m"], problem))
        return
    path = twin_config.resolve_stl(cfg, str(REPO_ROOT))
    try:
        st = os.stat(path)
        info = _jar_info(path, cfg["stl_units"], st.st_mtime_ns, st.st_size)
    except OSError as exc:
        raise twin_config.ConfigError("stl_path %r: cannot read the jar mesh (%s)"
                                      % (cfg["stl_path"], exc.strerror or exc))
    except MeshError as exc:
        raise twin_config.ConfigError("stl_path %r: %s" % (cfg["stl_path"], exc))
    problem = ball_fit_error(cfg["ball_diameter_m"], info)
    if problem:
        raise twin_config.ConfigError("ball_diameter_m = %g m does not fit the jar %s: %s"
                                      % (cfg["ball_diameter_m"], cfg["stl_path"], problem))


def run_twin(config, runs_dir=None, force=False, timeout_s=None):
    """Run the twin for one config (cached by run id) and return its run folder.

    Parameters
    ----------
    config : dict - run config (keys of twin_config.PARAMETERS; missing keys take defaults)
    runs_dir : path, optional - where run folders live (default results/runs)
    force : bool - rerun even when a complete recording exists
    timeout_s : float, optional - kill YADE after this many seconds

    Returns
    -------
    Path - results/runs/<run-id>

    Raises
    ------
    twin_config.ConfigError - the config is invalid or its ball does not fit its jar (both
        checked before YADE starts)
    TwinRunError - YADE exited non-zero; the message holds its error line
    """
    cfg = twin_config.complete_config(dict(config))
    out = run_dir_for(cfg, runs_dir)
    if is_complete(out) and not force:
        return out
    check_ball_fits_jar(cfg)
    out.parent.mkdir(parents=True, exist_ok=True)
    exe = yade_executable()
    with tempfile.TemporaryDirectory(prefix="twin-cfg-") as tmp:
        cfg_path = Path(tmp) / "run.json"
        cfg_path.write_text(json.dumps(cfg, indent=1, sort_keys=True))
        cmd = [exe, "-n", "-x", str(MILL_SCRIPT), "--config", str(cfg_path), "--out", str(out)]
        env = dict(os.environ, OMP_NUM_THREADS="1")
        try:
            proc = subprocess.run(cmd, cwd=str(REPO_ROOT), capture_output=True, text=True,
                                  timeout=timeout_s, env=env, stdin=subprocess.DEVNULL)
        except subprocess.TimeoutExpired:
            raise TwinRunError("YADE run %s timed out after %s s" % (out.name, timeout_s))
    if proc.returncode != 0 or not is_complete(out):
        lines = [ln for ln in (proc.stderr + proc.stdout).splitlines()
                 if "mill.py:" in ln or "Error" in ln or "error" in ln]
        msg = lines[-1] if lines else (proc.stderr.strip().splitlines() or ["(no output)"])[-1]
        err = TwinRunKilled if proc.returncode < 0 else TwinRunError
        raise err("twin run %s failed (exit %d): %s" % (out.name, proc.returncode, msg))
    return out


def load_recording(run_dir):
    """Read a run folder written by yade_scripts/mill.py.

    Raises
    ------
    FileNotFoundError - the folder is not a complete recording
    ValueError - a file lacks a contract column
    """
    run_dir = Path(run_dir)
    if not is_complete(run_dir):
        raise FileNotFoundError("%s is not a complete twin recording (no meta.json)" % run_dir)
    meta = json.loads((run_dir / "meta.json").read_text())
    traj = pd.read_csv(run_dir / "trajectory.csv")
    imp = pd.read_csv(run_dir / "impacts.csv")
    for name, df, cols in (("trajectory.csv", traj, TRAJECTORY_COLUMNS),
                           ("impacts.csv", imp, IMPACT_COLUMNS)):
        missing = [c for c in cols if c not in df.columns]
        if missing:
            raise ValueError("%s: %s lacks column(s) %s" % (run_dir, name, ", ".join(missing)))
    return Recording(run_dir, meta, traj, imp)


def condition_config(frequency_hz, ball_diameter_m, **overrides):
    """Config of one operating condition (defaults elsewhere)."""
    cfg = {"frequency_hz": float(frequency_hz), "ball_diameter_m": float(ball_diameter_m)}
    cfg.update(overrides)
    return cfg


def _parse_set(items):
    out = {}
    for item in items or []:
        if "=" not in item:
            raise twin_config.ConfigError("--set takes key=value, got %r" % item)
        k, v = item.split("=", 1)
        try:
            out[k] = json.loads(v)
        except ValueError:
            out[k] = v
    return out


def main(argv=None):
    p = argparse.ArgumentParser(
        prog="python -m analysis.twin",
        description="Run the MM400 twin once (cached by run id).",
        epilog="example: python -m analysis.twin --frequency-hz 30 --ball-diameter-mm 17.5 "
        "--set restitution=0.35 amplitude_m=0.0127")
    p.add_argument("--frequency-hz", type=float, default=25.0, help="jar frequency [Hz]")
    p.add_argument("--ball-diameter-mm", type=float, default=20.6, help="ball diameter [mm]")
    p.add_argument("--set", nargs="*", action="extend", metavar="KEY=VALUE",
                   help="other run-config keys (yade_scripts/twin_config.py, SI units as in "
                   "their names); frequency_hz and ball_diameter_m here override the options "
                   "above. Every value is checked against the bounds declared there, and the "
                   "ball against the jar mesh, before YADE starts")
    p.add_argument("--force", action="store_true", help="rerun even if cached")
    a = p.parse_args(argv)
    try:
        extra = _parse_set(a.set)
        f = extra.pop("frequency_hz", a.frequency_hz)
        d = extra.pop("ball_diameter_m", a.ball_diameter_mm * 1e-3)
        cfg = condition_config(f, d, **extra)
        check_ball_fits_jar(twin_config.complete_config(dict(cfg)))
        run = run_twin(cfg, force=a.force)
        rec = load_recording(run)
    except (twin_config.ConfigError, TwinRunError, TypeError, ValueError) as exc:
        print("analysis.twin: error: %s" % exc, file=sys.stderr)
        return 2
    s = rec.summary
    print("%s: v_mean %.3f m/s, f_col %.1f /s, mode %s" % (run, s["v_mean_m_s"], s["f_col_hz"],
                                                         s["motion_mode"]))
    steady = rec.meta.get("steady", {})
    if isinstance(steady, dict) and steady.get("steady") is False:
        print("analysis.twin: warning: the run never reached a steady state (meta.json "
              "steady: false); it recorded anyway after settle_max_s", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
