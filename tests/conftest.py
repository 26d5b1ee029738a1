"""Session settings of the test suite.

`make test` runs two pytest workers on a 2-core machine: each process (and every stage it starts) gets one
thread unless a test sets its own, as f2depth.threads reads ``$OMP_NUM_THREADS``. Two workers at two
threads each ran torch several times slower (docs/experiments/2026-12-04-shared-cpu.md).
"""

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
