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
  (``--retry-failed``). A worker process that dies (segfault, out of memory) leaves its runs
  ``failed`` in the table but writes no ``.failed.json``: the next sweep tries them again.
* Equal configs (same run id) in one sweep are run once.

Backends (chosen by configuration alone)
----------------------------------------
``local``   concurrent.futures.ProcessPoolExecutor with ``workers`` processes (default).
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
import datetime
import functools
import importlib
import json
import math
import os
import socket
import sys
import time
import traceback
import uuid
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from analysis.config import RUNS_DIR, twin_config

BACKENDS = ("local", "serial", "dask")
DEFAULT_RUNNER = "analysis.twin:run_twin"
#: columns of the sweep table before the config and summary columns
STATUS_COLUMNS = ("run_id", "status", "error", "run_dir", "exec_s")


class SweepInputError(ValueError):
    """A parameter table, sweep config or runner spec is malformed."""


@dataclass
class SweepResult:
    """Outcome of :func:`run_sweep`.

    Attributes
    ----------
    table : DataFrame, shape (n_configs, ...) - one row per input config, in input order:
        run_id, status ('done' computed now, 'cached' found complete, 'failed' failed now,
        'failed_cached' failed before and not retried), error, run_dir, exec_s [s], the configs'
        own keys, and the run summaries (v_mean_m_s, f_col_hz, ... from meta.json).
    wall_s : float - wall time of the sweep [s]
    """
    table: pd.DataFrame
    wall_s: float
    backend: str = "local"
    workers: int = 1
    counts: dict = field(default_factory=dict)

    @property
    def n_executed(self):
        """Runs really started by this sweep (done + failed now)."""
        return int(self.table.drop_duplicates("run_id")["status"].isin(["done", "failed"]).sum())

    @property
    def n_failed(self):
        return int(self.table.drop_duplicates("run_id")["status"]
                   .isin(["failed", "failed_cached"]).sum())

    @property
    def ok(self):
        """True when no run failed."""
        return self.n_failed == 0

    def failed(self):
        """Rows of the failed runs (with their errors)."""
        return self.table[self.table["status"].str.startswith("failed")]

    def to_frame(self):
        return self.table.copy()

    def __str__(self):
        c = self.table.drop_duplicates("run_id")["status"].value_counts().to_dict()
        return ("sweep: %d configs, %d unique runs (%s) in %.1f s on %s x%d"
                % (len(self.table), self.table["run_id"].nunique(),
                   ", ".join("%s %d" % kv for kv in sorted(c.items())), self.wall_s,
                   self.backend, self.workers))


# ----------------------------------------------------------------------------------------- runs

def failed_path(runs_dir, rid):
    """Path of the failure record of run ``rid``."""
    return Path(runs_dir) / ("%s.failed.json" % rid)


def _json_default(o):
    if hasattr(o, "item"):
        return o.item()
    return str(o)


def _atomic_write_json(path, obj):
    path = Path(path)
    tmp = path.with_name(".%s.%s.tmp" % (path.name, uuid.uuid4().hex[:8]))
    with open(tmp, "w") as fh:
        json.dump(obj, fh, indent=1, default=_json_default)
    os.replace(tmp, path)


def execute_run(runner, config, runs_dir, rid):
    """Run one config and return a status record; never raises for a failing run.

    A failure is also written to ``<runs_dir>/<rid>.failed.json`` (atomically) so it survives
    a killed sweep. Module-level so process pools and Dask can ship it to workers.
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

    if todo:
        run_fn = resolve_runner(runner, runner_kwargs)
        bar = tqdm(total=len(todo), desc="twin runs", unit="run", disable=not progress,
                   file=sys.stderr)
        try:
            if backend == "serial":
                for rid, cfg in todo.items():
                    records[rid] = execute_run(run_fn, cfg, runs_dir, rid)
                    bar.update(1)
            elif backend == "local":
                _run_local(run_fn, todo, runs_dir, workers, records, bar)
            else:
                _run_dask(run_fn, todo, runs_dir, workers, scheduler, slurm, records, bar)
        finally:
            bar.close()

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
    table = pd.DataFrame(rows)
    return SweepResult(table=table, wall_s=time.time() - t0, backend=backend, workers=workers)


def _run_local(run_fn, todo, runs_dir, workers, records, bar):
    with ProcessPoolExecutor(max_workers=workers) as pool:
        futs = {pool.submit(execute_run, run_fn, cfg, runs_dir, rid): rid
                for rid, cfg in todo.items()}
        try:
            for fut in as_completed(futs):
                rid = futs[fut]
                try:
                    records[rid] = fut.result()
                except BrokenProcessPool as exc:
                    # worker died (signal, OOM): no .failed.json, the next sweep retries
                    records[rid] = {"run_id": rid, "status": "failed", "run_dir": None,
                                    "error": "worker process died: %s" % exc, "exec_s": None}
                bar.update(1)
        except KeyboardInterrupt:
            for f in futs:
                f.cancel()
            raise


def _run_dask(run_fn, todo, runs_dir, workers, scheduler, slurm, records, bar):
    from dask.distributed import as_completed as dask_as_completed
    client, cluster = _dask_client(workers, scheduler, slurm)
    try:
        futs = {}
        for rid, cfg in todo.items():
            fut = client.submit(execute_run, run_fn, cfg, str(runs_dir), rid, pure=False,
                                key="twin-%s-%s" % (rid, uuid.uuid4().hex[:6]))
            futs[fut.key] = (rid, fut)
        for fut in dask_as_completed([f for _, f in futs.values()]):
            rid = futs[fut.key][0]
            try:
                records[rid] = fut.result()
            except Exception as exc:   # worker lost, cancelled
                records[rid] = {"run_id": rid, "status": "failed", "run_dir": None,
                                "error": "dask task lost: %s: %s" % (type(exc).__name__, exc),
                                "exec_s": None}
            bar.update(1)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


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
    text = "# yade-batch parameter table written by analysis.sweep; description = run id\n"
    text += "\n".join("  ".join(s.ljust(w) for s, w in zip(r, widths)).rstrip()
                      for r in rows) + "\n"
    path = Path(path)
    tmp = path.with_name(".%s.%s.tmp" % (path.name, uuid.uuid4().hex[:8]))
    tmp.write_text(text)
    os.replace(tmp, path)
    return path


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


def _kv(text):
    if "=" not in text:
        raise argparse.ArgumentTypeError("expected key=value, got %r" % text)
    k, v = text.split("=", 1)
    return k.strip(), _parse_value(v.strip())


def build_parser():
    p = argparse.ArgumentParser(prog="python -m analysis.sweep",
                                description="Run a table of twin configs in parallel (cached "
                                            "by run id; see the module docstring for clusters).")
    p.add_argument("--table", help="parameter table: CSV or yade-batch text, one run per row")
    p.add_argument("--sweep-config", help="YAML/JSON file with any of the options below")
    p.add_argument("--workers", type=int, help="parallel workers (default 2)")
    p.add_argument("--backend", choices=BACKENDS, help="default local")
    p.add_argument("--scheduler", help="Dask scheduler address, e.g. tcp://head:8786")
    p.add_argument("--slurm", action="store_true", help="start Dask workers as SLURM jobs")
    p.add_argument("--cores", type=int, help="SLURM: cores (= single-threaded workers) per job")
    p.add_argument("--memory", help="SLURM: memory per job, e.g. 16GB")
    p.add_argument("--walltime", help="SLURM: walltime per job, e.g. 02:00:00")
    p.add_argument("--jobs", type=int, help="SLURM: number of jobs")
    p.add_argument("--queue", help="SLURM: partition")
    p.add_argument("--account", help="SLURM: account")
    p.add_argument("--prologue", action="append", help="SLURM: shell line run before the "
                                                       "worker (repeatable)")
    p.add_argument("--runs-dir", help="parent of run folders (default results/runs)")
    p.add_argument("--retry-failed", action="store_true", help="re-run runs recorded as failed")
    p.add_argument("--runner", help="runner 'module:function' (default %s)" % DEFAULT_RUNNER)
    p.add_argument("--runner-kw", action="append", type=_kv, default=[],
                   help="key=value bound to the runner (repeatable)")
    p.add_argument("--set", action="append", type=_kv, default=[], dest="base",
                   help="config key=value merged into every row (repeatable)")
    p.add_argument("--export-yade-table", metavar="FILE",
                   help="write the sweep as a yade-batch table and exit without running")
    p.add_argument("--out", help="write the sweep table (status, errors, summaries) as CSV")
    p.add_argument("--no-progress", action="store_true")
    return p


def main(argv=None):
    args = build_parser().parse_args(argv)
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
    except (SweepInputError, twin_config.ConfigError) as exc:
        print("analysis.sweep: error: %s" % exc, file=sys.stderr)
        return 2
    print(res)
    for _, row in res.failed().drop_duplicates("run_id").iterrows():
        print("FAILED %s: %s" % (row["run_id"], row["error"]))
    out = args.out or opts.get("out")
    if out:
        out = Path(out)
        out.parent.mkdir(parents=True, exist_ok=True)
        tmp = out.with_name(".%s.tmp" % out.name)
        res.table.to_csv(tmp, index=False)
        os.replace(tmp, out)
        print("wrote %s" % out)
    return 0 if res.ok else 1


if __name__ == "__main__":
    sys.exit(main())
