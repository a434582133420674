"""pytest's assertion rewriting for the shared helpers (their asserts explain themselves too), and a
quick end to each pytest-xdist worker."""

import gc

import pytest

pytest.register_assert_rewrite("tests.helpers")


def pytest_sessionfinish(session):
    """Collect the garbage and freeze what survives, before the worker says it has finished.

    Once a pytest-xdist worker reports its session finished, the controller asks it to exit, and
    the worker's transport (execnet) sends the worker a SIGINT if it is still busy 5 s later.  The
    last thing pytest does is a full garbage collection, which on a worker's heap (models, compiled
    kernels, caches: millions of objects) can take longer on a loaded machine: the SIGINT then
    lands in the first Python code run after the collection, a gc callback (hypothesis's), and a
    passing run ends with a ``KeyboardInterrupt`` traceback.  Collected here, while the controller
    still waits, and frozen (``gc.freeze``: never scanned again), the heap leaves pytest's last
    collection only the objects made after this hook."""
    gc.collect()
    gc.freeze()
