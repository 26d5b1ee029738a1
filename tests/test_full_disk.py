"""A full disk (issue 25, item 7): one line naming the file and "no space left", and nothing half-written.
Before: `predict` said `30000 requested and 23520 written` (no file named, no "disk full") and left a frame
with 1 of its 3 files; `train_depth` ended in `RuntimeError: [enforce fail at inline_container.cc:672]`.

The disk is simulated: the writers fail as numpy and torch do when the disk is full, and
``shutil.disk_usage`` reports what a full disk reports. (Measured on a real 1 MB tmpfs in the issue note.)"""

from __future__ import annotations

import errno
import shutil
from collections import namedtuple
from pathlib import Path

import inference_data
import numpy as np
import pytest
import torch

from f2depth import io as io_mod
from f2depth.cli import main
from f2depth.stage import run_stage

Usage = namedtuple("Usage", "total used free")


@pytest.fixture
def full_disk(monkeypatch):
    """After ``full_disk.after`` successful np.save calls, the disk is full."""
    real_save, real_usage = np.save, shutil.disk_usage
    state = {"after": 0, "saves": 0}

    def save(file, arr, *args, **kwargs):
        state["saves"] += 1
        if state["saves"] > state["after"]:
            raise OSError(f"{arr.size * 4} requested and {arr.size * 3} written")  # numpy's words
        return real_save(file, arr, *args, **kwargs)

    def usage(path):
        real = real_usage(path)
        return Usage(real.total, real.total, 0) if state["saves"] > state["after"] else real

    monkeypatch.setattr(np, "save", save)
    monkeypatch.setattr(io_mod.shutil, "disk_usage", usage)
    return state


def test_predict_on_a_full_disk_names_the_file_and_leaves_whole_frames(tmp_path, capfd, full_disk):
    torch.set_num_threads(1)
    ckpt = inference_data.make_checkpoint(tmp_path / "m.pt", seed=5)
    inference_data.write_images(tmp_path / "in", 3)
    full_disk["after"] = 1  # the first frame's .npy fits, the second's does not
    code = main(["predict", "--model", str(ckpt), "--input", str(tmp_path / "in"), "--output",
                 str(tmp_path / "out"), "--batch-size", "1", "--no-progress"])
    err = capfd.readouterr().err.splitlines()
    assert code == 1 and err == [
        f"f2depth predict: error: {tmp_path / 'out' / 'img_01_depth.npy'}: no space left on device (0.0 MB "
        "free); nothing half-written was kept: free some space or write to another disk"]
    files = sorted(p.name for p in (tmp_path / "out").iterdir() if p.name != io_mod.OUTPUT_MARKER)
    assert files == ["img_00_depth.npy", "img_00_depth_color.png", "img_00_depth_mm.png"]  # no img_01 file


def test_a_checkpoint_on_a_full_disk_ends_a_stage_in_one_line(tmp_path, capsys, monkeypatch):
    real_usage = shutil.disk_usage

    def enforce_fail(obj, f, *args, **kwargs):
        Path(f).write_bytes(b"partial")
        raise RuntimeError("[enforce fail at inline_container.cc:672] . unexpected pos 64 vs 0")

    monkeypatch.setattr(torch, "save", enforce_fail)
    monkeypatch.setattr(io_mod.shutil, "disk_usage", lambda p: Usage(real_usage(p).total, 0, 1000))
    target = tmp_path / "models" / "seed0.pt"

    def stage_main(argv):
        io_mod.torch_save(target, {"weights": torch.zeros(3)})

    with pytest.raises(SystemExit) as exit_info:
        run_stage("train_depth", stage_main, ["train_depth.py"])
    assert exit_info.value.code == 1
    assert capsys.readouterr().err.splitlines() == [
        f"train_depth: {target}: no space left on device (0.0 MB free); nothing half-written was kept: free "
        "some space or write to another disk"]
    assert list(target.parent.iterdir()) == []  # the temporary is gone


def test_other_write_failures_keep_their_own_error(tmp_path, monkeypatch):
    def enforce_fail(obj, f, *args, **kwargs):
        raise RuntimeError("some other torch failure")

    monkeypatch.setattr(torch, "save", enforce_fail)  # the disk has room: not a full disk
    with pytest.raises(RuntimeError, match="some other torch failure"):
        io_mod.torch_save(tmp_path / "x.pt", {})
    full = io_mod.no_space(tmp_path / "y", OSError(errno.ENOSPC, "No space left on device"))
    assert full.errno == errno.ENOSPC and full.filename == str(tmp_path / "y")
    assert io_mod.no_space(tmp_path / "y", ValueError("bad value")) is None
