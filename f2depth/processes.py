"""Jobs in their own processes at a fixed thread count, all at once: the seeds of a CPU depth-training run
(f2depth.train.run) and the ranks of a CPU flow pretraining (f2depth.flow.chairs_ranks).

Why (docs/depth_training.md, "Seeds and threads"): a backward pass on a CPU sums in an order that depends
on torch's thread count, so a run gives the same weights only at the same count; and a 2-thread step on 2
cores beside one busy process runs many times slower, because every parallel operation waits for the
thread the other process displaced. One thread per process avoids both: a 1-thread process gives the same
bits on any machine of the same CPU kind, whatever its core count and whatever else runs, and beside a
busy process it only shares a core. The processes fill the cores by running side by side (3 seeds on 2
cores: 1.5 seeds' time), which more than pays for the second thread each would otherwise use (1.56× on
the CPU default's depth step).

:func:`run_jobs` runs ``job(*args)`` for each argument tuple in a ``spawn``-started process (a clean
interpreter: no OpenMP pool inherited from the parent, the same on Linux and macOS) whose torch and OpenCV
run ``threads`` threads, and returns the results in order. A job reports finished epochs through
:func:`epoch_done`; the parent draws one progress bar over all of them. An exception in a job stops the
others and is raised in the parent.
"""

from __future__ import annotations

import multiprocessing
import queue
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from typing import Any

from tqdm import tqdm

from f2depth import threads as thread_budget

_progress: Any = None  # the parent's queue, in a job process (set by _start)


def _start(progress: Any, n_threads: int) -> None:
    """Initializer of each job process: its thread count and the parent's progress queue."""
    global _progress
    _progress = progress
    thread_budget.use(n_threads)


def epoch_done() -> None:
    """In a job: one epoch finished (the parent's bar moves); a no-op outside :func:`run_jobs`."""
    if _progress is not None:
        _progress.put(1)


def processes_for(jobs: int, n_threads: int) -> int:
    """How many jobs run at once: all of them, up to two per usable CPU's worth of threads (a job waiting
    on its validation or its files leaves its core to the other)."""
    return max(1, min(jobs, 2 * thread_budget.usable_cpus() // n_threads))


def run_jobs(job: Callable[..., Any], args: Sequence[tuple], n_threads: int, total_epochs: int,
             desc: str, progress: bool = True, concurrent: bool = False) -> list[Any]:
    """``[job(*a) for a in args]``, each call in its own process at ``n_threads`` threads (module
    docstring). ``job`` must be a module-level function (the processes import it by name).
    ``concurrent``: every job at once, whatever :func:`processes_for` says (jobs that wait for each other,
    as the ranks of a data-parallel run)."""
    ctx = multiprocessing.get_context("spawn")
    reports = ctx.Queue()
    bar = tqdm(total=total_epochs, desc=desc, unit="epoch", disable=not progress)
    stop = threading.Event()

    def follow() -> None:
        while not stop.is_set():
            try:
                bar.update(reports.get(timeout=0.2))
            except queue.Empty:
                continue

    reader = threading.Thread(target=follow, daemon=True)
    reader.start()
    try:
        workers = len(args) if concurrent else processes_for(len(args), n_threads)
        with ProcessPoolExecutor(max(workers, 1), mp_context=ctx, initializer=_start,
                                 initargs=(reports, n_threads)) as pool:
            futures = [pool.submit(job, *a) for a in args]
            try:
                return [f.result() for f in futures]
            except BaseException:
                for f in futures:
                    f.cancel()
                raise
    finally:
        stop.set()
        reader.join()
        bar.close()
