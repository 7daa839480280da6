"""Run many twin configs in parallel, cached by run id, on a laptop or on a cluster.

A *sweep* is a list of run configs (dicts of ``twin_config.PARAMETERS`` keys). Each config is
run by a *runner* ``runner(config, runs_dir=..., force=False) -> Path`` - by default
``analysis.twin.run_twin``, which starts YADE and writes ``<runs_dir>/<run-id>/``.

Caching and failures
--------------------
* A run whose folder ``<runs_dir>/<run-id>/meta.json`` exists is complete and is never
  recomputed (the twin writes the folder under a temporary name and renames it when complete),
  so a killed sweep, run again, recomputes nothing that had finished.
* A run that raises is recorded in ``<runs_dir>/<run-id>.failed.json`` (error, traceback,
  config, host, time) and in the result table (status ``failed``) - never dropped. A later sweep
  reports it as ``failed_cached`` without re-running it, unless ``retry_failed=True``
  (``--retry-failed``). A worker process that dies (segfault, out of memory) leaves its run
  ``failed`` in the table but writes no ``.failed.json``: the next sweep tries it again.
* Equal configs (same run id) in one sweep are run once.

Interrupts
----------
SIGINT (Ctrl-C) or SIGTERM stops a sweep cleanly: no further run starts, the runs in progress
are stopped with everything they launched (the local backend runs each worker process as the
leader of its own process group, so YADE dies with it: SIGTERM, then SIGKILL after
``STOP_GRACE_S``; a second signal skips the grace), finished runs stay in the cache, and a
stopped run leaves no ``meta.json`` and no ``.failed.json`` - it is simply run again next time.
:func:`run_sweep` then raises :class:`SweepInterrupted` (a ``KeyboardInterrupt``) carrying the
partial table (status ``interrupted`` for stopped runs, ``not_started`` for queued ones); the
command line writes that table to ``--out``, prints one line (how many runs finished, how to
resume) and exits with 128 + the signal number (130 for SIGINT, 143 for SIGTERM). Rerunning the
same command resumes: finished runs are read from the cache. A command that does not catch
the exception still ends with that one line, not a traceback. A worker whose sweep process is
killed outright (SIGKILL) notices within a second and kills its run. On the Dask backend the
futures are cancelled and a cluster the sweep started is closed (for a local cluster the
processes its runs started are ended too); runs already executing on the workers of an external
scheduler may still finish (their folders land in the cache).

Backends (chosen by configuration alone)
----------------------------------------
``local``   ``workers`` worker processes, each the leader of its own process group and handed
            one run at a time (default).
``serial``  in this process, one run after another (debugging).
``dask``    dask.distributed: an existing scheduler (``scheduler='tcp://host:8786'``), a SLURM
            allocation (``slurm={...}``, through dask_jobqueue.SLURMCluster) or, with neither,
            a LocalCluster of ``workers`` single-threaded processes.

Running on a cluster
--------------------
The runs folder must be on a filesystem shared by the workers (results/runs/ inside the
checkout on a shared home or scratch), and every worker needs the checkout and its venv
(``analysis`` importable, ``yade`` on PATH).

1. Existing Dask scheduler::

       dask scheduler --port 8786 &                       # on the head node
       dask worker tcp://head:8786 --nthreads 1 --nworkers 8   # on each compute node
       python -m analysis.sweep --table params.csv --backend dask --scheduler tcp://head:8786

2. SLURM (the sweep submits its own worker jobs through dask_jobqueue)::

       python -m analysis.sweep --table params.csv --slurm --cores 16 --memory 32GB \\
           --walltime 04:00:00 --jobs 4 --queue compute \\
           --prologue "cd $PWD" --prologue "source .venv/bin/activate"

   Each job runs ``cores`` single-threaded Dask workers (one YADE run each).

3. The same through a sweep-config file (YAML or JSON), flags override the file::

       # sweep.yaml
       table: params.csv
       backend: dask
       slurm: {cores: 16, memory: 32GB, walltime: "04:00:00", jobs: 4, queue: compute,
               prologue: ["cd /home/me/mill", "source .venv/bin/activate"]}
       retry_failed: false
       base: {record_s: 0.5}        # merged into every row of the table

       python -m analysis.sweep --sweep-config sweep.yaml

4. Without Dask, YADE's own batch runner: export the sweep as a yade-batch parameter table and
   let ``yade-batch`` distribute the lines::

       python -m analysis.sweep --table params.csv --export-yade-table runs.table
       yade-batch --job-threads=1 runs.table yade_scripts/mill.py

   The table is whitespace-separated, a header of config keys and one line per run (the format
   ``yade.utils.readParamsFromTable`` reads); its ``description`` column holds the run id.

Parameter tables (``--table``) are either CSV (comma-separated, a header of config keys, an
empty cell meaning "default") or yade-batch tables as above (``*`` meaning default, ``=`` the
value of the line above, ``description`` and ``!``-columns ignored).
"""
from __future__ import annotations

import argparse
import ast
import collections
import datetime
import functools
import importlib
import json
import math
import multiprocessing
import os
import shutil
import signal
import socket
import sys
import threading
import time
import traceback
import uuid
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from analysis.atomic_dir import OutputError, atomic_file
from analysis.config import RUNS_DIR, twin_config

BACKENDS = ("local", "serial", "dask")
DEFAULT_RUNNER = "analysis.twin:run_twin"
#: columns of the sweep table before the config and summary columns
STATUS_COLUMNS = ("run_id", "status", "error", "run_dir", "exec_s")
#: statuses of the runs an interrupted sweep did not finish: stopped mid-run, never started
UNFINISHED_STATUSES = ("interrupted", "not_started")
#: signals that stop a sweep cleanly
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
#: seconds a stopped run's processes get to exit after SIGTERM before they get SIGKILL [s]
STOP_GRACE_S = 3.0
#: how often a local worker checks that the sweep process is still alive [s]
PARENT_POLL_S = 0.25


class SweepInputError(ValueError):
    """A parameter table, sweep config or runner spec is malformed."""


class SweepInterrupted(KeyboardInterrupt):
    """SIGINT or SIGTERM stopped a sweep: finished runs are cached, the others did not finish.

    A ``KeyboardInterrupt``, so code that catches ``Exception`` lets it through. ``str()`` is
    the one line for users (how many runs finished, how to resume).

    Attributes
    ----------
    result : SweepResult - the partial table: statuses done / cached / failed / failed_cached
        for the runs that ended, 'interrupted' for runs stopped mid-way and 'not_started' for
        queued ones (both without outputs)
    signum : int - the signal that stopped the sweep
    exit_code : int - 128 + signum (130 for SIGINT, 143 for SIGTERM)
    runs_dir : Path - the run cache
    """

    def __init__(self, result, signum, runs_dir):
        self.result = result
        self.signum = int(signum)
        self.runs_dir = Path(runs_dir)
        super().__init__(self.line())

    @property
    def exit_code(self):
        return 128 + self.signum

    @property
    def signal_name(self):
        return _signal_name(self.signum)

    def line(self, table_path=None):
        """The one-line report: finished runs, unfinished runs, partial table, how to resume."""
        st = self.result.table.drop_duplicates("run_id")["status"].value_counts()
        n = int(st.sum())
        now, cached = int(st.get("done", 0)), int(st.get("cached", 0))
        failed = int(st.get("failed", 0) + st.get("failed_cached", 0))
        stopped, queued = int(st.get("interrupted", 0)), int(st.get("not_started", 0))
        parts = ["interrupted by %s: %d of %d runs finished (%d now, %d cached)"
                 % (self.signal_name, now + cached, n, now, cached)]
        if failed:
            parts.append("%d failed" % failed)
        parts.append("%d stopped mid-run, %d not started" % (stopped, queued))
        text = ", ".join(parts)
        if table_path is not None:
            text += "; partial table in %s" % table_path
        return text + ("; finished runs are cached in %s - rerun the same command to resume"
                       % self.runs_dir)


def interrupted_exit(prog, exc):
    """Print the one line of an interrupted command to stderr and return its exit code.

    For a command's ``except KeyboardInterrupt as exc:`` clause: a :class:`SweepInterrupted`
    says how many runs finished and how to resume; a plain Ctrl-C outside a sweep says that
    finished twin runs stay cached. Returns 128 + the signal number (130 for Ctrl-C).
    """
    if isinstance(exc, SweepInterrupted):
        print("%s: %s" % (prog, exc), file=sys.stderr)
        return exc.exit_code
    print("%s: interrupted; finished twin runs stay cached - rerun the same command to resume"
          % prog, file=sys.stderr)
    return 128 + int(signal.SIGINT)


def _report_uncaught_interrupts():
    """Make an uncaught :class:`SweepInterrupted` end the program with its one line.

    Installed when a sweep is interrupted, so a command that does not catch the exception
    prints one line instead of a traceback (the interpreter still exits as for an uncaught
    Ctrl-C, i.e. non-zero); other exceptions go to the previous hook unchanged.
    """
    previous = sys.excepthook
    if getattr(previous, "reports_sweep_interrupts", False):
        return

    def hook(etype, value, tb):
        if isinstance(value, SweepInterrupted):
            prog = Path(sys.argv[0]).stem if sys.argv and sys.argv[0] else "sweep"
            print("%s: %s" % (prog, value), file=sys.stderr)
        else:
            previous(etype, value, tb)

    hook.reports_sweep_interrupts = True
    sys.excepthook = hook


@dataclass
class SweepResult:
    """Outcome of :func:`run_sweep`.

    Attributes
    ----------
    table : DataFrame, shape (n_configs, ...) - one row per input config, in input order:
        run_id, status ('done' computed now, 'cached' found complete, 'failed' failed now,
        'failed_cached' failed before and not retried; after an interrupt also 'interrupted'
        stopped mid-run and 'not_started'), error, run_dir, exec_s [s], the configs' own keys,
        and the run summaries (v_mean_m_s, f_col_hz, ... from meta.json).
    wall_s : float - wall time of the sweep [s]
    interrupted : str or None - the signal that stopped the sweep (see SweepInterrupted)
    """
    table: pd.DataFrame
    wall_s: float
    backend: str = "local"
    workers: int = 1
    counts: dict = field(default_factory=dict)
    #: name of the signal that stopped the sweep (None: it ran to its end)
    interrupted: str | None = None

    @property
    def n_executed(self):
        """Runs really started by this sweep (done + failed now)."""
        return int(self.table.drop_duplicates("run_id")["status"].isin(["done", "failed"]).sum())

    @property
    def n_failed(self):
        return int(self.table.drop_duplicates("run_id")["status"]
                   .isin(["failed", "failed_cached"]).sum())

    @property
    def n_unfinished(self):
        """Runs an interrupted sweep stopped mid-way or never started."""
        return int(self.table.drop_duplicates("run_id")["status"]
                   .isin(UNFINISHED_STATUSES).sum())

    @property
    def ok(self):
        """True when no run failed and the sweep was not interrupted."""
        return self.n_failed == 0 and self.interrupted is None

    def failed(self):
        """Rows of the failed runs (with their errors)."""
        return self.table[self.table["status"].str.startswith("failed")]

    def to_frame(self):
        return self.table.copy()

    def __str__(self):
        c = self.table.drop_duplicates("run_id")["status"].value_counts().to_dict()
        return ("sweep: %d configs, %d unique runs (%s) in %.1f s on %s x%d%s"
                % (len(self.table), self.table["run_id"].nunique(),
                   ", ".join("%s %d" % kv for kv in sorted(c.items())), self.wall_s,
                   self.backend, self.workers,
                   ", interrupted by %s" % self.interrupted if self.interrupted else ""))


# ----------------------------------------------------------------------------------------- runs

#: the latest runs whose wall time :func:`cached_wall_s` takes the median of, and the fewest
CACHED_WALL_RUNS, CACHED_WALL_MIN = 40, 5


def cached_wall_s(frame, runs_dir=None):
    """Median wall time [s] of the latest complete twin runs in the cache whose scene ran in
    ``frame`` ('lab' or 'jar', meta.json's ``frame``; the FAKE twin's runs left out), or None
    when fewer than CACHED_WALL_MIN are there."""
    root = Path(runs_dir) if runs_dir is not None else RUNS_DIR
    metas = []
    try:
        entries = list(os.scandir(root))
    except OSError:
        return None
    for e in entries:
        p = Path(e.path) / "meta.json"
        try:
            metas.append((p.stat().st_mtime, p))
        except OSError:
            continue
    walls = []
    # the latest few times as many as needed, at most: a cache of FAKE runs is not read whole
    for _, p in sorted(metas, reverse=True)[:4 * CACHED_WALL_RUNS]:
        try:
            m = json.loads(p.read_text())
        except (OSError, ValueError):
            continue
        if m.get("frame", "lab") != frame or str(m.get("yade_version", "")).startswith("FAKE"):
            continue
        w = m.get("wall_s")
        if isinstance(w, (int, float)) and w > 0:
            walls.append(float(w))
        if len(walls) >= CACHED_WALL_RUNS:
            break
    return float(pd.Series(walls).median()) if len(walls) >= CACHED_WALL_MIN else None


def failed_path(runs_dir, rid):
    """Path of the failure record of run ``rid``."""
    return Path(runs_dir) / ("%s.failed.json" % rid)


def _json_default(o):
    if hasattr(o, "item"):
        return o.item()
    return str(o)


def _atomic_write_json(path, obj):
    with atomic_file(path) as tmp, open(tmp, "w") as fh:
        json.dump(obj, fh, indent=1, default=_json_default)


def execute_run(runner, config, runs_dir, rid):
    """Run one config and return a status record; never raises for a failing run.

    A failure is also written to ``<runs_dir>/<rid>.failed.json`` (atomically) so it survives
    a killed sweep - unless the error is ``transient`` (a run ended by a signal from outside,
    :class:`analysis.twin.TwinRunKilled`): the next sweep runs it again. Module-level so
    process pools and Dask can ship it to workers.
    """
    t0 = time.time()
    try:
        path = runner(config, runs_dir=runs_dir, force=False)
        fp = failed_path(runs_dir, rid)
        if fp.exists():
            fp.unlink()
        return {"run_id": rid, "status": "done", "error": None, "run_dir": str(path),
                "exec_s": time.time() - t0}
    except Exception as exc:  # the run failed: keep the error, never drop the run
        rec = {"run_id": rid, "status": "failed",
               "error": "%s: %s" % (type(exc).__name__, exc),
               "traceback": traceback.format_exc(), "config": config,
               "host": socket.gethostname(), "pid": os.getpid(),
               "time_utc": datetime.datetime.now(datetime.timezone.utc).isoformat(),
               "exec_s": time.time() - t0}
        if not getattr(exc, "transient", False):
            Path(runs_dir).mkdir(parents=True, exist_ok=True)
            _atomic_write_json(failed_path(runs_dir, rid), rec)
        return {k: rec[k] for k in ("run_id", "status", "error", "exec_s")} | {"run_dir": None}


def load_summary(run_dir):
    """meta.json["summary"] of a complete run folder (an empty dict if it has none)."""
    with open(Path(run_dir) / "meta.json") as fh:
        meta = json.load(fh)
    return dict(meta.get("summary") or {})


def resolve_runner(spec=None, kwargs=None):
    """Runner callable from ``"module:function"`` (default the real twin) and fixed kwargs."""
    if callable(spec):
        fn = spec
    else:
        spec = spec or DEFAULT_RUNNER
        if ":" not in spec:
            raise SweepInputError("runner must be 'module:function', got %r" % spec)
        mod, name = spec.split(":", 1)
        try:
            fn = getattr(importlib.import_module(mod), name)
        except (ImportError, AttributeError) as exc:
            raise SweepInputError("cannot load runner %s: %s" % (spec, exc))
    return functools.partial(fn, **kwargs) if kwargs else fn


# --------------------------------------------------------------------------------------- sweep

def _clean(value):
    """numpy scalars -> Python scalars (twin_config checks isinstance(x, int/float))."""
    if hasattr(value, "item") and not isinstance(value, (list, dict, str)):
        return value.item()
    return value


def prepare_configs(configs):
    """Validate configs and return (clean user dicts, run ids). Raises SweepInputError."""
    clean, ids = [], []
    for i, cfg in enumerate(configs):
        if not isinstance(cfg, dict):
            raise SweepInputError("config %d is not a dict: %r" % (i, cfg))
        c = {k: _clean(v) for k, v in cfg.items()}
        try:
            ids.append(twin_config.run_id(c))
        except twin_config.ConfigError as exc:
            raise SweepInputError("config %d: %s" % (i, exc))
        clean.append(c)
    return clean, ids


def slurm_cluster_kwargs(slurm):
    """SLURMCluster keyword arguments from a sweep config's ``slurm`` mapping.

    Keys: cores (single-threaded workers per job), memory, walltime, queue, account,
    prologue (shell lines run before the worker starts: cd to the checkout, activate the
    venv), jobs (taken out: the number of jobs to scale to); anything else is passed through
    (job_extra_directives, local_directory, log_directory, ...). Returns (kwargs, jobs).
    """
    s = dict(slurm)
    jobs = int(s.pop("jobs", 1))
    cores = int(s.pop("cores", 1))
    prologue = s.pop("prologue", None)
    kw = dict(cores=cores, processes=cores, memory=s.pop("memory", "4GB"),
              walltime=s.pop("walltime", "01:00:00"))
    if prologue:
        kw["job_script_prologue"] = list(prologue) if not isinstance(prologue, str) \
            else [prologue]
    kw.update(s)
    return kw, jobs


def _dask_client(workers, scheduler=None, slurm=None):
    from dask.distributed import Client, LocalCluster
    if slurm:
        from dask_jobqueue import SLURMCluster
        kw, jobs = slurm_cluster_kwargs(slurm)
        cluster = SLURMCluster(**kw)
        cluster.scale(jobs=jobs)
        return Client(cluster), cluster
    if scheduler:
        return Client(scheduler), None
    cluster = LocalCluster(n_workers=int(workers), threads_per_worker=1, processes=True,
                           dashboard_address=None)
    return Client(cluster), cluster


def run_sweep(configs, runner=None, workers=2, backend="local", runs_dir=None,
              retry_failed=False, progress=True, scheduler=None, slurm=None,
              runner_kwargs=None):
    """Run ``configs`` in parallel, skipping complete runs; return a :class:`SweepResult`.

    Parameters
    ----------
    configs : list of dict - run configs (twin_config keys); validated before anything runs
    runner : callable or "module:function", optional - ``runner(config, runs_dir, force)
        -> Path``; default ``analysis.twin.run_twin`` (imported lazily)
    workers : int - parallel processes (local backend, or dask LocalCluster)
    backend : {'local', 'serial', 'dask'}
    runs_dir : path-like, optional - parent of run folders (default RUNS_DIR)
    retry_failed : bool - re-run runs recorded as failed (``<run-id>.failed.json``)
    progress : bool - show a tqdm progress bar
    scheduler : str, optional - address of a running Dask scheduler (dask backend)
    slurm : dict, optional - SLURMCluster options (cores, memory, walltime, jobs, queue,
        account, prologue, ...); implies the dask backend
    runner_kwargs : dict, optional - fixed keyword arguments bound to the runner

    Returns
    -------
    SweepResult

    Raises
    ------
    SweepInputError
        a config is invalid (nothing is run), or the backend / runner is unknown.
    SweepInterrupted
        SIGINT or SIGTERM arrived during the sweep (handled only while it runs, in the main
        thread; the previous handlers are restored): no further run was started, the running
        ones were stopped with their child processes, finished runs are cached; the exception
        carries the partial table. Calling again with the same configs resumes.
    """
    from tqdm.auto import tqdm

    if slurm or scheduler:
        backend = "dask"
    if backend not in BACKENDS:
        raise SweepInputError("backend must be one of %s, got %r" % (BACKENDS, backend))
    workers = int(workers)
    if workers < 1:
        raise SweepInputError("workers must be >= 1, got %d" % workers)
    configs, ids = prepare_configs(list(configs))
    runs_dir = Path(runs_dir) if runs_dir is not None else RUNS_DIR
    runs_dir.mkdir(parents=True, exist_ok=True)
    t0 = time.time()

    records = {}
    todo = {}
    for cfg, rid in zip(configs, ids):
        if rid in records or rid in todo:
            continue
        if (runs_dir / rid / "meta.json").exists():
            records[rid] = {"run_id": rid, "status": "cached", "error": None,
                            "run_dir": str(runs_dir / rid), "exec_s": 0.0}
        elif failed_path(runs_dir, rid).exists() and not retry_failed:
            with open(failed_path(runs_dir, rid)) as fh:
                old = json.load(fh)
            records[rid] = {"run_id": rid, "status": "failed_cached",
                            "error": old.get("error"), "run_dir": None,
                            "exec_s": old.get("exec_s")}
        else:
            todo[rid] = cfg

    started = {}   # runs handed out: run id -> pids of its processes stopped by a signal
    with _SignalGuard() as guard:
        if todo:
            run_fn = resolve_runner(runner, runner_kwargs)
            bar = tqdm(total=len(todo), desc="twin runs", unit="run", disable=not progress,
                       file=sys.stderr)
            try:
                if backend == "serial":
                    _run_serial(run_fn, todo, runs_dir, records, bar, guard, started)
                elif backend == "local":
                    _run_local(run_fn, todo, runs_dir, workers, records, bar, guard, started)
                else:
                    _run_dask(run_fn, todo, runs_dir, workers, scheduler, slurm, records, bar,
                              guard, started)
            finally:
                bar.close()
    if guard.signum is not None:
        _settle_unfinished(todo, records, runs_dir, started, guard.signum)
    result = SweepResult(table=_build_table(configs, ids, records), wall_s=time.time() - t0,
                         backend=backend, workers=workers,
                         interrupted=None if guard.signum is None else _signal_name(guard.signum))
    if guard.signum is not None:
        _report_uncaught_interrupts()
        raise SweepInterrupted(result, guard.signum, runs_dir)
    return result


def _build_table(configs, ids, records):
    """The sweep table: one row per config (status columns, config keys, run summary)."""
    rows = []
    summaries = {}
    for cfg, rid in zip(configs, ids):
        rec = records[rid]
        row = {k: rec.get(k) for k in STATUS_COLUMNS}
        row.update({k: (json.dumps(v) if isinstance(v, (dict, list)) else v)
                    for k, v in cfg.items()})
        if rec["status"] in ("done", "cached"):
            if rid not in summaries:
                summaries[rid] = load_summary(rec["run_dir"])
            row.update(summaries[rid])
        rows.append(row)
    return pd.DataFrame(rows)


def _signal_name(signum):
    try:
        return signal.Signals(signum).name
    except ValueError:
        return "signal %d" % signum


def _settle_unfinished(todo, records, runs_dir, started, signum):
    """Give every run of an interrupted sweep a record.

    A run whose folder is complete counts as done (it finished as the sweep stopped); a run
    that was started is 'interrupted' - the temporary folders ``.tmp-<run-id>-<pid>`` its
    stopped processes were writing are removed - and a queued one is 'not_started'. Neither
    gets a ``.failed.json``, so the next sweep runs them.
    """
    how = "stopped by %s" % _signal_name(signum)
    for rid in todo:
        if rid in records:
            continue
        if (runs_dir / rid / "meta.json").exists():
            records[rid] = {"run_id": rid, "status": "done", "error": None,
                            "run_dir": str(runs_dir / rid), "exec_s": None}
        elif rid in started:
            for pid in started[rid]:
                shutil.rmtree(runs_dir / (".tmp-%s-%d" % (rid, pid)), ignore_errors=True)
            records[rid] = {"run_id": rid, "status": "interrupted", "run_dir": None,
                            "error": "%s during the run" % how, "exec_s": None}
        else:
            records[rid] = {"run_id": rid, "status": "not_started", "run_dir": None,
                            "error": "%s before the run started" % how, "exec_s": None}


# -------------------------------------------------------------------------- signals, processes

class _StopRequested(BaseException):
    """Raised by the stop-signal handler to end a run executing in the sweep's own process."""


class _SignalGuard:
    """Catch SIGINT and SIGTERM for the duration of a sweep; restore the old handlers after.

    The handler records the first signal (``signum``) and counts them (a second one skips the
    grace period of stopped processes); while ``raise_now`` is set it also raises
    :class:`_StopRequested`, to break out of a run executing in this process (serial backend).
    A signal that is ignored on entry stays ignored. Outside the main thread no handler can be
    installed and the guard does nothing.
    """

    def __init__(self):
        self.signum = None
        self.count = 0
        self.raise_now = False
        self._old = {}

    @property
    def stop(self):
        """True once a stop signal arrived."""
        return self.signum is not None

    def _handle(self, signum, frame):
        self.count += 1
        if self.signum is None:
            self.signum = signum
        if self.raise_now:
            self.raise_now = False
            raise _StopRequested()

    def __enter__(self):
        if threading.current_thread() is threading.main_thread():
            for sig in STOP_SIGNALS:
                old = signal.getsignal(sig)
                if old is None or old == signal.SIG_IGN:
                    continue
                self._old[sig] = old
                signal.signal(sig, self._handle)
        return self

    def __exit__(self, *exc):
        for sig, old in self._old.items():
            signal.signal(sig, old)
        self._old = {}
        return False


def _live_processes():
    """(pid, parent pid, process group) of every live (not zombie) process, from /proc;
    None where /proc is not available."""
    proc = Path("/proc")
    if not (proc / "self" / "stat").exists():
        return None
    out = []
    for d in proc.iterdir():
        if not d.name.isdigit():
            continue
        try:
            fields = (d / "stat").read_text().rsplit(")", 1)[1].split()
            if fields[0] not in ("Z", "X"):
                out.append((int(d.name), int(fields[1]), int(fields[2])))
        except (OSError, IndexError, ValueError):
            continue
    return out


def _group_pids(pgid):
    """Live (not zombie) processes of process group ``pgid``; None without /proc."""
    procs = _live_processes()
    return None if procs is None else [pid for pid, _, pg in procs if pg == pgid]


def _descendants(pids):
    """Live descendants (children, their children, ...) of the processes ``pids``."""
    procs = _live_processes() or []
    kids = collections.defaultdict(list)
    for pid, ppid, _ in procs:
        kids[ppid].append(pid)
    found, todo = [], list(pids)
    while todo:
        for child in kids.get(todo.pop(), []):
            if child not in found:
                found.append(child)
                todo.append(child)
    return found


def _end_processes(pids, grace_s=STOP_GRACE_S):
    """SIGTERM the processes ``pids``, SIGKILL those still alive after ``grace_s``."""
    for pid in pids:
        try:
            os.kill(pid, signal.SIGTERM)
        except OSError:
            pass
    deadline = time.monotonic() + grace_s
    while pids and time.monotonic() < deadline:
        live = {pid for pid, _, _ in (_live_processes() or [])}
        pids = [pid for pid in pids if pid in live]
        if pids:
            time.sleep(0.05)
    for pid in pids:
        try:
            os.kill(pid, signal.SIGKILL)
        except OSError:
            pass


def _group_alive(pgid):
    """True while process group ``pgid`` holds a live process."""
    pids = _group_pids(pgid)
    if pids is not None:
        return bool(pids)
    try:
        os.killpg(pgid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _signal_group(pgid, sig):
    """Send ``sig`` to process group ``pgid`` (never the sweep's own group); False if gone."""
    if pgid is None or pgid == os.getpgrp():
        return False
    try:
        os.killpg(pgid, sig)
    except (ProcessLookupError, PermissionError):
        return False
    return True


def _watch_parent(ppid):
    """Thread of a local worker: once the sweep process ``ppid`` is gone (killed outright),
    SIGKILL this worker's process group - the worker, its run and every process the run started
    - all at once, so the worker cannot see its run's processes die and record the run as
    failed."""
    while os.getppid() == ppid:
        time.sleep(PARENT_POLL_S)
    me = os.getpid()
    if os.getpgrp() == me:
        os.killpg(me, signal.SIGKILL)
    os.kill(me, signal.SIGKILL)            # not a group leader: end this process alone


def _local_worker(conn, run_fn, runs_dir, parent_pid, start_method):
    """Body of a local-backend worker process: run the configs received on ``conn`` one at a
    time and send back each status record, until None or the end of the pipe.

    The worker leads a new process group, which every process its runs start (YADE) joins, so
    the sweep ends a run and all it launched by signalling that group. SIGINT and SIGTERM take
    their default action (a stopped worker dies at once and cannot record the stopped run as
    failed). A thread ends the group if the sweep process disappears.
    """
    try:
        os.setpgid(0, 0)
    except OSError:
        pass
    for sig in STOP_SIGNALS:
        signal.signal(sig, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, STOP_SIGNALS)
    watch = os.getppid() if start_method == "forkserver" else parent_pid
    threading.Thread(target=_watch_parent, args=(watch,), name="watch-sweep",
                     daemon=True).start()
    while True:
        try:
            task = conn.recv()
        except (EOFError, OSError):
            break
        if task is None:
            break
        rid, cfg = task
        conn.send(execute_run(run_fn, cfg, runs_dir, rid))


class _LocalWorker:
    """One local-backend worker process (:func:`_local_worker`): its pipe, its process group
    and the run it is executing (``task``, a run id, or None when idle)."""

    def __init__(self, ctx, run_fn, runs_dir):
        self.conn, child = ctx.Pipe()
        # the child must not run the sweep's handlers: it starts with the stop signals blocked
        # and unblocks them once their default action is back
        blocked = signal.pthread_sigmask(signal.SIG_BLOCK, STOP_SIGNALS)
        try:
            self.proc = ctx.Process(target=_local_worker, name="sweep-worker",
                                    args=(child, run_fn, str(runs_dir), os.getpid(),
                                          ctx.get_start_method()))
            self.proc.start()
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, blocked)
        child.close()
        try:
            os.setpgid(self.proc.pid, self.proc.pid)
        except OSError:
            pass
        self._pgid = None
        self.task = None
        self.stopped_pids = []
        _ = self.pgid                  # confirm the group now, while the worker surely lives

    @property
    def pgid(self):
        """The worker's own process group id once confirmed (None before: never guessed)."""
        if self._pgid is None:
            try:
                if os.getpgid(self.proc.pid) == self.proc.pid:
                    self._pgid = self.proc.pid
            except OSError:
                pass
        return self._pgid

    def give(self, rid, cfg):
        """Hand run ``rid`` to the (idle) worker; False if its pipe is broken."""
        try:
            self.conn.send((rid, cfg))
        except (OSError, ValueError):
            return False
        self.task = rid
        return True

    def poll(self):
        """The record of the run just finished, a failure record if the worker died during
        the run, or None while the run goes on."""
        try:
            if self.conn.poll():
                rec = self.conn.recv()
                self.task = None
                return rec
        except (EOFError, OSError):
            self.proc.join(timeout=1.0)
        if self.proc.is_alive():
            return None
        rid, self.task = self.task, None
        # the worker died (segfault, out of memory, killed): cause unknown, so no .failed.json
        return {"run_id": rid, "status": "failed", "run_dir": None, "exec_s": None,
                "error": "worker process died (exit code %s); the next sweep runs it again"
                         % self.proc.exitcode}

    def receive_last(self):
        """A record the worker sent before it was stopped, or None."""
        try:
            if self.conn.poll():
                return self.conn.recv()
        except (EOFError, OSError):
            pass
        return None

    def kill_group(self):
        """SIGKILL the worker and whatever is left in its process group; reap the worker."""
        if not _signal_group(self.pgid, signal.SIGKILL) and self.proc.is_alive():
            self.proc.kill()
        self.proc.join(timeout=5.0)
        self.conn.close()


def _run_serial(run_fn, todo, runs_dir, records, bar, guard, started):
    """Serial backend: the runs one after another in this process. A stop signal during a run
    interrupts it (the runner's own cleanup ends the processes it started, as
    ``subprocess.run`` does) and no further run starts."""
    for rid, cfg in todo.items():
        if guard.stop:
            break
        started[rid] = []
        try:
            guard.raise_now = True
            try:
                rec = execute_run(run_fn, cfg, runs_dir, rid)
            finally:
                guard.raise_now = False
        except _StopRequested:
            break
        records[rid] = rec
        bar.update(1)


def _run_local(run_fn, todo, runs_dir, workers, records, bar, guard, started):
    """Local backend: up to ``workers`` worker processes (:class:`_LocalWorker`), each handed
    one run at a time, so nothing waits queued inside a worker. A worker that dies fails only
    its own run and is replaced. On a stop signal (or any error) no further run is handed out
    and the running ones are stopped with everything they started (:func:`_stop_workers`)."""
    from multiprocessing.connection import wait

    ctx = multiprocessing.get_context()
    pending = collections.deque(todo.items())
    pool = []
    finished = False
    try:
        while not guard.stop and (pending or any(w.task is not None for w in pool)):
            idle = [w for w in pool if w.task is None]
            while pending and not guard.stop:
                if not idle:
                    if len(pool) >= workers:
                        break
                    idle.append(_LocalWorker(ctx, run_fn, runs_dir))
                    pool.append(idle[-1])
                w = idle.pop()
                rid, cfg = pending.popleft()
                started[rid] = []
                if not w.give(rid, cfg):       # the worker died while idle
                    records[rid] = {"run_id": rid, "status": "failed", "run_dir": None,
                                    "exec_s": None, "error": "worker process died before the "
                                    "run started; the next sweep runs it again"}
                    bar.update(1)
                    w.kill_group()
                    pool.remove(w)
            busy = [w for w in pool if w.task is not None]
            if not busy:
                continue
            wait([w.conn for w in busy] + [w.proc.sentinel for w in busy], timeout=0.2)
            for w in busy:
                rec = w.poll()
                if rec is None:
                    continue
                records[rec["run_id"]] = rec
                bar.update(1)
                if not w.proc.is_alive():
                    w.kill_group()             # what the dead worker left behind
                    pool.remove(w)
        finished = not guard.stop
    finally:
        if finished:
            _close_workers(pool)
        else:
            _stop_workers(pool, records, bar, guard, started)


def _close_workers(pool):
    """End idle workers at the end of a sweep (anything still alive after 5 s is killed)."""
    for w in pool:
        try:
            w.conn.send(None)
        except (OSError, ValueError):
            pass
    for w in pool:
        w.proc.join(timeout=5.0)
        w.kill_group()


def _stop_workers(pool, records, bar, guard, started):
    """Stop every worker and the processes of its runs: SIGTERM to each worker's process group,
    SIGKILL to what is left after ``STOP_GRACE_S`` (at once on a second stop signal). A record
    a worker sent just before is kept; the pids of a stopped run's processes go to
    ``started[run id]`` (their temporary folders are removed afterwards)."""
    for w in pool:
        pg = w.pgid
        if pg is not None:
            w.stopped_pids = _group_pids(pg) or [w.proc.pid]
            _signal_group(pg, signal.SIGTERM)
        elif w.proc.is_alive():
            w.stopped_pids = [w.proc.pid]
            w.proc.terminate()
    deadline = time.monotonic() + STOP_GRACE_S
    while time.monotonic() < deadline and guard.count < 2:
        if not any(w.proc.is_alive() or (w.pgid is not None and _group_alive(w.pgid))
                   for w in pool):
            break
        time.sleep(0.05)
    for w in pool:
        rec = w.receive_last()
        w.kill_group()
        if rec is not None:
            records[rec["run_id"]] = rec
            bar.update(1)
        elif w.task is not None:
            started[w.task] = list(w.stopped_pids)


def _run_dask(run_fn, todo, runs_dir, workers, scheduler, slurm, records, bar, guard, started):
    """Dask backend: submit every run, collect results as they complete. On a stop signal the
    unfinished futures are cancelled and a cluster this sweep started is closed: SLURM jobs are
    cancelled; a local cluster's workers stop, and the processes their runs started (YADE),
    which closing the cluster would leave running, are ended after them. Runs already executing
    on an external scheduler's workers may still finish (their folders land in the cache)."""
    from dask.distributed import as_completed as dask_as_completed
    client, cluster = _dask_client(workers, scheduler, slurm)
    local_cluster = cluster is not None and not slurm
    futs = {}
    try:
        for rid, cfg in todo.items():
            if guard.stop:
                break
            fut = client.submit(execute_run, run_fn, cfg, str(runs_dir), rid, pure=False,
                                key="twin-%s-%s" % (rid, uuid.uuid4().hex[:6]))
            futs[fut.key] = (rid, fut)
        done = dask_as_completed([f for _, f in futs.values()])
        while not guard.stop and not done.is_empty():
            batch = done.next_batch(block=False)
            if not batch:
                time.sleep(0.1)
                continue
            for fut in batch:
                rid = futs[fut.key][0]
                try:
                    records[rid] = fut.result()
                except Exception as exc:   # worker lost, cancelled
                    records[rid] = {"run_id": rid, "status": "failed", "run_dir": None,
                                    "error": "dask task lost: %s: %s"
                                             % (type(exc).__name__, exc), "exec_s": None}
                bar.update(1)
    finally:
        left = [f for _, f in futs.values() if not f.done()]
        orphans = []
        if left:
            try:                       # runs handed to a worker count as started
                busy = {k for keys in client.processing().values() for k in keys}
            except Exception:
                busy = {f.key for f in left}
            for f in left:
                if f.key in busy:
                    started[futs[f.key][0]] = []
            client.cancel(left, force=True)
            if local_cluster:
                try:
                    orphans = _descendants(client.run(os.getpid).values())
                except Exception:      # a worker already gone: nothing to collect from it
                    orphans = []
        client.close()
        if cluster is not None:
            cluster.close()
        if orphans:
            _end_processes(orphans)


def make_simulator(runner=None, **sweep_kwargs):
    """A ``simulate(configs) -> DataFrame`` callable that runs configs through :func:`run_sweep`.

    The table holds, per config, the status columns, the config keys and the run summary
    (v_mean_m_s, f_col_hz, motion_mode, ...); failed runs have NaN outputs and their error.
    """
    def simulate(configs):
        return run_sweep(configs, runner=runner, **sweep_kwargs).table
    return simulate


# ------------------------------------------------------------------------------ parameter tables

def _parse_value(text):
    try:
        return ast.literal_eval(text)
    except (ValueError, SyntaxError):
        return text


def read_param_table(path):
    """Read a parameter table (CSV or yade-batch text) into a list of user config dicts.

    CSV: a header of config keys, one row per run, empty cells = default. yade-batch: the
    format of ``yade.utils.readParamsFromTable`` (whitespace-separated, ``#`` comments, ``=``
    repeats the line above, ``*`` = default, ``description`` and ``!`` columns skipped).

    Raises
    ------
    SweepInputError naming the file, line and column of a bad value or unknown key.
    """
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise SweepInputError("cannot read parameter table %s: %s" % (path, exc))
    lines = [(i + 1, l.split("#", 1)[0].rstrip()) for i, l in enumerate(text.splitlines())]
    lines = [(n, l) for n, l in lines if l.strip()]
    if not lines:
        raise SweepInputError("parameter table %s is empty" % path)
    configs = []
    if "," in lines[0][1]:
        try:
            df = pd.read_csv(path, comment="#", skipinitialspace=True, dtype=str,
                             keep_default_na=False)
        except Exception as exc:
            raise SweepInputError("parameter table %s is not valid CSV: %s" % (path, exc))
        df.columns = [c.strip() for c in df.columns]
        for i, rec in enumerate(df.to_dict("records")):
            cfg = {k: _parse_value(v.strip()) for k, v in rec.items()
                   if k != "description" and v.strip() != ""}
            configs.append((i + 2, cfg))
    else:
        header = lines[0][1].split()
        prev = None
        for n, l in lines[1:]:
            vals = l.split()
            if len(vals) != len(header):
                raise SweepInputError("%s line %d: %d values for %d columns"
                                      % (path, n, len(vals), len(header)))
            row = {}
            for h, v in zip(header, vals):
                if v == "=":
                    if prev is None:
                        raise SweepInputError("%s line %d column %s: '=' on the first line"
                                              % (path, n, h))
                    v = prev[h]
                row[h] = v
            prev = row
            cfg = {}
            for h, v in row.items():
                name = h.rstrip("!")
                if h == "description" or h.startswith("!") or v == "*":
                    continue
                cfg[name] = _parse_value(v)
            configs.append((n, cfg))
    out = []
    for n, cfg in configs:
        for k, v in cfg.items():
            if isinstance(v, float) and not math.isfinite(v):
                raise SweepInputError("%s line %d column %s: value %r is not finite"
                                      % (path, n, k, v))
        try:
            twin_config.complete_config(cfg)
        except twin_config.ConfigError as exc:
            raise SweepInputError("%s line %d: %s" % (path, n, exc))
        out.append(cfg)
    return out


def _py_literal(v):
    """A Python literal without blanks (yade-batch columns are blank-separated)."""
    if isinstance(v, bool) or v is None:
        return repr(v)
    if isinstance(v, (int, float)):
        return repr(v)
    if isinstance(v, str):
        if any(ch.isspace() for ch in v) or "#" in v:
            raise SweepInputError("value %r cannot go in a yade-batch table (blank or #)" % v)
        return repr(v)
    if isinstance(v, (list, tuple)):
        return "[" + ",".join(_py_literal(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ",".join("%s:%s" % (_py_literal(k), _py_literal(x))
                              for k, x in v.items()) + "}"
    raise SweepInputError("cannot write %r (%s) to a yade-batch table" % (v, type(v).__name__))


def write_yade_batch_table(configs, path, columns=None):
    """Write configs as a yade-batch parameter table (readParamsFromTable format).

    Parameters
    ----------
    configs : list of dict - user configs
    path : path-like - output file (written atomically)
    columns : list of str, optional - config keys to write; default every key set in any
        config (in twin_config.PARAMETERS order). Values are the completed config's, as
        Python literals; the first column ``description`` holds the run id.

    Returns
    -------
    Path
    """
    configs, ids = prepare_configs(list(configs))
    if columns is None:
        used = set().union(*[set(c) for c in configs]) if configs else set()
        order = list(twin_config.PARAMETERS) + ["effects"]
        columns = [k for k in order if k in used]
    full = [twin_config.complete_config(c) for c in configs]
    rows = [["description"] + list(columns)]
    for rid, cfg in zip(ids, full):
        rows.append([rid] + [_py_literal(cfg[k]) for k in columns])
    widths = [max(len(r[j]) for r in rows) for j in range(len(rows[0]))]
    text = YADE_TABLE_HEAD + "; description = run id\n"
    text += "\n".join("  ".join(s.ljust(w) for s, w in zip(r, widths)).rstrip()
                      for r in rows) + "\n"
    with atomic_file(path) as tmp:
        tmp.write_text(text)
    return Path(path)


# ----------------------------------------------------------------------------------------- CLI

def read_sweep_config(path):
    """Read a YAML or JSON sweep-config file into a dict."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise SweepInputError("cannot read sweep config %s: %s" % (path, exc))
    try:
        if path.suffix in (".yaml", ".yml"):
            import yaml
            data = yaml.safe_load(text)
        else:
            data = json.loads(text)
    except Exception as exc:
        raise SweepInputError("sweep config %s is not valid %s: %s"
                              % (path, path.suffix.lstrip(".").upper() or "JSON", exc))
    if not isinstance(data, dict):
        raise SweepInputError("sweep config %s must hold a mapping" % path)
    known = {"table", "configs", "backend", "workers", "scheduler", "slurm", "runs_dir",
             "retry_failed", "runner", "runner_kwargs", "base", "out"}
    unknown = sorted(set(data) - known)
    if unknown:
        raise SweepInputError("sweep config %s: unknown key(s) %s (known: %s)"
                              % (path, ", ".join(unknown), ", ".join(sorted(known))))
    return data


def parse_key_value(text):
    if "=" not in text:
        raise argparse.ArgumentTypeError("expected key=value, got %r" % text)
    k, v = text.split("=", 1)
    return k.strip(), _parse_value(v.strip())


def build_parser():
    p = argparse.ArgumentParser(prog="python -m analysis.sweep",
                                description="Run a table of twin configs in parallel (cached "
                                            "by run id;\nsee the module docstring for "
                                            "clusters).",
                                epilog="example: printf 'frequency_hz,ball_diameter_m,seed\\n"
                                       "25,0.0206,0\\n30,0.0175,0\\n' > params.csv\n"
                                       "example: python -m analysis.sweep --table params.csv "
                                       "--workers 2 --out sweep.csv",
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--table", help="parameter table: CSV or yade-batch text, one run per row")
    p.add_argument("--sweep-config", help="YAML/JSON file with any of the options below")
    p.add_argument("--workers", type=int, help="parallel workers [processes] (default 2)")
    p.add_argument("--backend", choices=BACKENDS, help="default local")
    p.add_argument("--scheduler", help="Dask scheduler address, e.g. tcp://head:8786")
    p.add_argument("--slurm", action="store_true", help="start Dask workers as SLURM jobs")
    p.add_argument("--cores", type=int,
                   help="SLURM: cores (= single-threaded workers) per job [cores]")
    p.add_argument("--memory", help="SLURM: memory per job, e.g. 16GB")
    p.add_argument("--walltime", help="SLURM: walltime per job [HH:MM:SS], e.g. 02:00:00")
    p.add_argument("--jobs", type=int, help="SLURM: number of jobs [jobs]")
    p.add_argument("--queue", help="SLURM: partition")
    p.add_argument("--account", help="SLURM: account")
    p.add_argument("--prologue", action="append", help="SLURM: shell line run before the "
                                                       "worker (repeatable)")
    p.add_argument("--runs-dir", help="parent of run folders (default results/runs)")
    p.add_argument("--retry-failed", action="store_true", help="re-run runs recorded as failed")
    p.add_argument("--runner", help="runner 'module:function' (default %s)" % DEFAULT_RUNNER)
    p.add_argument("--runner-kw", action="append", type=parse_key_value, default=[],
                   help="key=value bound to the runner (repeatable)")
    p.add_argument("--set", action="append", type=parse_key_value, default=[], dest="base",
                   help="config key=value merged into every row (repeatable; value in the "
                        "SI unit the key's name states, e.g. record_s [s])")
    p.add_argument("--export-yade-table", metavar="FILE",
                   help="write the sweep as a yade-batch table and exit without running")
    p.add_argument("--out", help="write the sweep table (status, errors, summaries) as CSV")
    p.add_argument("--no-progress", action="store_true")
    return p


#: the first line of every yade-batch table :func:`write_yade_batch_table` writes
YADE_TABLE_HEAD = "# yade-batch parameter table written by analysis.sweep"




def check_outputs(out=None, yade_table=None, inputs=()):
    """The project's file rule (:func:`analysis.atomic_dir.check_out_file`) for the sweep's
    ``--out`` table and ``--export-yade-table``, before any run: never an input (the parameter
    table, the sweep config), never an existing file that is not this command's own earlier
    output (a sweep table: its status columns first; a yade-batch table: its header line)."""
    from analysis.atomic_dir import check_out_file, own_csv, own_text
    inputs = [p for p in inputs if p]
    if out:
        check_out_file(out, inputs, is_own=own_csv(STATUS_COLUMNS, prefix=True), flag="--out")
    if yade_table:
        check_out_file(yade_table, inputs, is_own=own_text(YADE_TABLE_HEAD),
                       flag="--export-yade-table")


def _write_table(table, out):
    """Write the sweep table as CSV, atomically (a temporary file renamed onto ``out``)."""
    with atomic_file(out) as tmp:
        table.to_csv(tmp, index=False)
    return Path(out)


def main(argv=None):
    """Command line: run a parameter table; exit 0 (all ran), 1 (a run failed), 2 (bad input)
    or 128 + signal number when SIGINT / SIGTERM stopped the sweep (partial table written to
    ``--out``, one line saying how many runs finished and how to resume)."""
    args = build_parser().parse_args(argv)
    opts = {}
    try:
        opts = read_sweep_config(args.sweep_config) if args.sweep_config else {}
        table = args.table or opts.get("table")
        if table:
            configs = read_param_table(table)
        elif opts.get("configs"):
            configs = list(opts["configs"])
        else:
            raise SweepInputError("give --table (or 'table'/'configs' in the sweep config)")
        base = dict(opts.get("base") or {})
        base.update(dict(args.base))
        configs = [{**base, **c} for c in configs]
        prepare_configs(configs)
        check_outputs(args.out or opts.get("out"), args.export_yade_table,
                      inputs=[table, args.sweep_config])
        if args.export_yade_table:
            out = write_yade_batch_table(configs, args.export_yade_table)
            print("wrote %s (%d runs)" % (out, len(configs)))
            return 0
        slurm = dict(opts.get("slurm") or {})
        if args.slurm or slurm:
            for k in ("cores", "memory", "walltime", "jobs", "queue", "account", "prologue"):
                v = getattr(args, k)
                if v is not None:
                    slurm[k] = v
        runner_kwargs = dict(opts.get("runner_kwargs") or {})
        runner_kwargs.update(dict(args.runner_kw))
        res = run_sweep(configs, runner=args.runner or opts.get("runner"),
                        workers=args.workers or opts.get("workers", 2),
                        backend=args.backend or opts.get("backend", "local"),
                        runs_dir=args.runs_dir or opts.get("runs_dir"),
                        retry_failed=args.retry_failed or bool(opts.get("retry_failed")),
                        progress=not args.no_progress,
                        scheduler=args.scheduler or opts.get("scheduler"),
                        slurm=slurm or None, runner_kwargs=runner_kwargs or None)
    except (SweepInputError, twin_config.ConfigError, OutputError) as exc:
        print("analysis.sweep: error: %s" % exc, file=sys.stderr)
        return 2
    except SweepInterrupted as exc:
        out = args.out or opts.get("out")
        if out:
            out = _write_table(exc.result.table, out)
        print("analysis.sweep: %s" % exc.line(out), file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt as exc:
        return interrupted_exit("analysis.sweep", exc)
    print(res)
    for _, row in res.failed().drop_duplicates("run_id").iterrows():
        print("FAILED %s: %s" % (row["run_id"], row["error"]))
    out = args.out or opts.get("out")
    if out:
        print("wrote %s" % _write_table(res.table, out))
    return 0 if res.ok else 1


if __name__ == "__main__":
    sys.exit(main())
