"""Bad input to ``f2depth``: one line on stderr naming the file and the problem, exit code 1 (3 for a
missing optional dependency), no traceback, and the outputs written before the error stay valid."""

from __future__ import annotations

import os
import subprocess
import sys

import cv2
import fakes
import inference_data
import numpy as np
import pytest
import torch

from f2depth.cli import main
from f2depth.io import OUTPUT_MARKER


@pytest.fixture(scope="module")
def ckpt(tmp_path_factory):
    return inference_data.make_checkpoint(tmp_path_factory.mktemp("model") / "depth.pt", seed=3)


def _bad_input(kind, root, ckpt):
    """(argv pieces for --input/--model/--onnx, the path the message must name, a problem phrase)."""
    if kind == "unreadable image":
        (path,) = inference_data.write_images(root, 1)
        fakes.truncate(path, 0.4)
        return ["--model", str(ckpt), "--input", str(path)], path, "truncated PNG"
    if kind == "empty folder":
        (root / "empty").mkdir()
        (root / "empty" / "notes.txt").write_text("no images here")
        return ["--model", str(ckpt), "--input", str(root / "empty")], root / "empty", "no images"
    if kind == "undecodable video":
        (root / "v.avi").write_bytes(np.random.default_rng(1).bytes(5000))
        return ["--model", str(ckpt), "--input", str(root / "v.avi")], root / "v.avi", "cannot open video"
    images = root / "in"
    inference_data.write_images(images, 1)
    if kind == "flow checkpoint":
        torch.save({"format": "f2depth.pwclite", "version": 1, "state_dict": {}, "config": {}, "params": {}},
                   root / "flow.pt")
        args = ["--model", str(root / "flow.pt"), "--input", str(images)]
        return args, root / "flow.pt", "not 'f2depth.depth'"
    if kind == "old checkpoint":
        data = torch.load(ckpt, weights_only=True)
        data["version"] = 0
        torch.save(data, root / "old.pt")
        return ["--model", str(root / "old.pt"), "--input", str(images)], root / "old.pt", "version 0"
    if kind == "not a checkpoint":
        (root / "junk.pt").write_bytes(b"junk")
        return ["--model", str(root / "junk.pt"), "--input", str(images)], root / "junk.pt", "not a readable"
    if kind == "not an onnx model":
        return ["--onnx", str(ckpt), "--input", str(images)], ckpt, "not a loadable ONNX model"
    raise AssertionError(kind)


KINDS = ["unreadable image", "empty folder", "undecodable video", "flow checkpoint", "old checkpoint",
         "not a checkpoint", "not an onnx model"]


@pytest.mark.parametrize("kind", KINDS)
def test_bad_input_one_line_exit_1(kind, ckpt, tmp_path, capfd):
    args, path, problem = _bad_input(kind, tmp_path, ckpt)
    code = main(["predict", *args, "--output", str(tmp_path / "out")])
    out, err = capfd.readouterr()
    assert code == 1
    lines = err.splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("f2depth predict: error: ") and str(path) in lines[0] and problem in lines[0]


def test_export_of_a_wrong_model(tmp_path, capfd):
    (tmp_path / "m.pt").write_bytes(b"junk")
    assert main(["export", "--model", str(tmp_path / "m.pt"), "--output", str(tmp_path / "m.onnx")]) == 1
    err = capfd.readouterr().err.splitlines()
    assert len(err) == 1 and "m.pt: not a readable torch checkpoint" in err[0]
    assert not (tmp_path / "m.onnx").exists()


def test_error_mid_folder_keeps_earlier_outputs_valid(ckpt, tmp_path, capfd):
    inference_data.write_images(tmp_path / "in", 4)
    fakes.truncate(tmp_path / "in" / "img_02.png", 0.5)
    code = main(["predict", "--model", str(ckpt), "--input", str(tmp_path / "in"), "--output",
                 str(tmp_path / "out"), "--batch-size", "1", "--ply"])
    err = capfd.readouterr().err.splitlines()
    assert code == 1 and len(err) == 1 and "img_02.png: truncated PNG" in err[0]
    names = sorted(p.name for p in (tmp_path / "out").iterdir() if p.name != OUTPUT_MARKER)
    assert names == sorted(f"img_0{i}{s}" for i in (0, 1) for s in
                           ("_depth.npy", "_depth_mm.png", "_depth_color.png", "_points.ply"))
    for i in (0, 1):
        assert np.load(tmp_path / "out" / f"img_0{i}_depth.npy").shape == (60, 80)
        mm = cv2.imread(str(tmp_path / "out" / f"img_0{i}_depth_mm.png"), cv2.IMREAD_UNCHANGED)
        assert mm.shape == (60, 80)


def test_missing_optional_dependency_exit_3(ckpt, tmp_path, capfd, monkeypatch):
    monkeypatch.setitem(sys.modules, "onnxruntime", None)
    inference_data.write_images(tmp_path / "in", 1)
    code = main(["predict", "--onnx", str(tmp_path / "x.onnx"), "--input", str(tmp_path / "in"), "--output",
                 str(tmp_path / "out")])
    err = capfd.readouterr().err.splitlines()
    assert code == 3 and len(err) == 1
    assert "needs the optional package 'onnxruntime'" in err[0] and "f2depth[onnx]" in err[0]


def test_subprocess_bad_video_no_traceback(ckpt, tmp_path):
    inference_data.write_video(tmp_path / "ok.avi", 3)
    data = (tmp_path / "ok.avi").read_bytes()
    (tmp_path / "cut.avi").write_bytes(data[: len(data) // 4])  # OpenCV's AVI parser complains on stderr
    run = subprocess.run(
        [sys.executable, "-m", "f2depth.cli", "predict", "--model", str(ckpt), "--input",
         str(tmp_path / "cut.avi"), "--output", str(tmp_path / "out")],
        capture_output=True, text=True, timeout=300, env={**os.environ, "PYTHONWARNINGS": "ignore"},
    )
    assert run.returncode == 1
    assert "Traceback" not in run.stderr
    lines = run.stderr.splitlines()
    assert len(lines) == 1 and f"{tmp_path / 'cut.avi'}: cannot " in lines[0], run.stderr


def test_interrupt_exit_130(ckpt, tmp_path, capfd, monkeypatch):
    import f2depth.inference.predict as predict_mod

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(predict_mod, "run_predict", interrupted)
    inference_data.write_images(tmp_path / "in", 1)
    code = main(["predict", "--model", str(ckpt), "--input", str(tmp_path / "in"), "--output",
                 str(tmp_path / "out")])
    err = capfd.readouterr().err.splitlines()
    assert code == 130
    assert err == ["f2depth predict: error: interrupted; every file written so far is complete"]
