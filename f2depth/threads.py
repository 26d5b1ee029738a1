"""How many CPU threads a process uses: the CPUs it may run on, never more, unless the user says so.

Torch sizes its intra-op pool to the machine's cores and OpenCV to all of them, whatever the process's
CPU affinity (``taskset``, Slurm, ``docker --cpuset-cpus``) or cgroup CPU quota (``docker --cpus``,
Kubernetes limits, CI runners) allows: on a 64-core host with a 2-CPU quota torch would run 64 threads on
2 CPUs' worth of time, and every parallel operation would wait for threads that are not running. So every
stage and the CLI take one budget:

* :func:`usable_cpus`: the CPUs of the affinity mask, capped by the cgroup quota (v2 ``cpu.max``, v1
  ``cpu.cfs_quota_us`` / ``cpu.cfs_period_us``), rounded up;
* :func:`budget`: the user's override when there is one (params.yaml ``threads``, the CLI's
  ``--threads``; else ``$OMP_NUM_THREADS``, the usual knob, which torch reads too), else :func:`usable_cpus`;
* :func:`use`: torch's and OpenCV's thread counts set to the budget, less the DataLoader processes that
  share it (each of those runs one torch thread, as torch's DataLoader sets);
* process pools (``f2depth.workers``) never start more processes than :func:`usable_cpus`.

Other jobs on the same CPUs are not seen: beside one busy process a 2-thread torch step on 2 cores ran
3.3× slower, a 1-thread step 1.02× (docs/experiments/2026-12-04-shared-cpu.md). On a shared machine set
``threads`` to the cores that are free.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

CGROUP = Path("/sys/fs/cgroup")


def _cgroup_quota(root: Path = CGROUP) -> float | None:
    """CPUs the cgroup quota allows (``quota / period``), or None without a quota."""
    try:
        quota, period = (root / "cpu.max").read_text().split()[:2]  # v2: "max 100000" or "200000 100000"
        return None if quota == "max" else int(quota) / int(period)
    except (OSError, ValueError):
        pass
    try:  # v1
        quota = int((root / "cpu" / "cpu.cfs_quota_us").read_text())
        period = int((root / "cpu" / "cpu.cfs_period_us").read_text())
    except (OSError, ValueError):
        return None
    return quota / period if quota > 0 and period > 0 else None


def usable_cpus(cgroup: Path = CGROUP) -> int:
    """The CPUs this process may use: its affinity mask, capped by the cgroup quota (≥ 1)."""
    try:
        cpus = len(os.sched_getaffinity(0))
    except AttributeError:  # macOS, Windows: no affinity call
        cpus = os.cpu_count() or 1
    quota = _cgroup_quota(cgroup)
    if quota is not None:
        cpus = min(cpus, math.ceil(quota))
    return max(1, cpus)


def budget(threads: int | None = None) -> int:
    """The thread budget: ``threads`` when given, else a positive ``$OMP_NUM_THREADS``, else
    :func:`usable_cpus`."""
    if threads is not None:
        if threads < 1:
            raise ValueError(f"threads must be >= 1 or null, got {threads}")
        return int(threads)
    env = os.environ.get("OMP_NUM_THREADS", "").strip()
    if env.isdigit() and int(env) > 0:
        return int(env)
    return usable_cpus()


def use(threads: int | None = None, *, loader_workers: int = 0) -> int:
    """Size torch's and OpenCV's pools to the :func:`budget` less ``loader_workers`` (≥ 1) → torch's count."""
    import cv2
    import torch

    n = max(1, budget(threads) - loader_workers)
    torch.set_num_threads(n)
    cv2.setNumThreads(n)
    return n
