"""Session settings of the test suite.

`make test` runs two pytest workers on a 2-core machine: each process (and every stage it starts) gets one
thread unless a test sets its own, as f2depth.threads reads ``$OMP_NUM_THREADS``. Two workers at two
threads each ran torch several times slower (docs/experiments/2026-12-04-shared-cpu.md).
"""

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")


def pytest_collection_modifyitems(config, items):
    """The long tests (marked ``e2e`` or ``slow``) first, in their collected order. `make test` hands tests
    to its two workers two at a time (``--maxschedchunk 2``), so the workers start on the long ones together
    and share them, instead of one of them starting a five-minute test when the other is nearly done."""
    items.sort(key=lambda item: not (item.get_closest_marker("e2e") or item.get_closest_marker("slow")))
