"""The jobs of a stage in worker processes: one helper for synth, prepare, keypoints and poses.

Workers are *spawned* (a fresh interpreter, no forked torch or OpenCV state) and run OpenCV with one
thread each: the processes are the parallelism. Results come back in the order of the jobs, so the
output does not depend on the number of workers or on which finishes first.
"""

from __future__ import annotations

import contextlib
import multiprocessing
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from typing import Any

import cv2
from tqdm import tqdm

from f2depth.threads import usable_cpus


def init_worker() -> None:
    cv2.setNumThreads(1)


def map_jobs(fn: Callable[[Any], Any], jobs: Sequence[Any], workers: int, desc: str = "",
             progress: bool = False, size: Callable[[Any], int] = lambda job: 1) -> list[Any]:
    """``[fn(job) for job in jobs]`` in ``min(workers, len(jobs))`` processes (in this one when that is ≤ 1);
    ``fn`` must be picklable (module level). The progress bar counts ``size(job)`` frames per job. Never
    more processes than the CPUs this process may use (f2depth.threads.usable_cpus)."""
    n = min(workers, len(jobs), usable_cpus())
    with tqdm(total=sum(map(size, jobs)), desc=desc, unit="frame", disable=not progress) as bar, \
            contextlib.ExitStack() as stack:
        if n <= 1:
            init_worker()
            results = map(fn, jobs)
        else:
            ctx = multiprocessing.get_context("spawn")
            pool = stack.enter_context(ProcessPoolExecutor(n, mp_context=ctx, initializer=init_worker))
            results = pool.map(fn, jobs)
        out = []
        for job, result in zip(jobs, results):
            out.append(result)
            bar.update(size(job))
        return out
