"""The mill twin's analysis package.

Ctrl-C in the first milliseconds of ``python -m analysis.<command>`` - while Python locates the
command's module, before the command's own code runs - is one line ``analysis: interrupted``
and exit 130, not a traceback. Only then: the handler is installed only while this package is
imported as the parent of the ``-m`` module (``sys.argv[0]`` is ``'-m'`` then) and Ctrl-C is not
ignored; once the command's module has started, it hands Ctrl-C back to Python unchanged
(``KeyboardInterrupt``), so each command's own handling (the loop's one line, a sweep's clean
stop) applies as before.

The same numbers on every machine: the loop's path through its waves and fits turns on the last
digits of its linear algebra (a fit in a flat direction of the likelihood), and OpenBLAS picks
its kernels at run time by the processor - AVX-512 ones (SkylakeX) here, AVX2 ones (Haswell)
there, each rounding its own way. Before NumPy is loaded this package pins OpenBLAS's Haswell
kernels and one BLAS thread on every x86-64 processor that has AVX2 and FMA, so a committed run
table replays to the same fits; a variable the user has set is left as it is
(``OPENBLAS_CORETYPE``, ``OPENBLAS_NUM_THREADS``). NumPy's own SIMD dispatch is left to the
processor: on Table 3's first fit AVX-512 or AVX2 there moves the restitution from 0.28749741
to 0.28748787, where the BLAS kernels moved it to 0.2913 (docs/loop.md, "Across machines").
Imports only ``os``, ``signal`` and ``sys``.
"""
import os as _os
import signal as _signal
import sys as _sys

#: the numeric kernels every machine uses (see the module docstring): variable -> value
PINNED_KERNELS = {"OPENBLAS_CORETYPE": "Haswell", "OPENBLAS_NUM_THREADS": "1"}


def _cpu_flags(path="/proc/cpuinfo") -> set:
    try:
        with open(path) as f:
            for line in f:
                if line.startswith("flags"):
                    return set(line.split(":", 1)[1].split())
    except OSError:
        pass
    return set()


def pin_kernels(environ=None, flags=None) -> dict:
    """Set :data:`PINNED_KERNELS` in ``environ`` (default os.environ) where the processor
    runs them (``flags`` has avx2 and fma) and the variable is unset; returns what it set."""
    env = _os.environ if environ is None else environ
    flags = _cpu_flags() if flags is None else flags
    if not {"avx2", "fma"} <= set(flags):
        return {}
    out = {k: v for k, v in PINNED_KERNELS.items() if k not in env}
    env.update(out)
    return out


if "numpy" not in _sys.modules:
    pin_kernels()


def _interrupted_at_start(signum, frame):
    main = _sys.modules.get("__main__")
    if getattr(main, "__spec__", None) is not None:
        # the command's own module runs: Ctrl-C is Python's again (KeyboardInterrupt)
        _signal.signal(_signal.SIGINT, _signal.default_int_handler)
        _signal.default_int_handler(signum, frame)
    _sys.stderr.write("analysis: interrupted\n")
    _sys.stderr.flush()
    _sys.exit(130)


if _sys.argv[:1] == ["-m"] and _signal.getsignal(_signal.SIGINT) is _signal.default_int_handler:
    _signal.signal(_signal.SIGINT, _interrupted_at_start)
