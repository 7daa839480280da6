"""Test ordering for the two-worker run (``make test``): the tests marked ``slow`` (each one a
loop on the FAKE twin, tens of seconds to minutes) are collected first, so the workers start
them early and fill the rest of the time with the short ones - started last, one of them would
leave the other worker idle at the end. The order within each class is the files' own; a
module stays contiguous within a class, so a module-scoped fixture is made once per worker
(the report tests that share one FAKE loop carry ``xdist_group("fake_loop")``: with
``--dist loadgroup`` they run on one worker, the loop made once).

The tests run on the numeric kernels the commands pin (:mod:`analysis`: OpenBLAS's Haswell
kernels, one BLAS thread), also when pytest is started without ``make test``: the package is
imported here, before any test module loads NumPy."""
import importlib

importlib.import_module("analysis")      # pins the kernels when NumPy is not loaded yet


def pytest_collection_modifyitems(config, items):
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)
