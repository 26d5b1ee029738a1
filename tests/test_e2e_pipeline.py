"""End to end: the repository's own dvc.yaml, params.yaml, configs/, stages/ and f2depth/ copied into a fresh
git + DVC repository, params cut to a tiny configuration, then `dvc repro` (every stage must run, the
tables must exist, every output must be a link to the DVC cache) and a second `dvc repro` (everything must be
up to date). Then kill -9 inside `dvc repro` (issue 25, what held), on the same repository:
`flow_finetune@patch` killed after its first epoch resumes from its state to the weights of the
uninterrupted run, and `poses` killed while it runs redoes the same files, byte for byte (priors.json holds
no timing). One test, so the tiny pipeline runs once.

Marked ``e2e`` (select with ``-m e2e``, leave out with ``-m "not e2e"``). It runs `dvc` from the venv
(the directory of the running Python) as a subprocess, with MLflow mirroring off; about 3-5 minutes on a
loaded 2-core machine.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import psutil
import pytest
import torch
import yaml

from f2depth.flow.net.checkpoint import load_flow_model

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
COPY = ("dvc.yaml", "params.yaml", "configs", "stages", "f2depth")

#: dotted key → value: tiny data (480×640 frames are fixed by the formats, so few of them), one epoch,
#: small networks' inputs (multiples of 64 for PWC-Lite), one timing run
TINY: dict[str, object] = {
    "synth.workers": 2,
    "synth.supersample": 1,
    "synth.nyu_raw.scenes": 2,
    "synth.nyu_raw.frames": 7,
    "synth.nyu_labeled.images": 4,
    "synth.nyu_labeled.test_fraction": 0.5,
    "synth.sevenscenes.scenes": 1,
    "synth.sevenscenes.frames_per_sequence": 2,
    "synth.campus.scenes": 2,
    "synth.campus.images_per_scene": 1,
    "synth.campus.height": 96,
    "synth.campus.width": 64,
    "synth.animated.sequences": 2,
    "synth.animated.frames": 3,
    "synth.animated.height": 64,
    "synth.animated.width": 64,
    "ingest.min_motion": 0.0005,  # the tiny clips' 7 frames move less than the default asks
    "prepare.height": 64,
    "prepare.width": 64,
    "prepare.frame_step": 2,
    "prepare.workers": 1,
    "keypoints.workers": 1,
    "keypoints.overlays": 1,
    "poses.workers": 1,
    "flow_pretrain.height": 64,
    "flow_pretrain.width": 64,
    "flow_pretrain.raw_epochs": 1,
    "flow_pretrain.census_epochs": 1,
    "flow_pretrain.batch_size": 2,
    "flow_pretrain.passes": ["clean"],
    "flow_pretrain.eval_prepared_pairs": 2,
    "flow_pretrain.figures": 1,
    "flow_pretrain.chairs.data.height": 64,
    "flow_pretrain.chairs.data.width": 64,
    "flow_pretrain.chairs.data.textures": 3,
    "flow_pretrain.chairs.data.image_crops": 2,
    "flow_pretrain.chairs.data.supersample": 1,
    "flow_pretrain.chairs.batch_size": 2,
    "flow_pretrain.chairs.steps_per_epoch": 2,
    "flow_pretrain.chairs.feature_epochs": 1,
    "flow_pretrain.chairs.epochs": 1,
    "flow_pretrain.chairs.average_epochs": 1,
    "flow_pretrain.chairs.calibration_pairs": 2,
    "flow_pretrain.chairs.heldout_pairs": 2,
    "flow_finetune.epochs": 2,  # the kill after the first epoch needs a second
    "flow_finetune.batch_size": 2,
    "flow_finetune.eval_train_pairs": 2,
    "flow_figure.pairs": 1,
    "train_depth.epochs": 1,
    "train_depth.seeds": [0],
    "train_depth.batch_size": 2,
    "train_depth.num_points": 50,
    "train_depth.val_max_images": 2,
    "evaluate.timing_height": 64,
    "evaluate.timing_width": 64,
    "evaluate.timing_repeats": 1,
    "evaluate.timing_warmup": 0,
    "evaluate.figure_images": 1,
    "evaluate.figure_width": 64,
    "device": "cpu",
}


def tiny_params(params: dict, overrides: dict[str, object]) -> dict:
    for dotted, value in overrides.items():
        node = params
        *parents, leaf = dotted.split(".")
        for part in parents:
            node = node[part]
        if leaf not in node:
            raise KeyError(f"params.yaml has no '{dotted}': update TINY in {Path(__file__).name}")
        node[leaf] = value
    return params


def run(cmd: list[str], cwd: Path, env: dict[str, str], timeout: float = 600) -> subprocess.CompletedProcess:
    proc = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    if proc.returncode != 0:
        raise AssertionError(f"{' '.join(cmd)} failed ({proc.returncode}):\n{proc.stdout[-6000:]}\n"
                             f"{proc.stderr[-6000:]}")
    return proc


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


def tiny_repo(tmp_path: Path, overrides: dict[str, object] | None = None
              ) -> tuple[Path, dict, dict[str, str]]:
    """A fresh git + DVC repository in ``tmp_path / "repo"`` with this repository's pipeline, code and
    cache settings and the TINY params (plus ``overrides``); returns (repo, params, env)."""
    repo = tmp_path / "repo"
    repo.mkdir()
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc")
    for name in COPY:
        src = ROOT / name
        (shutil.copytree(src, repo / name, ignore=ignore) if src.is_dir() else shutil.copy2(src, repo / name))
    params = tiny_params(yaml.safe_load((ROOT / "params.yaml").read_text()), {**TINY, **(overrides or {})})
    (repo / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False, allow_unicode=True))
    env = {**os.environ, "PATH": f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}", "F2DEPTH_MLFLOW": "0",
           "PYTHONPATH": str(repo), "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    env.pop("DVC_ROOT", None)
    git = ["git", "-c", "user.name=e2e", "-c", "user.email=e2e@example.invalid"]
    run(["git", "init", "-q"], repo, env)
    run([str(BIN / "dvc"), "init", "-q"], repo, env)
    shutil.copy2(ROOT / ".dvc" / "config", repo / ".dvc" / "config")  # the repository's cache link types
    run([str(BIN / "dvc"), "config", "core.analytics", "false"], repo, env)
    run(git + ["add", "-A"], repo, env)
    run(git + ["commit", "-q", "-m", "tiny pipeline"], repo, env)
    return repo, params, env


@pytest.mark.e2e
def test_dvc_repro_runs_every_stage_then_is_up_to_date(tmp_path):
    repo, params, env = tiny_repo(tmp_path)

    first = run([str(BIN / "dvc"), "repro"], repo, env, timeout=900)
    stages = yaml.safe_load((repo / "dvc.lock").read_text())["stages"]
    expected = {"synth", "ingest", "prepare", "keypoints", "poses", "flow_pretrain", "flow_figure", "tables",
                *(f"flow_finetune@{loss}" for loss in params["flow_finetune"]["losses"]),
                *(f"{stage}@{v}" for stage in ("train_depth", "evaluate") for v in params["variants"])}
    assert expected <= set(stages), sorted(expected - set(stages))
    for name in expected:
        assert f"Running stage '{name}'" in first.stdout, name
    for stem in ("table1_nyu", "table5_losses", "table6_flow", "sevenscenes_scenes", "campus_scenes"):
        for suffix in (".md", ".csv", ".tex"):
            assert (repo / "reports" / "tables" / f"{stem}{suffix}").stat().st_size > 0
    assert (repo / "reports" / "figures" / "depth" / "nyu_qualitative.png").stat().st_size > 0
    assert (repo / "reports" / "README.md").is_file()
    for v in params["variants"]:
        assert (repo / "metrics" / "evaluate" / f"{v}.json").is_file()

    # issue 25 item 10: after a plain `dvc repro` every output file is a link to the cache, not a copy
    outputs = [p for top in ("data", "models") for p in (repo / top).rglob("*")
               if p.is_file() and p.name != ".gitignore"]  # DVC's own .gitignore files are no outputs
    copies = [str(p.relative_to(repo)) for p in outputs if not p.is_symlink() and p.stat().st_nlink < 2]
    assert len(outputs) > 50 and copies == [], copies[:10]

    second = run([str(BIN / "dvc"), "repro"], repo, env)
    assert "Running stage" not in second.stdout
    status = run([str(BIN / "dvc"), "status"], repo, env)
    assert "Data and pipelines are up to date" in status.stdout, status.stdout

    killed_stages_resume_or_redo_identically(repo, params, env)


def killed_stages_resume_or_redo_identically(repo: Path, params: dict, env: dict[str, str]) -> None:
    """kill -9 inside `dvc repro -f -s` on the finished tiny repository: each killed stage, forced again,
    ends with the outputs of the uninterrupted run above (`flow_finetune` resuming from its state)."""
    dvc = str(BIN / "dvc")
    whole = load_flow_model(repo / "models" / "flow_patch.pt").state_dict()
    state = repo / "tmp" / "flow_finetune" / "patch.pt"
    kill_when([dvc, "repro", "-f", "-s", "flow_finetune@patch"], repo, env, state.exists)
    # forced: a plain `dvc repro` would check out the outputs dvc.lock still names (the run above) instead
    run([dvc, "repro", "-f", "-s", "flow_finetune@patch"], repo, env)
    metrics = json.loads((repo / "metrics" / "flow_finetune" / "patch.json").read_text())
    assert metrics["resumed_from"] >= 1 and not state.exists()
    resumed = load_flow_model(repo / "models" / "flow_patch.pt").state_dict()
    assert all(torch.equal(resumed[k], whole[k]) for k in whole)

    poses = Path(params["data"]["poses"])
    building = repo / poses.parent
    first = {p.relative_to(repo): p.read_bytes() for p in (repo / poses).rglob("*") if p.is_file()}

    def poses_under_way() -> bool:  # the stage's process has run for half a second (the tiny run takes ~2 s)
        return any("stages/poses.py" in " ".join(p.info["cmdline"] or [])
                   and time.time() - p.info["create_time"] > 0.5
                   for p in psutil.process_iter(["cmdline", "create_time"]))

    kill_when([dvc, "repro", "-f", "-s", "poses"], repo, env, poses_under_way)
    run([dvc, "repro", "-f", "-s", "poses"], repo, env)
    again = {p.relative_to(repo): p.read_bytes() for p in (repo / poses).rglob("*") if p.is_file()}
    assert not any(p.name.startswith(f".{poses.name}.") for p in building.iterdir())  # no temporaries left
    assert first and first == again
