"""Twin runs for a design: cached by run id, read from the committed run table, within a budget.

:class:`TwinRuns` takes a table of run configs (one row per run: a design point at a condition
and seed, :func:`analysis.history_matching.design_runs`) and returns it with ``run_id`` and the
observables every model of the twin is fitted to: the speed in both frames, f_col, the motion
mode and the impact observables of :mod:`analysis.flights`. A run is, in this order:

1. **cached** - its folder ``<runs_dir>/<run-id>/`` is complete (the sweep never reruns it);
2. **committed** - its id is in the committed run table (:data:`RUN_TABLE`, ``data/twin_runs/
   runs.csv``: real YADE runs with their configs, see ``data/twin_runs/README.md``), so a fresh
   clone reads what an earlier machine ran instead of running it again;
3. **new** - run now by the sweep (:func:`analysis.sweep.run_sweep`), counted against the
   budget *before* anything starts (:class:`BudgetError`).

``python -m analysis.twin_runs --add RUN_TABLE_CSV...`` appends the cached runs named in the
given tables (a loop's ``model_runs.csv`` / ``rerun_runs.csv``) to the committed run table.
"""
from __future__ import annotations

import argparse
import json
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from analysis.config import DATA_DIR, RUNS_DIR

#: the committed run table (real twin runs, keyed by run id)
RUN_TABLE = DATA_DIR / "twin_runs" / "runs.csv"
#: the largest share of one call's runs that may fail (each left out of the model, named in
#: the log) before the call stops with an error
MAX_FAILED_SHARE = 0.25
#: the run summaries a model of the twin reads (the impact observables are added to them)
SUMMARY_COLUMNS = ("v_mean_m_s", "v_mean_jar_m_s", "f_col_hz", "motion_mode")
#: wall time of one default twin run on one core [s] when the cache holds too few runs to
#: measure it (lab frame, measured 21 s on an idle core)
RUN_WALL_S = 21.0
#: the same in the jar frame (run config frame 'jar' / 'auto': measured 1.7-1.9x faster)
RUN_WALL_S_JAR = 12.0


class BudgetError(RuntimeError):
    """The runs asked for need more new twin runs than the budget allows (the message says
    how many)."""


def run_wall_s(base_config=None, runs_dir=None) -> float:
    """The planner's wall time per run for runs with ``base_config`` (its frame): the median
    of this machine's own latest runs in that frame (:func:`analysis.sweep.cached_wall_s`),
    else :data:`RUN_WALL_S` / :data:`RUN_WALL_S_JAR`."""
    from analysis.sweep import cached_wall_s
    jar = (base_config or {}).get("frame") in ("jar", "auto")
    measured = cached_wall_s("jar" if jar else "lab", runs_dir)
    if measured is not None:
        return measured
    return RUN_WALL_S_JAR if jar else RUN_WALL_S


def observable_columns():
    from analysis.flights import FLIGHT_OBSERVABLES
    return list(SUMMARY_COLUMNS) + list(FLIGHT_OBSERVABLES)


def committed_runs(path=None) -> pd.DataFrame:
    """The committed run table indexed by run id (empty when there is none)."""
    p = Path(path or RUN_TABLE)
    if not p.is_file():
        return pd.DataFrame(columns=observable_columns())
    t = pd.read_csv(p)
    return t.drop_duplicates("run_id", keep="last").set_index("run_id")


@dataclass
class RunPlan:
    """What a table of runs costs: runs, cached, committed, new, the estimated wall time [s]."""
    runs: int
    cached: int
    committed: int
    new: int
    est_wall_s: float

    def words(self, workers):
        return ("%d runs, %d cached, %d from the committed run table, %d new, about %.0f min "
                "on %d worker(s)" % (self.runs, self.cached, self.committed, self.new,
                                     self.est_wall_s / 60, workers))


class TwinRuns:
    """Runs tables of configs through the twin (see the module doc).

    Parameters
    ----------
    runner : callable or "module:function" or None - the sweep's runner (None: the YADE twin;
        ``analysis.fake_twin:run_fake_twin`` the FAKE analytic stand-in)
    runs_dir : the run cache (default results/runs)
    workers, backend, scheduler, slurm, progress : the sweep's
    budget_runs : most new runs over this object's life (None: no limit)
    run_table : the committed run table (default :data:`RUN_TABLE`; never read for the FAKE
        twin, whose runs are not in it)

    Attributes
    ----------
    new_runs : new runs started so far
    """

    def __init__(self, *, runner=None, runs_dir=None, workers=2, backend="local",
                 scheduler=None, slurm=None, progress=True, budget_runs=None, run_table=None,
                 base_config=None, max_failed_share=MAX_FAILED_SHARE, log=None):
        self.runner = runner
        self.runs_dir = Path(runs_dir) if runs_dir is not None else RUNS_DIR
        self.workers = int(workers)
        self.sweep_kw = dict(backend=backend, scheduler=scheduler, slurm=slurm,
                             progress=progress)
        self.budget_runs = budget_runs
        self.base_config = base_config
        self.max_failed_share = float(max_failed_share)
        self.log = log if log is not None else (lambda s: print(s, file=sys.stderr))
        #: the runs left out because they failed: run_id, error (and the design's columns)
        self.failed = pd.DataFrame(columns=["run_id", "error"])
        self.table = (pd.DataFrame(columns=observable_columns()) if runner is not None
                      else committed_runs(run_table))
        self._near_index = None
        self.new_runs = 0

    def _ids(self, runs):
        from analysis.sweep import prepare_configs
        return prepare_configs(list(runs["config"]))

    def _split(self, configs, ids):
        """(cached, committed, alias): which runs are cached here, which are in the committed
        table - exactly, or as a near run (:func:`near_run`: alias maps the id asked for to
        the committed id)."""
        from analysis.sweep import failed_path
        cached = np.array([(self.runs_dir / i / "meta.json").is_file()
                           or failed_path(self.runs_dir, i).is_file() for i in ids], bool)
        committed = np.array([i in self.table.index for i in ids], bool) & ~cached
        alias = {}
        for k, (cfg, rid) in enumerate(zip(configs, ids)):
            if not (cached[k] or committed[k]):
                hit = self._near(cfg)
                if hit is not None:
                    alias[rid] = hit
                    committed[k] = True
        return cached, committed, alias

    def _near(self, config):
        if self._near_index is None:
            self._near_index = near_index(self.table)
        return near_run(config, self._near_index)

    def plan(self, runs) -> RunPlan:
        """The cost of ``runs`` (nothing runs)."""
        configs, ids = self._ids(runs)
        cached, committed, _ = self._split(configs, ids)
        uniq_new = len({i for i, c, t in zip(ids, cached, committed) if not (c or t)})
        per = run_wall_s(self.base_config, self.runs_dir)
        return RunPlan(len(ids), int(cached.sum()), int(committed.sum()), uniq_new,
                       float(np.ceil(uniq_new / max(self.workers, 1)) * per))

    def __call__(self, runs: pd.DataFrame) -> pd.DataFrame:
        """``runs`` with run_id and the observables (see the module doc).

        A run that fails (the twin's own failure, e.g. the ball leaves the jar at a corner of
        the design; recorded in ``<run-id>.failed.json``, so a resumed loop leaves it out too)
        is left out of the returned table and kept in :attr:`failed`, with one log line -
        while at most ``max_failed_share`` of the runs asked for fail.

        Raises BudgetError before anything runs when the new runs exceed the budget left;
        RuntimeError when more runs fail than that share (or the sweep was interrupted)."""
        from analysis.sweep import run_sweep
        out = runs.reset_index(drop=True).copy()
        configs, ids = self._ids(out)
        cached, committed, alias = self._split(configs, ids)
        if alias:
            self.log("%d run(s) asked for are committed runs within a relative %g of every "
                     "value (a fitted point's last digits differ between machines): read "
                     "from the run table" % (len(alias), NEAR_REL_TOL))
        ids = [alias.get(i, i) for i in ids]
        out["run_id"] = ids
        new = sorted({i for i, c, t in zip(ids, cached, committed) if not (c or t)})
        if self.budget_runs is not None and self.new_runs + len(new) > self.budget_runs:
            raise BudgetError(
                "budget: %d new twin run(s) needed, %d of --budget-runs %d left (nothing "
                "was started; raise --budget-runs or lower --points / --waves)"
                % (len(new), self.budget_runs - self.new_runs, self.budget_runs))
        for c in observable_columns():
            out[c] = np.nan
        out["motion_mode"] = out["motion_mode"].astype(object)
        known_bad = {}
        if committed.any():
            t = self.table.reindex(out.loc[committed, "run_id"])
            for c in observable_columns():
                if c in t.columns:
                    out.loc[committed, c] = t[c].to_numpy()
            if "error" in t.columns:           # failed on the machine that made the table
                err = t["error"].dropna()
                known_bad = {str(r): str(e) for r, e in err.items()}
        run = ~committed
        bad = pd.DataFrame({"run_id": list(known_bad), "error": list(known_bad.values())})
        n_asked = len(set(out["run_id"]))
        if run.any():
            sub = out[run]
            res = run_sweep(list(sub["config"]), runner=self.runner, workers=self.workers,
                            runs_dir=self.runs_dir, **self.sweep_kw)
            self.new_runs += res.n_executed
            bad = pd.concat([bad, res.failed()[["run_id", "error"]]], ignore_index=True
                            ).drop_duplicates("run_id")
            if res.interrupted is not None:
                raise RuntimeError("the twin runs were interrupted")
            t = res.table.reset_index(drop=True)
            for c in SUMMARY_COLUMNS:
                if c in t.columns:
                    out.loc[run, c] = t[c].to_numpy()
            fl = run_flights(list(sub["run_id"]), self.runs_dir)
            for c in fl.columns[1:]:
                out.loc[run, c] = fl[c].to_numpy(float)
        if len(bad):
            if len(bad) > self.max_failed_share * n_asked:
                raise RuntimeError("%d twin run(s) failed:\n%s" % (
                    len(bad), bad[["run_id", "error"]].to_string()))
            errs = dict(zip(bad["run_id"], bad["error"].astype(str)))
            gone = out[out["run_id"].isin(errs)].drop(columns=["config"], errors="ignore")
            gone = gone[[c for c in gone.columns if c not in observable_columns()]]
            gone.insert(1, "error", gone["run_id"].map(errs))
            self.failed = pd.concat([self.failed, gone], ignore_index=True)
            self.log("%d of %d twin run(s) failed and are left out of the model: %s"
                     % (len(errs), n_asked, "; ".join(
                         "%s (%s)" % (r, e.split("run failed: ")[-1][:100]) for r, e in
                         list(errs.items())[:3]) + (" ..." if len(errs) > 3 else "")))
            out = out[~out["run_id"].isin(errs)].reset_index(drop=True)
        return out


#: a run asked for is a committed run when their configs agree in every key and every number to
#: this relative tolerance: a focus wave's points and a rerun's point come from fits whose last
#: digits differ between machines (BLAS), and 1e-4 of a parameter is far below what a twin run
#: can tell (its chaos alone moves v_mean by about 1 %)
NEAR_REL_TOL = 1e-4


def _flat(config, prefix=""):
    """{dotted key: value} of a config, nested dicts (the effects) flattened."""
    out = {}
    for k, v in config.items():
        if isinstance(v, dict):
            out.update(_flat(v, prefix + k + "."))
        else:
            out[prefix + k] = v
    return out


def _split_numbers(config):
    """(the config's discrete part as a key, {dotted key: float} of its real numbers)."""
    flat = _flat(config)
    nums = {k: float(v) for k, v in flat.items() if isinstance(v, float)}
    rest = json.dumps({k: v for k, v in flat.items() if k not in nums}, sort_keys=True)
    return rest + "|" + ",".join(sorted(nums)), nums


def near_index(table: pd.DataFrame) -> dict:
    """{discrete key: [(run_id, numbers)]} of a committed run table's configs."""
    out = {}
    if "config" not in table.columns:
        return out
    for rid, cfg in table["config"].dropna().items():
        key, nums = _split_numbers(json.loads(cfg))
        out.setdefault(key, []).append((str(rid), nums))
    return out


def near_run(config, index, rel_tol=NEAR_REL_TOL):
    """The id of the committed run (:func:`near_index`) whose complete config equals
    ``config``'s in every discrete value and within ``rel_tol`` in every number; None when
    there is none."""
    from analysis.config import twin_config
    try:
        key, nums = _split_numbers(twin_config.complete_config(dict(config)))
    except twin_config.ConfigError:
        return None
    for rid, other in index.get(key, ()):
        if all(abs(v - other[k]) <= rel_tol * max(abs(v), abs(other[k]), 1e-300)
               for k, v in nums.items()):
            return rid
    return None


def run_flights(run_ids, runs_dir=None) -> pd.DataFrame:
    """Impact observables (:mod:`analysis.flights`) of cached twin runs, one row per run id
    (NaN where the operator finds no end-to-end impacts, e.g. a run in another motion mode, or
    the run has no trajectory; a FAKE twin run's are its made-up ones,
    :func:`analysis.fake_twin.fake_flights`)."""
    from analysis.flights import FLIGHT_OBSERVABLES, FlightError, recording_flights
    from analysis.observe import ObserveError
    root = Path(runs_dir or RUNS_DIR)
    rows = []
    for rid in run_ids:
        try:
            vals = recording_flights(root / str(rid)).values
        except (FlightError, ObserveError, OSError):
            vals = _fake_flights(root / str(rid))
        rows.append({"run_id": rid, **{k: vals.get(k, np.nan) for k in FLIGHT_OBSERVABLES}})
    return pd.DataFrame(rows, columns=["run_id", *FLIGHT_OBSERVABLES])


def _fake_flights(run_dir) -> dict:
    """A FAKE twin run's made-up impact observables ({} for any other run folder)."""
    try:
        meta = json.loads((Path(run_dir) / "meta.json").read_text())
    except (OSError, ValueError):
        return {}
    if not str(meta.get("yade_version", "")).startswith("FAKE"):
        return {}
    from analysis.fake_twin import fake_flights
    return fake_flights(meta["config"])


# --------------------------------------------------------------------------- the table

def table_rows(run_ids, runs_dir=None) -> pd.DataFrame:
    """Committed-table rows of cached real runs: run_id, the config (JSON), the scene's frame,
    YADE version and wall time, and the observables; a run that failed (only its
    ``<run-id>.failed.json``) gives its config and its ``error``, no observables."""
    from analysis.sweep import failed_path
    root = Path(runs_dir or RUNS_DIR)
    fl = run_flights(run_ids, root).set_index("run_id")
    rows = []
    for rid in run_ids:
        if not (root / rid / "meta.json").is_file():
            rec = json.loads(failed_path(root, rid).read_text())
            rows.append({"run_id": rid, "config": json.dumps(rec.get("config", {}),
                                                            sort_keys=True),
                         "error": rec.get("error")})
            continue
        meta = json.loads((root / rid / "meta.json").read_text())
        if str(meta.get("yade_version", "")).startswith("FAKE"):
            raise ValueError("run %s is a FAKE twin run: the table holds real runs only" % rid)
        s = meta.get("summary", {})
        rows.append({"run_id": rid, "config": json.dumps(meta.get("config", {}),
                                                        sort_keys=True),
                     "frame": meta.get("frame", "lab"), "yade_version": meta.get("yade_version"),
                     "wall_s": meta.get("wall_s"),
                     **{c: s.get(c, np.nan) for c in SUMMARY_COLUMNS},
                     **fl.loc[rid].to_dict()})
    return pd.DataFrame(rows)


def add_to_table(run_ids, path=None, runs_dir=None) -> int:
    """Append the cached runs ``run_ids`` not yet in the committed table; returns how many."""
    from analysis.atomic_dir import atomic_file
    p = Path(path or RUN_TABLE)
    have = committed_runs(p)
    todo = sorted({str(r) for r in run_ids} - set(have.index))
    if not todo:
        return 0
    from analysis.sweep import failed_path
    root = Path(runs_dir or RUNS_DIR)
    missing = [r for r in todo if not (root / r / "meta.json").is_file()
               and not failed_path(root, r).is_file()]
    if missing:
        raise ValueError("%d run(s) are not in the cache, e.g. %s" % (len(missing), missing[0]))
    new = table_rows(todo, runs_dir)
    t = pd.concat([have.reset_index(), new], ignore_index=True) if len(have) else new
    with atomic_file(p) as tmp:
        t.to_csv(tmp, index=False, float_format="%.17g")   # exact: a refit must see the same data
    return len(new)


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m analysis.twin_runs",
                                 description="Append cached real twin runs to the committed "
                                 "run table (data/twin_runs/runs.csv).",
                                 epilog="example: python -m analysis.twin_runs --add "
                                 "results/loop/my_mill/model_runs.csv")
    ap.add_argument("--add", nargs="+", required=True, metavar="CSV",
                    help="[files] tables with a run_id column (a loop's model_runs.csv, "
                    "rerun_runs.csv; the runs its loop.json lists as failed are added too, "
                    "with their error)")
    a = ap.parse_args(argv)
    ids = []
    try:
        for f in a.add:
            ids += list(pd.read_csv(f)["run_id"].astype(str))
            info = Path(f).with_name("loop.json")
            if info.is_file():
                ids += [str(r["run_id"]) for r in
                        json.loads(info.read_text()).get("failed_runs") or []]
        n = add_to_table(ids)
    except (OSError, KeyError, ValueError, pd.errors.ParserError) as exc:
        print("analysis.twin_runs: error: %s" % exc, file=sys.stderr)
        return 2
    print("added %d run(s) to %s" % (n, RUN_TABLE.relative_to(DATA_DIR.parent)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
