"""The test run itself (tests/conftest.py): a pytest-xdist worker ends quickly once it has
reported its session finished."""

from __future__ import annotations

import gc

from tests import conftest


def test_the_session_end_leaves_pytests_last_collection_nothing_old_to_scan():
    """After ``pytest_sessionfinish`` (which runs before the worker reports finished), every
    object alive is frozen: pytest's last full collection scans none of them, so it cannot run
    past execnet's 5 s and bring its SIGINT."""
    old = [[i] for i in range(50_000)]  # a heap of containers the collector tracks
    marker = old[-1]
    try:
        conftest.pytest_sessionfinish(session=None)
        assert gc.get_freeze_count() >= len(old)
        assert not any(o is marker for o in gc.get_objects())  # no generation holds it: not scanned
        young = [[0]]
        assert any(o is young[0] for o in gc.get_objects())  # what comes later is collected as usual
    finally:
        gc.unfreeze()
