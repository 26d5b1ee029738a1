"""f2depth.threads: the thread budget comes from the CPUs the process may use (affinity, cgroup quota), the
user's override wins, and every stage and process pool keeps to it."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import cv2
import pytest
import torch
import yaml

from f2depth import params as P
from f2depth import threads, workers

ROOT = Path(__file__).resolve().parents[1]
AFFINITY = len(os.sched_getaffinity(0))


def cgroup(tmp_path: Path, v2: str | None = None, v1: tuple[str, str] | None = None) -> Path:
    root = tmp_path / "cgroup"
    root.mkdir(parents=True)
    if v2 is not None:
        (root / "cpu.max").write_text(v2 + "\n")
    if v1 is not None:
        (root / "cpu").mkdir()
        (root / "cpu" / "cpu.cfs_quota_us").write_text(v1[0] + "\n")
        (root / "cpu" / "cpu.cfs_period_us").write_text(v1[1] + "\n")
    return root


def test_usable_cpus_is_the_affinity_capped_by_the_cgroup_quota(tmp_path, monkeypatch):
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: set(range(16)))  # a 16-core host
    assert threads.usable_cpus(cgroup(tmp_path / "none")) == 16  # no quota files at all
    assert threads.usable_cpus(cgroup(tmp_path / "max", v2="max 100000")) == 16  # v2, no limit
    assert threads.usable_cpus(cgroup(tmp_path / "q", v2="150000 100000")) == 2  # docker --cpus 1.5 → 2
    assert threads.usable_cpus(cgroup(tmp_path / "v1", v1=("300000", "100000"))) == 3
    assert threads.usable_cpus(cgroup(tmp_path / "v1off", v1=("-1", "100000"))) == 16  # v1, no limit
    assert threads.usable_cpus(cgroup(tmp_path / "bad", v2="garbage")) == 16
    assert threads.usable_cpus(cgroup(tmp_path / "big", v2="6400000 100000")) == 16  # quota above the mask
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {3})  # taskset -c 3
    assert threads.usable_cpus(cgroup(tmp_path / "one")) == 1


def test_the_override_wins_then_omp_num_threads_then_the_usable_cpus(monkeypatch):
    monkeypatch.setattr(threads, "usable_cpus", lambda: 5)
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    assert threads.budget() == 5
    monkeypatch.setenv("OMP_NUM_THREADS", "3")
    assert threads.budget() == 3 and threads.budget(7) == 7
    for junk in ("0", "", "two", "-1"):
        monkeypatch.setenv("OMP_NUM_THREADS", junk)
        assert threads.budget() == 5
    with pytest.raises(ValueError, match="threads must be >= 1"):
        threads.budget(0)


def test_use_sizes_torch_and_opencv_leaving_room_for_loader_processes(monkeypatch, restore_threads):
    monkeypatch.setattr(threads, "usable_cpus", lambda: 4)
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    assert threads.use() == 4 and torch.get_num_threads() == 4 and cv2.getNumThreads() == 4
    assert threads.use(loader_workers=3) == 1 and torch.get_num_threads() == 1
    assert threads.use(loader_workers=9) == 1  # never below one
    assert threads.use(2) == 2 and torch.get_num_threads() == 2 and cv2.getNumThreads() == 2


def _pid(_job: int) -> int:
    return os.getpid()


def test_process_pools_never_outnumber_the_usable_cpus(monkeypatch):
    monkeypatch.setattr(workers, "usable_cpus", lambda: 1)
    assert set(workers.map_jobs(_pid, [0, 1, 2], workers=4)) == {os.getpid()}  # in this process
    monkeypatch.setattr(workers, "usable_cpus", lambda: 2)
    pids = workers.map_jobs(_pid, [0, 1, 2, 3], workers=4)
    assert os.getpid() not in pids and 1 <= len(set(pids)) <= 2


def test_the_threads_key_is_checked_in_one_line():
    assert P.threads({"_file": "p.yaml", "threads": None}) is None
    assert P.threads({"_file": "p.yaml", "threads": 3}) == 3
    for bad in (0, "many", 1.5):
        with pytest.raises(P.ParamsError) as info:
            P.threads({"_file": "p.yaml", "threads": bad})
        assert "threads" in str(info.value) and "\n" not in str(info.value)


def test_every_stage_that_computes_reads_and_declares_the_threads_key():
    stages = yaml.safe_load((ROOT / "dvc.yaml").read_text())["stages"]
    for name in ("synth", "prepare", "keypoints", "poses", "flow_pretrain", "flow_finetune", "flow_figure",
                 "train_depth", "evaluate"):
        stage = stages[name].get("do", stages[name])
        assert "threads" in stage["params"], name
        assert "threads.use(P.threads(" in (ROOT / "stages" / f"{name}.py").read_text(), name


def test_a_stage_runs_with_the_threads_it_was_given(tmp_path):
    """The budget reaches torch in a real stage process: `threads: 1` beside OMP_NUM_THREADS=2 → 1 thread."""
    probe = tmp_path / "probe.py"
    probe.write_text("import sys, torch\nfrom f2depth import params as P, threads\n"
                     "threads.use(P.threads(P.load(sys.argv[1])))\nprint(torch.get_num_threads())\n")
    params = tmp_path / "params.yaml"
    counts = []
    for value in (1, None):
        params.write_text(yaml.safe_dump({"threads": value}))
        out = subprocess.run([sys.executable, str(probe), str(params)], capture_output=True, text=True,
                             check=True, env={**os.environ, "OMP_NUM_THREADS": "2", "PYTHONPATH": str(ROOT)})
        counts.append(int(out.stdout.strip()))
    assert counts == [1, 2]


def test_the_cli_sizes_its_threads_before_the_command_runs(tmp_path, monkeypatch, capsys, restore_threads):
    from f2depth import cli

    seen = []
    monkeypatch.setattr(threads, "use", lambda n=None, **kw: seen.append(n) or 1)
    (tmp_path / "in").mkdir()
    code = cli.main(["predict", "--threads", "3", "--model", str(tmp_path / "missing.pt"),
                     "--input", str(tmp_path / "in"), "--output", str(tmp_path / "out")])
    assert seen == [3] and code != 0  # sized first, then the command failed on the missing model
    with pytest.raises(SystemExit) as info:
        cli.main(["predict", "--threads", "0", "--model", "m.pt", "--input", "a", "--output", "b"])
    assert info.value.code == 2 and "--threads" in capsys.readouterr().err


def test_cpu_seconds_adds_the_busy_ticks_of_the_given_cpus(tmp_path):
    stat = tmp_path / "stat"
    stat.write_text("cpu  9 9 9 9 9 9 9 9 0 0\n"
                    "cpu0 100 10 50 999 7 3 2 1 0 0\n"
                    "cpu1 200 0 100 999 0 0 0 0 0 0\n"
                    "intr 1 2 3\n")
    tick = os.sysconf("SC_CLK_TCK")
    assert threads.cpu_seconds([0], stat) == pytest.approx((100 + 10 + 50 + 3 + 2 + 1) / tick)
    assert threads.cpu_seconds([0, 1], stat) == pytest.approx((166 + 300) / tick)
    assert threads.cpu_seconds([5], stat) is None
    assert threads.cpu_seconds([0], tmp_path / "missing") is None
    assert threads.cpu_seconds(sorted(os.sched_getaffinity(0))) > 0  # the real /proc/stat


def test_threads_for_gives_the_free_cores_within_one_and_the_ceiling():
    assert threads.threads_for(0.0, 2, 2) == 2
    assert threads.threads_for(1.0, 2, 2) == 1  # one busy competitor on two cores
    assert threads.threads_for(0.3, 2, 2) == 2
    assert threads.threads_for(3.0, 2, 2) == 1
    assert threads.threads_for(0.0, 16, 4) == 4


def test_free_cores_follows_the_other_processes_between_measurements():
    now = [0.0]
    busy = [0.0]
    own = [0.0]
    free = threads.FreeCores(2, cpus=[0, 1], interval=2.0, busy=lambda cpus: busy[0],
                             own=lambda: own[0], clock=lambda: now[0])

    def after(seconds, own_cores, other_cores):
        now[0] += seconds
        own[0] += seconds * own_cores
        busy[0] += seconds * (own_cores + other_cores)
        return free.threads()

    assert after(2.0, 2.0, 0.0) == 2  # alone: both cores
    assert after(2.0, 1.0, 1.0) == 1  # another process took one core
    assert after(1.0, 1.0, 0.0) == 1  # too soon to re-measure: the last count
    assert after(2.0, 1.0, 0.0) == 2  # over the last 3 s: 1/3 core taken by others → both again
    reserved = threads.FreeCores(2, reserved=1, cpus=[0, 1], interval=2.0, busy=lambda cpus: busy[0],
                                 own=lambda: own[0], clock=lambda: now[0])
    now[0] += 2.0
    busy[0] += 2.0 * 2  # this process's loader worker (a child process) keeps one core busy
    own[0] += 2.0
    assert reserved.threads() == 2


def test_adapt_runs_only_when_the_count_is_automatic(monkeypatch, restore_threads):
    monkeypatch.setenv("OMP_NUM_THREADS", "2")
    assert threads.use(None) == 2
    assert threads.adapt() is None  # $OMP_NUM_THREADS fixes it
    assert threads.use(2) == 2 and threads.adapt() is None
    monkeypatch.delenv("OMP_NUM_THREADS")
    monkeypatch.setattr(threads, "usable_cpus", lambda cgroup=threads.CGROUP: 2)
    assert threads.use(None) == 2 and threads.adapt() is None  # training: the count stays
    assert threads.use(None, follow_free_cores=True) == 2  # inference
    monkeypatch.setattr(threads._free, "threads", lambda: 1)
    assert threads.adapt() == 1 and torch.get_num_threads() == 1
    threads.use(1)
    assert threads._free is None
