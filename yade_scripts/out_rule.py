"""The project's output rule for the YADE scene: replace only a folder this project wrote.

Standard library only: the scene (``mill.py``) runs under YADE's own Python and cannot import
``analysis/``. This is the same rule as ``analysis.atomic_dir.check_out_dir`` (which the venv's
stages use), for the one folder a twin run writes. :func:`check_run_out` refuses, before any
simulation,

* the current directory, the repository, or a folder holding either; a path that is a file;
* a folder inside the repository but outside ``results/`` (sources, ``data/``), ``results/``
  itself and the run cache ``results/runs/`` itself (its run folders are the scene's to write);
* an input of the run (the config file, the jar's STL), a folder inside one or holding one;
* an existing, non-empty folder that neither carries the project's mark (:data:`MARKER`) nor
  holds only the files of a recording this scene wrote (``meta.json``, ``trajectory.csv``,
  ``impacts.csv``, with a ``meta.json`` that is the scene's own: :func:`is_scene_recording`).
"""
import json
import os

#: file put in every folder the project publishes ("this project wrote this folder")
MARKER = ".mill-twin-output"
#: the files of one recording (docs/reference.md, "Recording")
RECORDING_FILES = ("meta.json", "trajectory.csv", "impacts.csv")
#: keys every meta.json the scene writes holds
SCENE_META_KEYS = ("config", "run_id", "yade_version", "summary", "steps", "dt_s")


class OutRefused(ValueError):
    """An output folder the scene must not write (the message says why)."""


def _within(a, b):
    """a is b or lies inside b (both real, absolute paths)."""
    return a == b or a.startswith(b.rstrip(os.sep) + os.sep)


def is_scene_recording(folder):
    """``folder`` holds nothing but a recording's files and its meta.json is one the scene
    wrote (a JSON object with the scene's keys)."""
    try:
        names = os.listdir(folder)
    except OSError:
        return False
    if "meta.json" not in names:
        return False
    for n in names:
        p = os.path.join(folder, n)
        if n not in RECORDING_FILES or os.path.islink(p) or not os.path.isfile(p):
            return False
    try:
        with open(os.path.join(folder, "meta.json")) as fh:
            meta = json.load(fh)
    except (OSError, ValueError):
        return False
    return isinstance(meta, dict) and all(k in meta for k in SCENE_META_KEYS)


def may_replace(folder):
    """An existing folder the scene may replace: empty, marked, or its own recording."""
    try:
        names = os.listdir(folder)
    except OSError:
        return False
    return not names or MARKER in names or is_scene_recording(folder)


def check_run_out(out_dir, repo_root, inputs=(), flag="--out"):
    """Raise :class:`OutRefused` when ``out_dir`` is not a folder the scene may (re)write.

    Parameters
    ----------
    out_dir : str - the run folder about to be written or replaced
    repo_root : str - the repository (its ``results/`` is the home of outputs)
    inputs : iterable of str - files the run reads (config, STL): never replaced or held
    flag : str - the option that named the folder, for the messages

    Returns
    -------
    str - ``out_dir`` resolved
    """
    out = os.path.realpath(os.path.expanduser(out_dir))
    repo = os.path.realpath(repo_root)
    results = os.path.join(repo, "results")
    runs = os.path.join(results, "runs")
    cwd = os.path.realpath(os.getcwd())
    if _within(cwd, out):
        raise OutRefused("%s %s is the current directory or holds it; give a new folder, e.g. "
                         "results/runs/<run-id>" % (flag, out_dir))
    if _within(repo, out):
        raise OutRefused("%s %s is the repository or holds it; give a new folder, e.g. "
                         "results/runs/<run-id>" % (flag, out_dir))
    if out == results:
        raise OutRefused("%s %s is results/ itself; give results/runs/<run-id> or "
                         "results/<name>" % (flag, out_dir))
    if _within(out, repo) and not _within(out, results):
        raise OutRefused("%s %s lies in the repository outside results/; give "
                         "results/<name> or a folder outside the repository" % (flag, out_dir))
    if out == runs:
        raise OutRefused("%s %s is the twin's run cache results/runs/ itself; give "
                         "results/runs/<run-id>" % (flag, out_dir))
    for p in inputs or ():
        if not p:
            continue
        p = os.path.realpath(os.path.expanduser(p))
        if _within(out, p) or _within(p, out):
            raise OutRefused("%s %s is, holds or lies inside an input of the run (%s): outputs "
                             "never replace what was read" % (flag, out_dir, p))
    if os.path.lexists(out):
        if not os.path.isdir(out):
            raise OutRefused("%s %s is a file, not a folder" % (flag, out_dir))
        if not may_replace(out):
            raise OutRefused("%s %s already holds files this project did not write (no %s "
                             "mark, not a recording of this scene); give a new or empty folder"
                             % (flag, out_dir, MARKER))
    return out


def check_out_file(out_file, repo_root, inputs=(), is_own=None, flag="--out"):
    """Raise :class:`OutRefused` when ``out_file`` is not a file the scene's tools may (re)write
    (``analysis.atomic_dir.check_out_file``'s rule): a folder, a path in the repository outside
    ``results/``, an input, a path under a file, an existing file unless ``is_own(path)``.

    Returns
    -------
    str - ``out_file`` resolved
    """
    out = os.path.realpath(os.path.expanduser(out_file))
    repo = os.path.realpath(repo_root)
    if os.path.isdir(out):
        raise OutRefused("%s %s is a folder; give a file name" % (flag, out_file))
    if _within(out, repo) and not _within(os.path.dirname(out), os.path.join(repo, "results")):
        raise OutRefused("%s %s lies in the repository outside results/; give results/<name> "
                         "or a path outside the repository" % (flag, out_file))
    for p in inputs or ():
        if p and _within(out, os.path.realpath(os.path.expanduser(p))):
            raise OutRefused("%s %s is an input: outputs never replace what was read"
                             % (flag, out_file))
    anc = os.path.dirname(out)
    while not os.path.lexists(anc) and os.path.dirname(anc) != anc:
        anc = os.path.dirname(anc)
    if not os.path.isdir(anc):
        raise OutRefused("%s %s: %s is a file, not a folder" % (flag, out_file, anc))
    if os.path.lexists(out) and not (is_own is not None and is_own(out)):
        raise OutRefused("%s %s already exists and is not an earlier output of this command; "
                         "give a new file name" % (flag, out_file))
    return out


def write_atomic(path, text):
    """Write ``text`` to a temporary file beside ``path`` and rename it over ``path``."""
    parent = os.path.dirname(os.path.abspath(path))
    os.makedirs(parent, exist_ok=True)
    tmp = os.path.join(parent, ".%s.tmp-%d" % (os.path.basename(path), os.getpid()))
    try:
        with open(tmp, "w") as fh:
            fh.write(text)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
