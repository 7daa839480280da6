"""Sweep: caching by run id, resume after a kill, failures kept, yade-batch tables."""
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest

from analysis import sweep
from analysis.config import REPO_ROOT, twin_config
from analysis.fake_twin import run_fake_twin

RUNNER = "analysis.fake_twin:run_fake_twin"


def _configs(n, **extra):
    return [{"restitution": 0.1 + 0.05 * i, "seed": i, **extra} for i in range(n)]


def _exec_counts(log_dir):
    counts = {}
    for p in Path(log_dir).glob("*.*"):
        rid = p.name.split(".")[0]
        counts[rid] = counts.get(rid, 0) + 1
    return counts


def _write_csv(path, configs):
    pd.DataFrame(configs).to_csv(path, index=False)
    return path


def test_cached_runs_are_not_recomputed(tmp_path):
    log = tmp_path / "exec"
    cfgs = _configs(4)
    kw = {"exec_log": str(log)}
    r1 = sweep.run_sweep(cfgs, runner=RUNNER, runner_kwargs=kw, workers=2,
                         runs_dir=tmp_path / "runs", progress=False)
    assert list(r1.table["status"]) == ["done"] * 4
    assert r1.n_executed == 4
    r2 = sweep.run_sweep(cfgs, runner=RUNNER, runner_kwargs=kw, workers=2,
                         runs_dir=tmp_path / "runs", progress=False)
    assert list(r2.table["status"]) == ["cached"] * 4
    assert r2.n_executed == 0
    assert all(c == 1 for c in _exec_counts(log).values())
    # summaries come from meta.json and match between the two sweeps
    pd.testing.assert_series_equal(r1.table["v_mean_m_s"], r2.table["v_mean_m_s"])
    assert r1.table["run_id"].tolist() == [twin_config.run_id(c) for c in cfgs]


def test_duplicate_configs_run_once(tmp_path):
    log = tmp_path / "exec"
    cfgs = _configs(2) + _configs(2)
    res = sweep.run_sweep(cfgs, runner=RUNNER, runner_kwargs={"exec_log": str(log)},
                          backend="serial", runs_dir=tmp_path / "runs", progress=False)
    assert len(res.table) == 4 and res.table["run_id"].nunique() == 2
    assert sum(_exec_counts(log).values()) == 2


def _complete(runs):
    """Names of complete run folders (a run killed before its rename leaves a '.tmp-*' folder,
    which is not a finished run)."""
    return {p.parent.name for p in runs.glob("*/meta.json") if not p.parent.name.startswith(".")}


def test_killed_sweep_resumes_without_recomputing(tmp_path):
    log, runs = tmp_path / "exec", tmp_path / "runs"
    cfgs = _configs(10)
    table = _write_csv(tmp_path / "params.csv", cfgs)
    cmd = [sys.executable, "-m", "analysis.sweep", "--table", str(table), "--runner", RUNNER,
           "--runner-kw", "delay_s=0.4", "--runner-kw", "exec_log=%s" % log,
           "--workers", "2", "--runs-dir", str(runs), "--no-progress"]
    proc = subprocess.Popen(cmd, cwd=REPO_ROOT, start_new_session=True,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    t_end = time.time() + 60
    while time.time() < t_end and len(_complete(runs)) < 3:
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    finished = _complete(runs)
    assert 3 <= len(finished) < 10, "the sweep must be killed mid-way"
    before = _exec_counts(log)
    res = sweep.run_sweep(cfgs, runner=RUNNER, workers=2, runs_dir=runs, progress=False,
                          runner_kwargs={"exec_log": str(log)})
    after = _exec_counts(log)
    assert res.ok and len(_complete(runs)) == 10
    for rid in finished:                        # finished runs were never re-executed
        assert after[rid] == before[rid] == 1
    assert res.n_executed == 10 - len(finished)
    st = res.table.set_index("run_id")["status"]
    assert (st[list(finished)] == "cached").all()


def test_failed_run_is_reported_and_not_retried_unless_asked(tmp_path):
    runs = tmp_path / "runs"
    cfgs = _configs(3) + [{"restitution": 0.9, "seed": 7}]
    kw = {"fail_above_restitution": 0.8}
    res = sweep.run_sweep(cfgs, runner=RUNNER, runner_kwargs=kw, backend="local",
                          workers=2, runs_dir=runs, progress=False)
    bad = res.failed()
    assert len(bad) == 1 and not res.ok
    assert "RuntimeError" in bad["error"].iloc[0] and "restitution 0.9" in bad["error"].iloc[0]
    rid = bad["run_id"].iloc[0]
    rec = json.loads((runs / ("%s.failed.json" % rid)).read_text())
    assert rec["config"]["restitution"] == 0.9 and "Traceback" in rec["traceback"]
    assert res.table["v_mean_m_s"].notna().sum() == 3
    again = sweep.run_sweep(cfgs, runner=RUNNER, runner_kwargs=kw, backend="serial",
                            runs_dir=runs, progress=False)
    assert again.n_executed == 0
    assert again.table.set_index("run_id").loc[rid, "status"] == "failed_cached"
    fixed = sweep.run_sweep(cfgs, runner=RUNNER, backend="serial", runs_dir=runs,
                            progress=False, retry_failed=True)
    assert fixed.ok and fixed.n_executed == 1
    assert not (runs / ("%s.failed.json" % rid)).exists()


def test_cli_reports_failure_and_exit_codes(tmp_path):
    table = _write_csv(tmp_path / "p.csv", [{"restitution": 0.9}])
    rc = sweep.main(["--table", str(table), "--runner", RUNNER, "--runner-kw",
                     "fail_above_restitution=0.5", "--runs-dir", str(tmp_path / "r"),
                     "--backend", "serial", "--no-progress"])
    assert rc == 1
    bad = tmp_path / "bad.csv"
    bad.write_text("restitution,frequency_hz\n0.2,-5\n")
    assert sweep.main(["--table", str(bad), "--runs-dir", str(tmp_path / "r")]) == 2


def test_bad_table_names_line_and_key(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("restitution,bogus_key\n0.2,1\n")
    with pytest.raises(sweep.SweepInputError, match=r"line 2.*bogus_key"):
        sweep.read_param_table(bad)
    bad.write_text("restitution seed\n0.2 1\n0.3\n")
    with pytest.raises(sweep.SweepInputError, match="line 3"):
        sweep.read_param_table(bad)
    with pytest.raises(sweep.SweepInputError):
        sweep.run_sweep([{"restitution": 2.0}], runner=RUNNER, runs_dir=tmp_path)


def test_yade_batch_table_round_trip(tmp_path):
    cfgs = [{"restitution": 0.25, "static_friction": 0.4, "seed": 3, "ball_start": "center"},
            {"restitution": 0.5, "ball_diameter_m": 0.0175, "seed": 4}]
    path = sweep.write_yade_batch_table(cfgs, tmp_path / "runs.table")
    lines = [l for l in path.read_text().splitlines() if not l.startswith("#")]
    header = lines[0].split()
    assert header[0] == "description"
    assert set(header[1:]) == {"restitution", "static_friction", "seed", "ball_start",
                               "ball_diameter_m"}
    assert all(len(l.split()) == len(header) for l in lines[1:])
    back = sweep.read_param_table(path)
    assert [twin_config.run_id(c) for c in back] == [twin_config.run_id(c) for c in cfgs]
    assert [l.split()[0] for l in lines[1:]] == [twin_config.run_id(c) for c in cfgs]


def test_dask_backend_local_cluster(tmp_path):
    pytest.importorskip("dask.distributed")
    cfgs = _configs(3) + [{"restitution": 0.9}]
    res = sweep.run_sweep(cfgs, runner=RUNNER, runner_kwargs={"fail_above_restitution": 0.8},
                          backend="dask", workers=2, runs_dir=tmp_path, progress=False)
    assert list(res.table["status"]) == ["done"] * 3 + ["failed"]


def test_direct_runner_callable(tmp_path):
    res = sweep.run_sweep(_configs(2), runner=run_fake_twin, backend="serial",
                          runs_dir=tmp_path, progress=False)
    assert res.ok and (res.table["v_mean_m_s"] > 0).all()


def test_slurm_job_script_from_sweep_config(tmp_path):
    pytest.importorskip("dask_jobqueue")
    from dask_jobqueue import SLURMCluster
    cfg = tmp_path / "sweep.yaml"
    cfg.write_text("table: p.csv\nbackend: dask\nslurm: {cores: 4, memory: 8GB, "
                   "walltime: '02:00:00', jobs: 3, queue: compute, "
                   "prologue: ['cd /home/me/mill', 'source .venv/bin/activate']}\n")
    opts = sweep.read_sweep_config(cfg)
    kw, jobs = sweep.slurm_cluster_kwargs(opts["slurm"])
    assert jobs == 3
    with SLURMCluster(**kw, scheduler_options={"dashboard_address": None}) as cluster:
        script = cluster.job_script()
    assert "#SBATCH -t 02:00:00" in script and "#SBATCH -p compute" in script
    assert "cd /home/me/mill" in script and "--nworkers 4" in script


def test_sweep_config_file_selects_backend_and_base(tmp_path):
    cfg = tmp_path / "sweep.json"
    cfg.write_text(json.dumps({
        "configs": [{"seed": 1}, {"seed": 2}], "backend": "serial",
        "runner": RUNNER, "runner_kwargs": {"exec_log": str(tmp_path / "exec")},
        "runs_dir": str(tmp_path / "runs"), "base": {"restitution": 0.3},
        "out": str(tmp_path / "out.csv")}))
    assert sweep.main(["--sweep-config", str(cfg), "--no-progress"]) == 0
    out = pd.read_csv(tmp_path / "out.csv")
    assert (out["restitution"] == 0.3).all() and (out["status"] == "done").all()
    assert sum(_exec_counts(tmp_path / "exec").values()) == 2
    cfg.write_text(json.dumps({"configs": [{"seed": 1}], "bogus": 1}))
    assert sweep.main(["--sweep-config", str(cfg)]) == 2


def test_dead_worker_is_reported_and_retried_next_time(tmp_path):
    runs = tmp_path / "runs"
    cfgs = _configs(3) + [{"restitution": 0.95, "seed": 9}]
    res = sweep.run_sweep(cfgs, runner=RUNNER, workers=2, runs_dir=runs, progress=False,
                          runner_kwargs={"crash_above_restitution": 0.9, "delay_s": 0.2})
    row = res.table.set_index("run_id").loc[twin_config.run_id(cfgs[-1])]
    assert row["status"] == "failed" and "worker process died" in row["error"]
    assert not list(runs.glob("*.failed.json"))      # cause unknown: not recorded as failed
    again = sweep.run_sweep(cfgs, runner=RUNNER, workers=2, runs_dir=runs, progress=False)
    assert again.ok and len(list(runs.glob("*/meta.json"))) == 4


def test_cached_wall_s_is_the_median_of_the_latest_runs_in_the_frame(tmp_path):
    import json
    import os
    from analysis.sweep import CACHED_WALL_MIN, cached_wall_s
    assert cached_wall_s("lab", tmp_path) is None
    for i in range(12):
        d = tmp_path / ("run%02d" % i)
        d.mkdir()
        frame = "jar" if i % 2 else "lab"
        fake = i == 10
        (d / "meta.json").write_text(json.dumps(
            {"frame": frame, "wall_s": 500.0 if fake else 10.0 + i,
             "yade_version": "FAKE (analysis.fake_twin)" if fake else "2023.02a"}))
        os.utime(d / "meta.json", (1e9 + i, 1e9 + i))
    # lab runs 0, 2, 4, 6, 8 (10 is FAKE): median 14; jar runs 1, 3, 5, 7, 9, 11: median 16
    assert cached_wall_s("lab", tmp_path) == 14.0
    assert cached_wall_s("jar", tmp_path) == 16.0
    assert CACHED_WALL_MIN == 5
    (tmp_path / "run00" / "meta.json").unlink()
    assert cached_wall_s("lab", tmp_path) is None          # 4 lab runs: too few


def test_a_run_killed_from_outside_is_not_recorded_as_failed(tmp_path, monkeypatch):
    """YADE ended by a signal (a kill, the OOM killer: exit -15, -9) is TwinRunKilled, a
    transient error: the sweep reports it failed now but writes no .failed.json, so the next
    sweep runs it again (a config that YADE refuses, exit 2, stays recorded)."""
    from analysis import twin

    def fake_yade(returncode):
        def run(cmd, **kw):
            return subprocess.CompletedProcess(cmd, returncode, "", "Terminated")
        return run
    cfg = {"frequency_hz": 25.0, "seed": 3}
    for code, kind, recorded in ((-15, twin.TwinRunKilled, False), (-9, twin.TwinRunKilled,
                                                                      False),
                                 (2, twin.TwinRunError, True)):
        runs = tmp_path / ("runs%d" % code)
        monkeypatch.setattr(twin.subprocess, "run", fake_yade(code))
        monkeypatch.setattr(twin, "yade_executable", lambda: "yade")
        with pytest.raises(kind):
            twin.run_twin(cfg, runs_dir=runs)
        rec = sweep.execute_run(twin.run_twin, cfg, runs, "r1")
        assert rec["status"] == "failed" and "exit %d" % code in rec["error"]
        assert (runs / "r1.failed.json").exists() == recorded, code
