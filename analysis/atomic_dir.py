"""Write a result folder completely or not at all, and only where it is ours to write.

Every stage that writes a folder goes through :func:`staging_dir` (checks the target, makes a
temporary folder beside it) and :func:`publish_dir` (marks the finished folder as written by this
project and swaps it in). The one rule (:func:`check_out_dir`): a stage replaces only a folder it
wrote itself. It refuses, before anything is written,

* the current directory, the repository, a folder holding either, or a file;
* a folder inside the repository but outside ``results/`` (sources, ``data/`` - the measurement
  datasets), ``results/`` itself and the run cache ``results/runs/``;
* any folder given as ``protected`` (e.g. the dataset being analysed), one inside it or one
  holding it;
* an existing, non-empty folder that carries no mark (:data:`MARKER`) of an earlier output of
  this project and does not sit in ``results/``.
"""
import os
import shutil
import tempfile
from pathlib import Path

#: file put in every published folder: "this project wrote this folder; it may replace it"
MARKER = ".mill-twin-output"


class OutputError(ValueError):
    """An output folder this project must not write (the message says why)."""


def _repo_paths():
    from analysis.config import REPO_ROOT, RESULTS_DIR, RUNS_DIR
    return Path(REPO_ROOT).resolve(), Path(RESULTS_DIR).resolve(), Path(RUNS_DIR).resolve()


def _within(a: Path, b: Path) -> bool:
    """a is b or lies inside b."""
    return a == b or b in a.parents


def check_out_dir(out_dir, protected=(), area="results"):
    """Raise :class:`OutputError` when ``out_dir`` is not a folder this project may (re)write.

    Parameters
    ----------
    out_dir : path-like - the folder a stage is about to write or replace
    protected : iterable of path-like - folders that must stay untouched (inputs)
    area : {'results', 'datasets'} - where in the repository this kind of output lives:
        ``results/<name>`` or, for a written measurement dataset, also ``data/measurements/<name>``
        (an existing dataset folder is replaced only when it carries the mark)

    Returns
    -------
    Path - ``out_dir`` resolved
    """
    out = Path(out_dir).expanduser().resolve()
    repo, results, runs = _repo_paths()
    cwd = Path.cwd().resolve()
    if _within(cwd, out):
        raise OutputError("--out %s is the current directory or holds it; give a new folder, "
                          "e.g. results/<name>" % out_dir)
    if _within(repo, out):
        raise OutputError("--out %s is the repository or holds it; give a new folder, e.g. "
                          "results/<name>" % out_dir)
    if area == "datasets":
        from analysis.config import MEASUREMENTS_DIR
        homes = [Path(MEASUREMENTS_DIR).resolve(), results]
    elif area == "results":
        homes = [results]
    else:
        raise ValueError("area must be 'results' or 'datasets', got %r" % (area,))
    if _within(out, repo) and not any(_within(out, h) and out != h for h in homes):
        where = " or ".join("%s/<name>" % h.relative_to(repo) for h in homes)
        raise OutputError("--out %s lies in the repository outside %s; give %s or a folder "
                          "outside the repository" % (out_dir, where, where))
    if _within(out, runs) or _within(runs, out):
        raise OutputError("--out %s is (or holds) the twin's run cache results/runs/" % out_dir)
    for p in protected or ():
        if p is None:
            continue
        p = Path(p).expanduser().resolve()
        if _within(out, p) or _within(p, out):
            raise OutputError("--out %s is, holds or lies inside an input (%s): outputs never "
                              "replace what was read" % (out_dir, p))
    if out.exists():
        if not out.is_dir():
            raise OutputError("--out %s is a file, not a folder" % out_dir)
        if (any(out.iterdir()) and not (out / MARKER).exists()
                and not (area == "results" and _within(out, results))):
            raise OutputError("--out %s already holds files this project did not write; give "
                              "a new or empty folder" % out_dir)
    return out


def staging_dir(out_dir, protected=(), area="results"):
    """A fresh temporary folder beside ``out_dir`` (same file system, so the swap is a rename),
    after :func:`check_out_dir` has accepted ``out_dir``."""
    out_dir = Path(out_dir)
    check_out_dir(out_dir, protected, area)
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    return Path(tempfile.mkdtemp(prefix=".%s.tmp-" % out_dir.name, dir=out_dir.parent))


def publish_dir(tmp, out_dir, protected=(), area="results"):
    """Mark the finished folder ``tmp`` and move it onto ``out_dir``, replacing an earlier output.

    The old folder is renamed away first, so ``out_dir`` never holds a mix of old and new files.
    ``out_dir`` is checked again (:func:`check_out_dir`); on refusal ``tmp`` is removed.
    """
    tmp, out_dir = Path(tmp), Path(out_dir)
    try:
        check_out_dir(out_dir, protected, area)
    except OutputError:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    (tmp / MARKER).write_text("written by the mill twin project; a rerun may replace this "
                              "folder\n")
    if out_dir.exists():
        old = Path(tempfile.mkdtemp(prefix=".%s.old-" % out_dir.name, dir=out_dir.parent))
        os.replace(out_dir, old / out_dir.name)
        os.replace(tmp, out_dir)
        shutil.rmtree(old)
    else:
        os.replace(tmp, out_dir)
    return out_dir
