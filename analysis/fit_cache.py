"""Fitted Gaussian-process hyperparameters, remembered by what they were fitted to.

A loop run again on the same twin runs (from the run cache or the committed run table) refits
its emulators on exactly the same training data with the same seeds; the hyperparameter
optimiser's restarts are about half of such a loop's time on Table 3 (a tenth at six
conditions, where the bootstrap draws take most). The cache keeps each fit's optimised
hyperparameters under a hash of everything the optimiser saw - the kernel with its bounds, the
training inputs and targets, the per-run noise, the optimiser's restarts and seed, and
scikit-learn's version - and a fit that finds its key refits with them held (one Cholesky
factorisation instead of an optimisation): the same model, bit for bit.

One small JSON file per fit, ``<runs dir>/emulator_fits/<key>.json`` beside the twin runs the
fits came from; the loop also reads the committed ones of ``make demo``'s loops
(:data:`COMMITTED_FITS`), so that a fresh clone's demo replays them. A file that does not parse
or does not fit the kernel is a miss (the fit optimises and writes it again); deleting the
folder costs only time.
"""
from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import tempfile
from pathlib import Path

import numpy as np
import scipy.optimize
import sklearn
from sklearn.base import clone

from analysis.atomic_dir import OutputError, atomic_file
from analysis.config import DATA_DIR

#: the cache's folder inside a twin-runs folder
FOLDER = "emulator_fits"
#: the bootstrap draws' outcomes of the loop's diagnosis steps, beside it
#: (:func:`analysis.loop.null_scale`)
DRAWS_FOLDER = "bootstrap_draws"
#: the source whose change makes every cached bootstrap outcome a miss
SOURCE_DIRS = ("analysis", "effects", "geometry", "yade_scripts")
_ROOT = Path(__file__).resolve().parents[1]
#: the committed fits of make demo's loops (read only; data/twin_runs/README.md)
COMMITTED_FITS = DATA_DIR / "twin_runs" / FOLDER


def hyperparameters(kernel) -> dict:
    """{name: value} of a kernel's free hyperparameters, in its own (not log) units."""
    params = kernel.get_params()
    return {h.name: np.asarray(params[h.name], float).tolist() for h in kernel.hyperparameters
            if not h.fixed}


def with_hyperparameters(kernel, values: dict):
    """A copy of ``kernel`` with the hyperparameters ``values`` (from :func:`hyperparameters`)."""
    names = {h.name for h in kernel.hyperparameters if not h.fixed}
    if set(values) != names:
        raise ValueError("cached hyperparameters %s do not match the kernel's %s"
                         % (sorted(values), sorted(names)))
    return clone(kernel).set_params(
        **{k: (np.asarray(v, float) if np.ndim(v) else float(v)) for k, v in values.items()})


def kernels_with(kernel, found, n: int) -> list | None:
    """``n`` copies of ``kernel``, each with the hyperparameters of one entry of ``found`` (a
    list of :func:`hyperparameters`), or None when they do not fit it."""
    if not isinstance(found, list) or len(found) != n:
        return None
    try:
        return [with_hyperparameters(kernel, v) for v in found]
    except (ValueError, TypeError):
        return None


class Search:
    """scikit-learn's own hyperparameter search of a regressor (the same L-BFGS-B call as its
    ``optimizer="fmin_l_bfgs_b"``), remembering each start's optimum so that the chosen one
    can be cached exactly (a fitted kernel gives its hyperparameters back only through a log
    and an exp, which may move the last digit)."""

    def __init__(self):
        self.optima = []

    def __call__(self, obj_func, initial_theta, bounds):
        res = scipy.optimize.minimize(obj_func, initial_theta, method="L-BFGS-B", jac=True,
                                      bounds=bounds)
        self.optima.append((np.asarray(res.x, float), float(res.fun)))
        return res.x, res.fun

    def best(self) -> dict:
        """The optimum the regressor chose (the first of the lowest): {"theta", "fun"}."""
        theta, fun = self.optima[int(np.argmin([f for _, f in self.optima]))]
        return {"theta": theta.tolist(), "fun": fun}


class Replay:
    """An "optimiser" that returns a cached optimum at once (every start): the regressor then
    sets exactly the hyperparameters :class:`Search` found."""

    def __init__(self, theta, fun):
        self.theta, self.fun = theta, fun

    @classmethod
    def of(cls, found, kernel) -> "Replay | None":
        """The replay of :meth:`Search.best`'s ``found`` for ``kernel``, None if it does not
        fit it (not cached, or a file written for something else)."""
        try:
            theta, fun = np.asarray(found["theta"], float), float(found["fun"])
        except (TypeError, KeyError, ValueError):
            return None
        ok = theta.shape == kernel.theta.shape and np.isfinite(theta).all()
        return cls(theta, fun) if ok else None

    def __call__(self, obj_func, initial_theta, bounds):
        return self.theta.copy(), self.fun


class FitCache:
    """Earlier fits' hyperparameters in ``folder``, else in the read-only folders ``also``
    (see the module docstring); new fits are written to ``folder``."""

    def __init__(self, folder, also=()):
        self.folder = Path(folder)
        self.also = tuple(Path(f) for f in also)

    @classmethod
    def beside(cls, runs_dir, also=()) -> "FitCache":
        """The cache of the fits made from the twin runs in ``runs_dir``."""
        return cls(Path(runs_dir) / FOLDER, also)

    @staticmethod
    def key(kind: str, kernel, *arrays, **settings) -> str:
        """Hash of a fit's kind, initial kernel, training arrays and optimiser settings."""
        h = hashlib.sha256()
        h.update(repr((kind, sklearn.__version__, repr(kernel), sorted(settings.items())))
                 .encode())
        for a in (kernel.theta, kernel.bounds) + arrays:
            _hash_array(h, a)
        return h.hexdigest()[:32]

    def get(self, key: str, kind=dict):
        """What :meth:`put` kept under ``key`` if it is a ``kind``, else None (not cached, or
        a file that does not parse)."""
        for folder in (self.folder,) + self.also:
            try:
                found = json.loads((folder / (key + ".json")).read_text())
            except (OSError, ValueError):
                continue
            if isinstance(found, kind):
                if folder != self.folder:       # copied: the own folder holds every fit used
                    self.put(key, found)
                return found
        return None

    def put(self, key: str, found) -> None:
        """Keep ``found`` (JSON: floats keep every digit) under ``key``, written atomically:
        processes sharing the folder never read half a file. A folder that cannot be written
        (read-only, full) only loses the cache."""
        try:
            with atomic_file(self.folder / (key + ".json")) as tmp:
                tmp.write_text(json.dumps(found))
        except OSError:
            pass


def code_fingerprint() -> str:
    """Hash of the project's Python source (:data:`SOURCE_DIRS`) and the numerical libraries'
    versions: an outcome cached by other code is a miss. Read once per process."""
    global _CODE
    if _CODE is None:
        import pandas
        h = hashlib.sha256(repr((np.__version__, scipy.__version__, sklearn.__version__,
                                 pandas.__version__)).encode())
        for d in SOURCE_DIRS:
            for f in sorted((_ROOT / d).rglob("*.py")):
                h.update(str(f.relative_to(_ROOT)).encode())
                h.update(f.read_bytes())
        _CODE = h.hexdigest()
    return _CODE


_CODE = None


def digest(*parts) -> str:
    """Hash of ``parts``: tables by their CSV text (every digit), arrays by dtype, shape and
    bytes, anything else by its repr."""
    import pandas
    h = hashlib.sha256()
    for p in parts:
        if isinstance(p, (pandas.DataFrame, pandas.Series)):
            h.update(p.to_csv().encode())
        elif isinstance(p, np.ndarray):
            _hash_array(h, p)
        else:
            h.update(repr(p).encode())
        h.update(b"\x00")
    return h.hexdigest()[:32]


def _hash_array(h, a) -> None:
    """Feed an array to hash ``h``: its dtype, shape and bytes (an object array's values)."""
    a = np.ascontiguousarray(a)
    h.update(repr((a.dtype.str, a.shape)).encode())
    h.update(a.tobytes() if a.dtype != object else repr(a.tolist()).encode())


def is_fit_file(path) -> bool:
    """A file this cache writes: ``<32 hex digits>.json``."""
    path = Path(path)
    return path.is_file() and re.fullmatch(r"[0-9a-f]{32}\.json", path.name) is not None


def replace_fits(new, dest=COMMITTED_FITS) -> int:
    """Make the folder ``dest`` hold exactly the fit files of the folder ``new`` (copied; the
    old ones swapped out at once). Refused (:class:`OutputError`, nothing changed) when
    ``dest`` holds anything this cache did not write. Returns the number of fits."""
    dest = Path(dest)
    if dest.exists() and not all(is_fit_file(p) for p in dest.iterdir()):
        raise OutputError("%s holds files that are not emulator fits; it is left as it is"
                          % dest)
    dest.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=".%s.tmp-" % dest.name, dir=dest.parent))
    try:
        fits = [p for p in Path(new).iterdir() if is_fit_file(p)]
        for p in fits:
            shutil.copy2(p, tmp / p.name)
        os.chmod(tmp, 0o755)
        old = tmp.with_name(tmp.name.replace(".tmp-", ".old-"))
        if dest.exists():
            os.replace(dest, old)
        os.replace(tmp, dest)
        shutil.rmtree(old, ignore_errors=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return len(fits)
