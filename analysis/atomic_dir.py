"""Write a result folder completely or not at all, and only where it is ours to write.

Every stage that writes a folder goes through :func:`staging_dir` (checks the target, makes a
temporary folder beside it) and :func:`publish_dir` (marks the finished folder as written by this
project and swaps it in). The one rule (:func:`check_out_dir`): a stage replaces only a folder it
wrote itself. It refuses, before anything is written,

* the current directory, the repository, a folder holding either, or a file;
* a folder inside the repository but outside ``results/`` (sources, ``data/`` - the measurement
  datasets), ``results/`` itself and the caches ``results/runs/``, ``results/runs_fake/`` and
  ``results/track_cache/``;
* any folder given as ``protected`` (e.g. the dataset being analysed), one inside it or one
  holding it;
* a folder whose parent cannot be made or written (a file on the way, a read-only folder:
  :func:`check_parent`);
* an existing, non-empty folder that carries no mark (:data:`MARKER`) of an earlier output of
  this project - in ``results/`` too (a folder a user made there is theirs; the committed
  study folders carry the mark). A stage may name the files it writes
  (``own_names``, and say how it recognises its own earlier output, ``is_own``): then an
  unmarked folder in the repository's home of its outputs (e.g. a committed
  ``data/measurements/<name>`` written before the mark existed) is also replaced when it holds
  nothing but files of those names (and ``is_own`` says it is the stage's).

A stage that writes one FILE (a movie, say) follows the same rule through
:func:`check_out_file`: the same places are refused, and an existing file is replaced only when
the stage recognises it as its own earlier output (the stage says how, e.g. from a sidecar it
wrote beside the file holding the file's hash, or from the table's header: :func:`own_csv`).

:func:`output_dir` joins the two: ``with output_dir(out, protected) as tmp:`` writes into
``tmp`` and publishes it when the block ends, or removes it on an error.

Every single file a stage writes goes through :func:`atomic_file`: written under a temporary
name beside its target and renamed over it only when complete, so a reader never sees half a
file and a failure leaves the old one.
"""
import os
import shutil
import tempfile
from contextlib import contextmanager
from pathlib import Path

#: file put in every published folder: "this project wrote this folder; it may replace it"
MARKER = ".mill-twin-output"


class OutputError(ValueError):
    """An output folder this project must not write (the message says why)."""


def _repo_paths():
    from analysis.config import REPO_ROOT, RESULTS_DIR
    return Path(REPO_ROOT).resolve(), Path(RESULTS_DIR).resolve()


def _caches():
    """{folder: words} of the caches no output may replace: the twin's run cache, the FAKE
    twin's and the tracks of datasets' films."""
    from analysis.config import FAKE_RUNS_DIR, RUNS_DIR, TRACK_CACHE_DIR
    return {Path(RUNS_DIR).resolve(): "the twin's run cache results/runs/",
            Path(FAKE_RUNS_DIR).resolve(): "the FAKE twin's run cache results/runs_fake/",
            Path(TRACK_CACHE_DIR).resolve(): "the films' track cache results/track_cache/"}


def _within(a: Path, b: Path) -> bool:
    """a is b or lies inside b."""
    return a == b or b in a.parents


def _only_own_files(folder: Path, own_names) -> bool:
    """``folder`` holds nothing but plain files named in ``own_names``."""
    names = set(own_names)
    return all(p.is_file() and not p.is_symlink() and p.name in names for p in folder.iterdir())


def _writable(folder: Path) -> bool:
    """This process may make entries in the existing folder ``folder``."""
    return os.access(folder, os.W_OK | os.X_OK)


def check_parent(out, flag="--out", shown=None):
    """Raise :class:`OutputError` unless ``out``'s parent can be made and written: the nearest
    existing ancestor must be a folder (not a file) this process may write in (not read-only).
    Nothing is created."""
    out = Path(out)
    shown = out if shown is None else shown
    anc = out.parent
    while not (anc.exists() or anc.is_symlink()) and anc != anc.parent:
        anc = anc.parent
    if not anc.is_dir():
        raise OutputError("%s %s: %s is a file, not a folder; give a path in a folder"
                          % (flag, shown, anc))
    if not _writable(anc):
        raise OutputError("%s %s: cannot write in %s (read-only or not yours); give a "
                          "writable place" % (flag, shown, anc))


def own_csv(columns, prefix=False):
    """An ``is_own`` test for :func:`check_out_file`: the existing file is a CSV whose header is
    exactly ``columns`` (or, with ``prefix``, starts with them) - the table a stage writes, never
    a track or summary it reads."""
    want = list(columns)

    def is_own(path) -> bool:
        try:
            with open(path, encoding="utf-8", errors="replace") as fh:
                head = fh.readline().strip().split(",")
        except OSError:
            return False
        return head[:len(want)] == want if prefix else head == want
    return is_own


def own_text(first_line):
    """An ``is_own`` test for :func:`check_out_file`: the existing file's first line starts
    with ``first_line`` (a page's title, a table's header line the stage writes)."""
    def is_own(path) -> bool:
        try:
            with open(path, encoding="utf-8", errors="replace") as fh:
                return fh.readline().startswith(first_line)
        except OSError:
            return False
    return is_own


def check_out_dir(out_dir, protected=(), area="results", flag="--out", own_names=None,
                  is_own=None):
    """Raise :class:`OutputError` when ``out_dir`` is not a folder this project may (re)write.

    Parameters
    ----------
    out_dir : path-like - the folder a stage is about to write or replace
    protected : iterable of path-like - folders that must stay untouched (inputs)
    area : {'results', 'datasets'} - where in the repository this kind of output lives:
        ``results/<name>`` or, for a written measurement dataset, also ``data/measurements/<name>``
        (an existing dataset folder is replaced only when it carries the mark)
    flag : str - the command-line option that named the folder, for the messages
    own_names : iterable of str, optional - the file names the stage writes into the folder; an
        unmarked folder inside the repository's home of this area (``results/<name>``,
        ``data/measurements/<name>``) holding only plain files of these names is taken as the
        stage's own earlier output (a folder outside the repository still needs the mark)
    is_own : callable, optional - ``is_own(resolved_folder) -> bool``, with ``own_names``: the
        unmarked folder is taken as the stage's own only when this also says so (e.g. from what
        a file in it records about its writer)

    Returns
    -------
    Path - ``out_dir`` resolved
    """
    out = Path(out_dir).expanduser().resolve()
    repo, results = _repo_paths()
    cwd = Path.cwd().resolve()
    if _within(cwd, out):
        raise OutputError("%s %s is the current directory or holds it; give a new folder, "
                          "e.g. results/<name>" % (flag, out_dir))
    if _within(repo, out):
        raise OutputError("%s %s is the repository or holds it; give a new folder, e.g. "
                          "results/<name>" % (flag, out_dir))
    if area == "datasets":
        from analysis.config import MEASUREMENTS_DIR
        homes = [Path(MEASUREMENTS_DIR).resolve(), results]
    elif area == "results":
        homes = [results]
    else:
        raise ValueError("area must be 'results' or 'datasets', got %r" % (area,))
    if _within(out, repo) and not any(_within(out, h) and out != h for h in homes):
        where = " or ".join("%s/<name>" % h.relative_to(repo) for h in homes)
        raise OutputError("%s %s lies in the repository outside %s; give %s or a folder "
                          "outside the repository" % (flag, out_dir, where, where))
    for cache, words in _caches().items():
        if _within(out, cache) or _within(cache, out):
            raise OutputError("%s %s is (or holds) %s" % (flag, out_dir, words))
    for p in protected or ():
        if p is None:
            continue
        p = Path(p).expanduser().resolve()
        if _within(out, p) or _within(p, out):
            raise OutputError("%s %s is, holds or lies inside an input (%s): outputs never "
                              "replace what was read" % (flag, out_dir, p))
    check_parent(out, flag, out_dir)
    if out.exists():
        if not out.is_dir():
            raise OutputError("%s %s is a file, not a folder" % (flag, out_dir))
        at_home = any(_within(out, h) for h in homes)
        if (any(out.iterdir()) and not (out / MARKER).exists()
                and not (own_names is not None and at_home and _only_own_files(out, own_names)
                         and (is_own is None or is_own(out)))):
            raise OutputError("%s %s already holds files this project did not write; give "
                              "a new or empty folder" % (flag, out_dir))
    return out


def staging_dir(out_dir, protected=(), area="results", flag="--out", own_names=None,
                is_own=None):
    """A fresh temporary folder beside ``out_dir`` (same file system, so the swap is a rename),
    after :func:`check_out_dir` has accepted ``out_dir``."""
    out_dir = Path(out_dir)
    check_out_dir(out_dir, protected, area, flag, own_names, is_own)
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=".%s.tmp-" % out_dir.name, dir=out_dir.parent))
    mask = os.umask(0)
    os.umask(mask)
    tmp.chmod(0o777 & ~mask)        # a folder's usual mode, not mkdtemp's private 0700
    return tmp


def publish_dir(tmp, out_dir, protected=(), area="results", flag="--out", own_names=None,
                is_own=None):
    """Mark the finished folder ``tmp`` and move it onto ``out_dir``, replacing an earlier output.

    The old folder is renamed away first, so ``out_dir`` never holds a mix of old and new files.
    ``out_dir`` is checked again (:func:`check_out_dir`); on refusal ``tmp`` is removed.
    """
    tmp, out_dir = Path(tmp), Path(out_dir)
    try:
        check_out_dir(out_dir, protected, area, flag, own_names, is_own)
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


def check_out_file(out_file, protected=(), is_own=None, flag="--out", homes=()):
    """Raise :class:`OutputError` when ``out_file`` is not a file this project may (re)write.

    The places refused are those of :func:`check_out_dir`: a path inside the repository outside
    ``results/``, the run cache ``results/runs/``, a protected input (a file, or anything inside
    a protected folder); besides, a path that is a folder, and an existing file unless
    ``is_own(path)`` says the same stage wrote it earlier.

    Parameters
    ----------
    out_file : path-like - the file a stage is about to write or replace
    protected : iterable of path-like - inputs that must stay untouched (files or folders)
    is_own : callable, optional - ``is_own(resolved_path) -> bool``: True when the existing file
        is the stage's own earlier output (without it, no existing file is replaced)
    flag : str - the command-line option that named the file, for the messages
    homes : iterable of path-like - further folders of the repository where this stage's file
        belongs (e.g. ``geometry/`` for the jar's STL): a path in one of them is taken like one
        in ``results/`` (an existing file there is still replaced only when ``is_own``)

    Returns
    -------
    Path - ``out_file`` resolved
    """
    out = Path(out_file).expanduser().resolve()
    repo, results = _repo_paths()
    if out.is_dir():
        raise OutputError("%s %s is a folder; give a file name" % (flag, out_file))
    homes = [results] + [Path(h).expanduser().resolve() for h in homes or ()]
    if _within(out, repo) and not any(_within(out.parent, h) for h in homes):
        raise OutputError("%s %s lies in the repository outside results/; give results/<name> "
                          "or a path outside the repository" % (flag, out_file))
    for cache, words in _caches().items():
        if _within(out, cache):
            raise OutputError("%s %s lies in %s" % (flag, out_file, words))
    for p in protected or ():
        if p is None:
            continue
        p = Path(p).expanduser().resolve()
        if _within(out, p):
            raise OutputError("%s %s is or lies inside an input (%s): outputs never replace "
                              "what was read" % (flag, out_file, p))
    check_parent(out, flag, out_file)
    if (out.exists() or out.is_symlink()) and not (is_own is not None and is_own(out)):
        raise OutputError("%s %s already exists and is not an earlier output of this command; "
                          "give a new file name" % (flag, out_file))
    return out


@contextmanager
def atomic_file(path):
    """``with atomic_file(path) as tmp:`` write to ``tmp`` (a fresh name beside ``path`` with
    the same suffix, so writers that pick a format from it still do); when the block ends
    without an error ``tmp`` is renamed over ``path``, otherwise it is removed and ``path`` is
    left as it was. The parent folder is made when missing."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, name = tempfile.mkstemp(prefix=".%s.tmp-" % path.stem, suffix=path.suffix,
                                dir=path.parent)
    os.close(fd)
    tmp = Path(name)
    try:
        yield tmp
        if tmp.exists():                    # a plain file's mode, not mkstemp's 0600
            umask = os.umask(0)
            os.umask(umask)
            os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


@contextmanager
def output_dir(out_dir, protected=(), area="results", flag="--out", own_names=None,
               is_own=None):
    """``with output_dir(out, protected) as tmp:`` - :func:`staging_dir`, the block writes into
    ``tmp``, then :func:`publish_dir`; on any error ``tmp`` is removed and ``out_dir`` is left as
    it was."""
    kw = dict(area=area, flag=flag, own_names=own_names, is_own=is_own)
    tmp = staging_dir(out_dir, protected, **kw)
    try:
        yield tmp
        publish_dir(tmp, out_dir, protected, **kw)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
