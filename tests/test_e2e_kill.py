"""kill -9 inside `dvc repro` (issue 25, what held): the repository's pipeline on the tiny configuration of
test_e2e_pipeline.py; `flow_finetune@patch` killed after its first epoch resumes from its state to the
weights of an uninterrupted run, and `poses` killed while it runs redoes the same files, byte for byte
(priors.json holds no timing). Marked ``e2e`` like the pipeline test (about 2 minutes)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time
from pathlib import Path

import psutil
import pytest
import torch
from test_e2e_pipeline import BIN, run, tiny_repo

from f2depth.flow.checkpoint import load_flow_model


def kill_when(cmd: list[str], cwd: Path, env: dict[str, str], ready, timeout: float = 600) -> None:
    """Start ``cmd`` in its own process group and kill -9 the whole group once ``ready()`` is true."""
    proc = subprocess.Popen(cmd, cwd=cwd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)
    deadline = time.monotonic() + timeout
    try:
        while not ready():
            assert proc.poll() is None, f"{' '.join(cmd)} ended before it could be killed"
            assert time.monotonic() < deadline, "timed out waiting to kill"
            time.sleep(0.02)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()


@pytest.mark.e2e
def test_stages_killed_inside_dvc_repro_resume_or_redo_identically(tmp_path):
    repo, params, env = tiny_repo(tmp_path, {"flow_finetune.epochs": 3})
    dvc = str(BIN / "dvc")

    state = repo / "tmp" / "flow_finetune" / "patch.pt"
    kill_when([dvc, "repro", "flow_finetune@patch"], repo, env, state.exists)
    assert not (repo / "models" / "flow_patch.pt").exists()
    run([dvc, "repro", "flow_finetune@patch"], repo, env)
    metrics = json.loads((repo / "metrics" / "flow_finetune" / "patch.json").read_text())
    assert metrics["resumed_from"] >= 1 and not state.exists()
    resumed = load_flow_model(repo / "models" / "flow_patch.pt").state_dict()
    run([dvc, "repro", "-f", "-s", "flow_finetune@patch"], repo, env)  # uninterrupted, from scratch
    assert json.loads((repo / "metrics" / "flow_finetune" / "patch.json").read_text())["resumed_from"] == 0
    whole = load_flow_model(repo / "models" / "flow_patch.pt").state_dict()
    assert all(torch.equal(resumed[k], whole[k]) for k in whole)

    poses = Path(params["data"]["poses"])
    building = repo / poses.parent

    def poses_under_way() -> bool:  # the stage's process has run for half a second (the tiny run takes ~2 s)
        return any("stages/poses.py" in " ".join(p.info["cmdline"] or [])
                   and time.time() - p.info["create_time"] > 0.5
                   for p in psutil.process_iter(["cmdline", "create_time"]))

    kill_when([dvc, "repro", "poses"], repo, env, poses_under_way)
    run([dvc, "repro", "poses"], repo, env)
    first = {p.relative_to(repo): p.read_bytes() for p in (repo / poses).rglob("*") if p.is_file()}
    assert not any(p.name.startswith(f".{poses.name}.") for p in building.iterdir())  # no temporaries left
    run([dvc, "repro", "-f", "-s", "poses"], repo, env)
    again = {p.relative_to(repo): p.read_bytes() for p in (repo / poses).rglob("*") if p.is_file()}
    assert first and first == again
