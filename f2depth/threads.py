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

Other jobs on the same CPUs: beside one busy process a 2-thread torch step on 2 cores ran 3.3× slower,
a 1-thread step 1.02× (docs/experiments/2026-12-04-shared-cpu.md), because every parallel operation
waits for the thread that is not running. Where the thread count cannot change a result — inference:
a forward pass gives the same bits at any count, a backward pass does not (tests/test_threads.py) —
``use(..., follow_free_cores=True)`` (evaluate, the CLI) with an automatic budget (no ``threads``, no
``$OMP_NUM_THREADS``) also starts a :class:`FreeCores` watch, and :func:`adapt`, called between inference
batches, sets torch's count to the cores the other processes leave free (measured from ``/proc/stat`` every
2 s, less this process's own CPU time). Training stages keep the count :func:`use` set for the whole run,
so the same inputs give the same weights whatever else the machine runs.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable
from pathlib import Path

CGROUP = Path("/sys/fs/cgroup")
PROC_STAT = Path("/proc/stat")


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


def _affinity() -> list[int]:
    """The CPU ids this process may run on."""
    try:
        return sorted(os.sched_getaffinity(0))
    except AttributeError:  # macOS, Windows: no affinity call
        return list(range(os.cpu_count() or 1))


def usable_cpus(cgroup: Path = CGROUP) -> int:
    """The CPUs this process may use: its affinity mask, capped by the cgroup quota (≥ 1)."""
    cpus = len(_affinity())
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


def automatic(threads: int | None = None) -> bool:
    """True when neither ``threads`` nor a positive ``$OMP_NUM_THREADS`` fixes the count."""
    env = os.environ.get("OMP_NUM_THREADS", "").strip()
    return threads is None and not (env.isdigit() and int(env) > 0)


def cpu_seconds(cpus: list[int], stat: Path = PROC_STAT) -> float | None:
    """Busy CPU seconds (all processes; user, nice, system, irq, softirq, steal) of ``cpus`` since boot,
    from ``/proc/stat``; None where it cannot be read (not Linux)."""
    try:
        lines = stat.read_text().splitlines()
    except OSError:
        return None
    wanted = {f"cpu{i}" for i in cpus}
    ticks = 0
    found = False
    for line in lines:
        fields = line.split()
        if fields and fields[0] in wanted:
            user, nice, system, _idle, _iowait, irq, softirq, steal = (int(v) for v in fields[1:9])
            ticks += user + nice + system + irq + softirq + steal
            found = True
    return ticks / os.sysconf("SC_CLK_TCK") if found else None


def own_cpu_seconds() -> float:
    """CPU seconds this process has used, all its threads."""
    return time.process_time()


def threads_for(others: float, cpus: int, ceiling: int) -> int:
    """Torch threads for ``cpus`` CPUs of which other processes keep ``others`` busy (in cores):
    the free cores rounded, within [1, ceiling]."""
    return max(1, min(ceiling, round(cpus - others)))


class FreeCores:
    """Watches the CPUs of this process: :meth:`threads` → the thread count for the cores the other
    processes leave free, re-measured at most every ``interval`` seconds (between calls it answers
    the last count, so calling it per step costs nothing)."""

    def __init__(self, ceiling: int, *, reserved: int = 0, interval: float = 2.0,
                 cpus: list[int] | None = None, busy: Callable[[list[int]], float | None] = cpu_seconds,
                 own: Callable[[], float] = own_cpu_seconds, clock: Callable[[], float] = time.monotonic):
        self.cpus = cpus if cpus is not None else _affinity()
        self.ceiling, self.reserved, self.interval = ceiling, reserved, interval
        self._busy, self._own, self._clock = busy, own, clock
        self.count = ceiling
        self.usable = min(len(self.cpus), usable_cpus())
        self._last = self._sample()

    def _sample(self) -> tuple[float, float, float] | None:
        busy = self._busy(self.cpus)
        return None if busy is None else (self._clock(), busy, self._own())

    def threads(self) -> int:
        """The thread count to use now."""
        if self._last is None or self._clock() - self._last[0] < self.interval:
            return self.count
        now = self._sample()
        if now is None:
            return self.count
        wall = now[0] - self._last[0]
        others = ((now[1] - self._last[1]) - (now[2] - self._last[2])) / wall - self.reserved
        self._last = now
        self.count = threads_for(max(0.0, others), self.usable, self.ceiling)
        return self.count


_free: FreeCores | None = None


def use(threads: int | None = None, *, loader_workers: int = 0, follow_free_cores: bool = False) -> int:
    """Size torch's and OpenCV's pools to the :func:`budget` less ``loader_workers`` (≥ 1) → torch's count.
    With ``follow_free_cores`` (only where the count cannot change a result: inference) and an automatic
    budget of more than one thread, :func:`adapt` then follows the free cores; otherwise the count stays."""
    import cv2
    import torch

    global _free
    n = max(1, budget(threads) - loader_workers)
    torch.set_num_threads(n)
    cv2.setNumThreads(n)
    follow = follow_free_cores and automatic(threads) and n > 1
    _free = FreeCores(n, reserved=loader_workers) if follow else None
    return n


def adapt() -> int | None:
    """Between inference batches: set torch's count to the free cores when :func:`use` started a watch
    → the count, or None when the count is fixed."""
    if _free is None:
        return None
    import torch

    n = _free.threads()
    if n != torch.get_num_threads():
        torch.set_num_threads(n)
    return n
