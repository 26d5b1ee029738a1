"""f2depth.workers: the jobs of a stage in spawned processes, results in job order."""

from __future__ import annotations

import math

import pytest

from f2depth.workers import map_jobs


@pytest.mark.parametrize("workers", [0, 1, 2])
def test_results_come_back_in_job_order_whatever_the_workers(workers):
    jobs = [9, 3, 7, 0, 5]
    assert map_jobs(math.factorial, jobs, workers) == [math.factorial(j) for j in jobs]


def test_a_failing_job_raises_its_own_error_from_a_worker():
    with pytest.raises(ValueError, match="invalid literal"):
        map_jobs(int, ["1", "two", "3"], workers=2)
