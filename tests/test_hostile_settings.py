"""Bad settings a user can write end a stage with one line naming the file and the key, before any work
(issue 25, items 4 and 9). Each test states the behaviour before the fix."""

from __future__ import annotations

import copy
import subprocess
import sys
from pathlib import Path

import pytest
import torch
import train_fakes
import yaml

from f2depth import params as P
from f2depth.errors import DataError
from f2depth.stage import run_stage
from f2depth.train.distributed import DistContext
from f2depth.train.settings import settings_from_params

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def setup(tmp_path):
    prep = train_fakes.write_prepared(tmp_path / "prepared", hw=(64, 64), scenes=1, frames=6)
    mat, splits = train_fakes.write_nyu_test(tmp_path, n=3)
    flow = train_fakes.write_flow_model(tmp_path / "flow.pt")
    path = train_fakes.write_params(tmp_path, prep, mat, splits, flow, epochs=1, seeds=[3])
    return tmp_path, path


def edited(path: Path, key: str, value) -> Path:
    params = yaml.safe_load(path.read_text())
    node = params
    *parents, last = key.split(".")
    for part in parents:
        node = node[part]
    node[last] = copy.deepcopy(value)
    out = path.with_name(f"edited_{last}.yaml")
    out.write_text(yaml.safe_dump(params, sort_keys=False))
    return out


@pytest.mark.parametrize("key,value,expected", [
    ("train_depth.lr", [-1e-4, 1e-5, 1e-6], r"train_depth\.lr must be a list of positive learning rates"),
    ("train_depth.lr", [1e-4, 1e-5], r"train_depth\.lr has 2 rates but lr_epochs 3 phases"),
    ("train_depth.lr_epochs", [0, 0, 0], r"train_depth\.lr_epochs must be epoch counts >= 0 with a positive"),
    ("train_depth.lr_epochs", [27, -1, 2], r"train_depth\.lr_epochs must be epoch counts >= 0"),
])
def test_learning_rate_schedules_are_checked_by_the_loader(setup, key, value, expected):
    """Before: a ValueError traceback (14–17 lines) from LRSchedule, after the data, the flow teacher and
    the validator were set up. Now the params loader refuses it in one line naming the file."""
    _, path = setup
    bad = edited(path, key, value)
    with pytest.raises(P.ParamsError, match=f"^{bad}: {expected}"):
        settings_from_params(P.load(bad), "full")


def test_the_stage_says_a_bad_schedule_in_one_line(setup):
    root, path = setup
    bad = edited(path, "train_depth.lr", [1e-4, 1e-5])
    run = subprocess.run([sys.executable, str(ROOT / "stages" / "train_depth.py"), "--variant", "baseline",
                          "--params", str(bad), "--models", str(root / "models"), "--metrics",
                          str(root / "metrics")], capture_output=True, text=True,
                         env={"F2DEPTH_MLFLOW": "0", "OMP_NUM_THREADS": "1", "PATH": "/usr/bin:/bin"})
    assert run.returncode == 1
    assert run.stderr.splitlines() == [
        f"train_depth: {bad}: train_depth.lr has 2 rates but lr_epochs 3 phases; give one epoch count per "
        "rate (the paper: lr [1e-4, 1e-5, 1e-6], lr_epochs [27, 15, 2])"]
    assert not (root / "models").exists()


def _nothing_may_be_set_up(monkeypatch):
    import f2depth.train.run as run_module

    def must_not_run(*args, **kwargs):
        raise AssertionError("set up before the batch size was checked")

    for name in ("make_validator", "fit"):
        monkeypatch.setattr(run_module, name, must_not_run)
    monkeypatch.setattr(run_module.FlowTeacher, "load", must_not_run)
    return run_module


def test_a_batch_larger_than_the_training_set_is_refused_before_setup(setup, monkeypatch, tmp_path):
    """Before: a 26-line traceback from the sampler, after the teacher and validator were built."""
    _, path = setup
    run_module = _nothing_may_be_set_up(monkeypatch)
    s = settings_from_params(P.load(edited(path, "train_depth.batch_size", 64)), "full")
    with pytest.raises(DataError, match=r"prepared/tuples\.csv: 4 training tuples are fewer than one "
                                        r"batch of train_depth\.batch_size 64; lower "
                                        r"train_depth\.batch_size"):
        run_module.train_variant(s, tmp_path / "build")


def test_a_batch_that_does_not_divide_among_processes_is_refused_before_setup(setup, monkeypatch, tmp_path):
    """Before: `torchrun --nproc_per_node 2` with batch 3 printed a 66-line traceback from both ranks."""
    torch.set_num_threads(1)
    _, path = setup
    run_module = _nothing_may_be_set_up(monkeypatch)
    s = settings_from_params(P.load(edited(path, "train_depth.batch_size", 3)), "full")
    with pytest.raises(DataError, match=r"train_depth\.batch_size 3 does not divide among the 2 processes"):
        run_module.train_variant(s, tmp_path / "build", ctx=DistContext(rank=0, world_size=2))


@pytest.mark.parametrize("rank,lines", [("0", 1), ("1", 0)])
def test_only_rank_zero_writes_the_error_line(monkeypatch, capsys, rank, lines):
    monkeypatch.setenv("RANK", rank)

    def main(argv):
        raise DataError("params.yaml", "something is wrong", "fix it")

    with pytest.raises(SystemExit) as exit_info:
        run_stage("train_depth", main, ["train_depth.py"])
    assert exit_info.value.code == 1
    err = capsys.readouterr().err.splitlines()
    assert err == ["train_depth: params.yaml: something is wrong; fix it"][:lines]


def test_a_depth_model_named_as_the_flow_teacher_is_one_line(setup, tmp_path):
    """Issue 25 item 4. Before: `variants.full.flow` naming a depth model ended in a 23-line CheckpointError
    traceback. Now a DataError (one line through run_stage) naming the file and the fix."""
    import inference_data

    from f2depth.errors import CheckpointError
    from f2depth.train.run import train_variant

    _, path = setup
    depth = inference_data.make_checkpoint(tmp_path / "depth.pt", seed=5)
    s = settings_from_params(P.load(edited(path, "variants.full.flow", str(depth))), "full")
    with pytest.raises(CheckpointError, match=rf"^{depth}: checkpoint format 'f2depth.depth', expected "
                                              r"'f2depth.flow'; pass a flow model"):
        train_variant(s, tmp_path / "build")
    assert issubclass(CheckpointError, DataError)
