"""Stopping a sweep with SIGINT / SIGTERM: queued runs never start, running runs end with their
child processes, no process outlives the sweep, finished runs stay cached and valid, nothing
half-done looks finished or failed, the partial table is written, one line tells how to resume,
and the rerun recomputes nothing that had finished."""
import json
import os
import signal
import subprocess
import sys
import threading
import time
import uuid
from pathlib import Path

import pandas as pd
import pytest

from analysis import sweep
from analysis.config import REPO_ROOT, twin_config
from analysis.fake_twin import run_fake_twin

RUNNER = "tests.test_sweep_interrupt:child_process_runner"
N_RUNS = 8
RUN_S = 0.6
#: length of the runs started after the first two while a test holds its ``hold`` file [s]:
#: far longer than the stop grace, so a run the sweep fails to stop outlives it
SLOW_S = 30.0


def child_process_runner(config, runs_dir=None, force=False, delay_s=RUN_S, marker="",
                         start_log=None, hold=None):
    """Runner for these tests: like the twin it runs each config in a child process (a Python
    sleeping ``delay_s`` whose command line carries ``marker``), then writes the run folder
    through the fake twin. Each start leaves a file ``<run-id>.<uuid>`` in ``start_log``; while
    the file ``hold`` exists, every run after the first two started sleeps ``SLOW_S``."""
    cfg = twin_config.complete_config(dict(config))
    rid = twin_config.run_id(cfg)
    if runs_dir is not None and (Path(runs_dir) / rid / "meta.json").exists() and not force:
        return Path(runs_dir) / rid
    n_started = 0
    if start_log:
        Path(start_log).mkdir(parents=True, exist_ok=True)
        (Path(start_log) / ("%s.%s" % (rid, uuid.uuid4().hex))).touch()
        n_started = len(list(Path(start_log).iterdir()))
    if hold and Path(hold).exists() and n_started > 2:
        delay_s = SLOW_S
    subprocess.run([sys.executable, "-c", "import sys, time; time.sleep(float(sys.argv[1]))",
                    str(delay_s), marker], check=True)
    return run_fake_twin(config, runs_dir=runs_dir, force=force)


from tests.test_sweep import _exec_counts  # noqa: E402  (run id -> times started)


def _configs(n=N_RUNS):
    return [{"restitution": 0.1 + 0.05 * i, "seed": 100 + i} for i in range(n)]


def _finished(runs):
    """Run folders the cache treats as finished (meta.json in a non-temporary folder)."""
    return {p.parent.name for p in Path(runs).glob("*/meta.json")
            if not p.parent.name.startswith(".")}


def _live_marked(marker):
    """Live (not zombie) processes whose command line holds ``marker``: (pid, cmdline)."""
    found = []
    try:
        import psutil
    except ImportError:
        psutil = None
    if psutil is not None:
        for p in psutil.process_iter(["pid", "cmdline", "status"]):
            try:
                cmd = " ".join(p.info["cmdline"] or [])
                if marker in cmd and p.info["status"] != psutil.STATUS_ZOMBIE \
                        and p.info["pid"] != os.getpid():
                    found.append((p.info["pid"], cmd))
            except (psutil.Error, TypeError):
                continue
        return found
    for d in Path("/proc").iterdir():
        if not d.name.isdigit() or int(d.name) == os.getpid():
            continue
        try:
            cmd = (d / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
            state = (d / "stat").read_text().rsplit(")", 1)[1].split()[0]
        except (OSError, IndexError):
            continue
        if marker in cmd and state not in ("Z", "X"):
            found.append((int(d.name), cmd))
    return found


def _no_orphans_within(marker, seconds=3.0):
    """Processes still carrying ``marker`` after waiting up to ``seconds`` (should be none)."""
    t_end = time.time() + seconds
    left = _live_marked(marker)
    while left and time.time() < t_end:
        time.sleep(0.1)
        left = _live_marked(marker)
    return left


def _kill_marked(marker):
    """SIGKILL whatever still carries ``marker`` (cleanup after a failed check)."""
    for pid, _ in _live_marked(marker):
        try:
            os.kill(pid, signal.SIGKILL)
        except OSError:
            pass


@pytest.fixture
def marker():
    """A unique string put on the command line of every process a test starts; whatever still
    carries it at the end is killed, so a failing test leaves nothing running."""
    m = "sweep-interrupt-%s" % uuid.uuid4().hex
    yield m
    _kill_marked(m)


def _finish(proc, marker, timeout=15.0):
    """Wait for ``proc`` to exit (its output, if piped); fail, killing everything, if it hangs."""
    try:
        return proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        _kill_marked(marker)
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except OSError:
            pass
        proc.communicate(timeout=10)
        pytest.fail("the sweep did not exit %.0f s after the signal" % timeout)


def _check_cache(runs):
    """Every finished folder is complete and loads; nothing was recorded as failed."""
    for rid in _finished(runs):
        meta = json.loads((Path(runs) / rid / "meta.json").read_text())
        assert meta["run_id"] == rid
        assert sweep.load_summary(Path(runs) / rid)["v_mean_m_s"] > 0
    assert not list(Path(runs).glob("*.failed.json")), "a stopped run was recorded as failed"


def _cli(tmp_path, marker):
    table = tmp_path / "params.csv"
    if not table.exists():
        pd.DataFrame(_configs()).to_csv(table, index=False)
    return [sys.executable, "-m", "analysis.sweep", "--table", str(table), "--runner", RUNNER,
            "--runner-kw", "marker=%s" % marker, "--runner-kw",
            "start_log=%s" % (tmp_path / "starts"), "--runner-kw",
            "hold=%s" % (tmp_path / "hold"), "--workers", "2",
            "--runs-dir", str(tmp_path / "runs"), "--out", str(tmp_path / "out.csv"),
            "--no-progress"]


def _start_mid_way(tmp_path, marker, capture=True):
    """Start the sweep command; return it once 2 runs finished and a (slow) run's child is
    alive."""
    (tmp_path / "hold").touch()
    pipe = subprocess.PIPE if capture else subprocess.DEVNULL
    proc = subprocess.Popen(_cli(tmp_path, marker), cwd=REPO_ROOT, start_new_session=True,
                            stdout=pipe, stderr=pipe, text=True)
    t_end = time.time() + 30
    while time.time() < t_end:
        if len(_finished(tmp_path / "runs")) >= 2 and any(
                "time.sleep" in cmd for _, cmd in _live_marked(marker)):
            return proc
        if proc.poll() is not None:
            break
        time.sleep(0.02)
    os.killpg(proc.pid, signal.SIGKILL)
    _kill_marked(marker)
    proc.communicate(timeout=10)
    pytest.fail("the sweep did not reach the middle of its runs")


def _interrupt_and_resume(tmp_path, marker, send, expected_rc):
    runs, log = tmp_path / "runs", tmp_path / "starts"
    proc = _start_mid_way(tmp_path, marker)
    t_sig = time.time()
    send(proc)
    _, err = _finish(proc, marker)
    took = time.time() - t_sig
    left = _no_orphans_within(marker)
    assert not left, "processes outlived the sweep: %s" % left
    assert proc.returncode == expected_rc, err
    assert took < 5.0, "the sweep took %.1f s to stop" % took
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and "Traceback" not in err, err
    assert "finished" in lines[0] and "rerun the same command" in lines[0], lines[0]

    finished = _finished(runs)
    starts = _exec_counts(log)
    assert 2 <= len(finished) < N_RUNS
    time.sleep(2 * RUN_S)          # nothing keeps working on the queue after the exit
    assert _exec_counts(log) == starts and _finished(runs) == finished
    _check_cache(runs)
    (tmp_path / "hold").unlink()

    part = pd.read_csv(tmp_path / "out.csv")
    assert len(part) == N_RUNS
    st = part.set_index("run_id")["status"]
    assert set(st) <= {"done", "interrupted", "not_started"}, set(st)
    assert set(st[st == "done"].index) == finished
    assert (st == "not_started").sum() >= 1
    assert not set(st[st == "not_started"].index) & set(starts), "a queued run was started"
    assert "%d of %d runs finished" % (len(finished), N_RUNS) in lines[0]

    again = subprocess.run(_cli(tmp_path, marker), cwd=REPO_ROOT, capture_output=True,
                           text=True, timeout=60)
    assert again.returncode == 0, again.stderr
    after = _exec_counts(log)
    for rid in finished:
        assert after[rid] == 1, "finished run %s was recomputed" % rid
    assert len(_finished(runs)) == N_RUNS
    full = pd.read_csv(tmp_path / "out.csv").set_index("run_id")["status"]
    assert (full[list(finished)] == "cached").all()
    assert (full.drop(list(finished)) == "done").all()
    _check_cache(runs)


def test_ctrl_c_to_the_process_group_stops_the_sweep_cleanly(tmp_path, marker):
    _interrupt_and_resume(tmp_path, marker, lambda p: os.killpg(p.pid, signal.SIGINT), 130)


def test_sigterm_to_the_sweep_process_stops_it_cleanly(tmp_path, marker):
    _interrupt_and_resume(tmp_path, marker, lambda p: os.kill(p.pid, signal.SIGTERM), 143)


def test_killed_sweep_process_leaves_no_worker_behind(tmp_path, marker):
    proc = _start_mid_way(tmp_path, marker, capture=False)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait(timeout=10)
    left = _no_orphans_within(marker, seconds=sweep.STOP_GRACE_S + 2.0)
    assert not left, "processes outlived the killed sweep: %s" % left
    _check_cache(tmp_path / "runs")


def _interrupt_in_process(cond, call, sig=signal.SIGINT, timeout=20.0):
    """Run ``call()`` while a thread sends ``sig`` to this process once ``cond()`` holds;
    return the SweepInterrupted it raised (fail if it raised none or a plain interrupt)."""
    over = threading.Event()

    def fire():
        t_end = time.time() + timeout
        while time.time() < t_end and not over.is_set():
            if cond():
                os.kill(os.getpid(), sig)
                return
            time.sleep(0.02)

    t = threading.Thread(target=fire, daemon=True)
    t.start()
    try:
        call()
    except sweep.SweepInterrupted as exc:
        return exc
    except KeyboardInterrupt:
        pytest.fail("a plain KeyboardInterrupt escaped the sweep")
    finally:
        over.set()
        t.join()
    pytest.fail("the sweep was not interrupted")


@pytest.mark.parametrize("backend", ["local", "serial"])
def test_run_sweep_raises_interrupted_and_resumes(tmp_path, marker, backend):
    runs, log = tmp_path / "runs", tmp_path / "starts"
    kw = {"marker": marker, "start_log": str(log), "hold": str(tmp_path / "hold")}
    (tmp_path / "hold").touch()
    before = (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM))
    cfgs = _configs(5)
    exc = _interrupt_in_process(
        lambda: len(_finished(runs)) >= 1 and any(
            "time.sleep" in cmd for _, cmd in _live_marked(marker)),
        lambda: sweep.run_sweep(cfgs, runner=RUNNER, runner_kwargs=kw, workers=2,
                                backend=backend, runs_dir=runs, progress=False))
    assert isinstance(exc, KeyboardInterrupt) and exc.exit_code == 130
    assert (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)) == before
    assert not _no_orphans_within(marker)
    st = exc.result.table.set_index("run_id")["status"]
    finished = _finished(runs)
    assert set(st[st == "done"].index) == finished and 1 <= len(finished) < 5
    assert (st == "interrupted").sum() >= 1 and (st == "not_started").sum() >= 1
    assert exc.result.n_unfinished == 5 - len(finished) and not exc.result.ok
    assert exc.result.table.loc[st.values == "done", "v_mean_m_s"].notna().all()
    _check_cache(runs)
    (tmp_path / "hold").unlink()
    res = sweep.run_sweep(cfgs, runner=RUNNER, runner_kwargs=kw, workers=2, backend=backend,
                          runs_dir=runs, progress=False)
    assert res.ok and res.n_executed == 5 - len(finished)
    assert all(_exec_counts(log)[rid] == 1 for rid in finished)


def test_uncaught_interrupt_prints_one_line(tmp_path, marker):
    """A command that does not catch SweepInterrupted still ends with one line, non-zero."""
    script = tmp_path / "study.py"
    script.write_text(
        "from analysis.sweep import run_sweep\n"
        "cfgs = [{'restitution': 0.1 + 0.05 * i, 'seed': 300 + i} for i in range(6)]\n"
        "run_sweep(cfgs, runner=%r, runner_kwargs={'marker': %r, 'hold': %r,\n"
        "          'start_log': %r}, workers=2, runs_dir=%r, progress=False)\n"
        % (RUNNER, marker, str(tmp_path / "hold"), str(tmp_path / "starts"),
           str(tmp_path / "runs")))
    (tmp_path / "hold").touch()
    env = dict(os.environ, PYTHONPATH=str(REPO_ROOT))
    proc = subprocess.Popen([sys.executable, str(script)], cwd=REPO_ROOT, env=env,
                            start_new_session=True, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    t_end = time.time() + 30
    while time.time() < t_end and not any("time.sleep" in c for _, c in _live_marked(marker)):
        time.sleep(0.02)
    os.killpg(proc.pid, signal.SIGINT)
    _, err = _finish(proc, marker)
    assert proc.returncode != 0
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and "Traceback" not in err, err
    assert "rerun the same command" in lines[0]
    assert not _no_orphans_within(marker)


def test_dask_backend_cancels_its_futures(tmp_path, marker):
    pytest.importorskip("dask.distributed")
    (tmp_path / "hold").touch()
    runs, log = tmp_path / "runs", tmp_path / "starts"
    exc = _interrupt_in_process(
        lambda: len(_finished(runs)) >= 1 and any(
            "time.sleep" in cmd for _, cmd in _live_marked(marker)),
        lambda: sweep.run_sweep(_configs(10), runner=RUNNER, backend="dask", workers=2,
                                runs_dir=runs, progress=False,
                                runner_kwargs={"start_log": str(log), "delay_s": 1.0,
                                               "marker": marker,
                                               "hold": str(tmp_path / "hold")}))
    assert not _no_orphans_within(marker)      # the local cluster's runs ended with it
    st = exc.result.table.set_index("run_id")["status"]
    assert (st == "interrupted").sum() >= 1 and (st == "not_started").sum() >= 1
    assert set(st) <= {"done", "interrupted", "not_started"}
    starts = _exec_counts(log)
    time.sleep(1.0)
    assert _exec_counts(log) == starts                           # the cancelled runs never start
    assert not set(st[st == "not_started"].index) & set(starts)
    _check_cache(runs)
