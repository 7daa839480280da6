"""The mill twin's analysis package.

Ctrl-C in the first milliseconds of ``python -m analysis.<command>`` - while Python locates the
command's module, before the command's own code runs - is one line ``analysis: interrupted``
and exit 130, not a traceback. Only then: the handler is installed only while this package is
imported as the parent of the ``-m`` module (``sys.argv[0]`` is ``'-m'`` then) and Ctrl-C is not
ignored; once the command's module has started, it hands Ctrl-C back to Python unchanged
(``KeyboardInterrupt``), so each command's own handling (the loop's one line, a sweep's clean
stop) applies as before. Imports only ``signal`` and ``sys``.
"""
import signal as _signal
import sys as _sys


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
