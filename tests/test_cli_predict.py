"""Tests for the ``f2depth`` command line (f2depth.cli): --help everywhere, predict on images, folders and
video, scaling options, point clouds with given intrinsics, export and predict --onnx."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import inference_data
import numpy as np
import pytest

from f2depth.cli import main


@pytest.fixture(scope="module")
def ckpt(tmp_path_factory):
    return inference_data.make_checkpoint(tmp_path_factory.mktemp("model") / "depth.pt", seed=2)


@pytest.mark.parametrize("command", [[], ["predict"], ["export"], ["reconstruct"]])
def test_help_for_every_subcommand(command, capsys):
    with pytest.raises(SystemExit) as info:
        main([*command, "--help"])
    assert info.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: f2depth") and "exit codes" in out
    if command == ["predict"]:
        assert "RELATIVE" in out and "--scale-from" in out and "median(reference) / median(prediction)" in out


def test_console_script_is_installed():
    script = shutil.which("f2depth", path=str(Path(sys.executable).parent))
    assert script is not None, "reinstall the package (pip install -e .) to create the f2depth script"
    run = subprocess.run([script, "--help"], capture_output=True, text=True, timeout=60)
    assert run.returncode == 0 and "predict" in run.stdout


def test_predict_folder_writes_consistent_files(ckpt, tmp_path, capsys):
    inference_data.write_images(tmp_path / "in", 3, hw=(50, 70))
    code = main(["predict", "--model", str(ckpt), "--input", str(tmp_path / "in"), "--output",
                 str(tmp_path / "out"), "--batch-size", "2", "--device", "cpu", "--no-progress"])
    assert code == 0
    assert "wrote 3 frame(s)" in capsys.readouterr().out
    for i in range(3):
        metres = np.load(tmp_path / "out" / f"img_{i:02d}_depth.npy")
        mm = cv2.imread(str(tmp_path / "out" / f"img_{i:02d}_depth_mm.png"), cv2.IMREAD_UNCHANGED)
        assert metres.shape == mm.shape == (50, 70) and mm.dtype == np.uint16
        assert np.abs(mm / 1000.0 - metres).max() <= 0.0005 + 1e-6
        assert cv2.imread(str(tmp_path / "out" / f"img_{i:02d}_depth_color.png")).shape == (50, 70, 3)
    summary = json.loads((tmp_path / "out" / "predict.json").read_text())
    assert summary["frames"] == 3 and summary["metric"] is False and summary["intrinsics"] is None


def test_predict_video_with_scale_and_batching(ckpt, tmp_path):
    inference_data.write_video(tmp_path / "clip.avi", 4)
    common = ["predict", "--model", str(ckpt), "--input", str(tmp_path / "clip.avi"), "--no-progress"]
    assert main([*common, "--output", str(tmp_path / "one"), "--batch-size", "1"]) == 0
    assert main([*common, "--output", str(tmp_path / "four"), "--batch-size", "4", "--scale", "3"]) == 0
    for i in range(4):
        a = np.load(tmp_path / "one" / f"frame_{i:06d}_depth.npy")
        b = np.load(tmp_path / "four" / f"frame_{i:06d}_depth.npy")
        assert a.shape == (60, 80)
        np.testing.assert_allclose(b, 3 * a, rtol=1e-5)


def test_predict_image_ply_with_given_intrinsics_and_scale_from(ckpt, tmp_path):
    (image,) = inference_data.write_images(tmp_path, 1, hw=(40, 60))
    ref = np.full((40, 60), 2000, np.uint16)
    cv2.imwrite(str(tmp_path / "ref.png"), ref)
    code = main(["predict", "--model", str(ckpt), "--input", str(image), "--output", str(tmp_path / "out"),
                 "--ply", "--fx", "70", "--fy", "72", "--cx", "29", "--cy", "20.5", "--scale-from",
                 str(tmp_path / "ref.png"), "--post-process", "--no-progress"])
    assert code == 0
    depth = np.load(tmp_path / "out" / "img_00_depth.npy")
    assert np.median(depth) == pytest.approx(2.0, rel=1e-5)  # median scaling to the reference
    points, colours = inference_data.read_ply_points(tmp_path / "out" / "img_00_points.ply")
    K = np.array([[70.0, 0, 29.0], [0, 72.0, 20.5], [0, 0, 1]])
    uv = (K @ points.T.astype(np.float64)).T
    v, u = np.mgrid[0:40, 0:60]
    np.testing.assert_allclose(uv[:, 0] / uv[:, 2], u.ravel(), atol=1e-3)
    np.testing.assert_allclose(uv[:, 1] / uv[:, 2], v.ravel(), atol=1e-3)
    np.testing.assert_allclose(points[:, 2], depth.ravel(), rtol=1e-6)
    rgb = cv2.cvtColor(cv2.imread(str(image)), cv2.COLOR_BGR2RGB)
    np.testing.assert_array_equal(colours, rgb.reshape(-1, 3))
    summary = json.loads((tmp_path / "out" / "predict.json").read_text())
    assert summary["intrinsics"]["40x60"] == K.tolist() and summary["post_process"] is True


def test_export_then_predict_onnx_gives_the_same_depth(ckpt, tmp_path, capsys):
    onnx_path = tmp_path / "d.onnx"
    assert main(["export", "--model", str(ckpt), "--format", "onnx", "--output", str(onnx_path)]) == 0
    out = capsys.readouterr().out
    assert "64×96, dynamic batch" in out and "max abs difference" in out
    inference_data.write_images(tmp_path / "in", 2)
    for flag, model in (("--model", ckpt), ("--onnx", tmp_path / "d.onnx")):
        assert main(["predict", flag, str(model), "--input", str(tmp_path / "in"), "--output",
                     str(tmp_path / flag[2:]), "--no-progress"]) == 0
    for i in range(2):
        a = np.load(tmp_path / "model" / f"img_{i:02d}_depth.npy")
        b = np.load(tmp_path / "onnx" / f"img_{i:02d}_depth.npy")
        np.testing.assert_allclose(b, a, rtol=1e-4)
    assert json.loads((tmp_path / "onnx" / "predict.json").read_text())["backend"] == "onnxruntime"


def test_usage_errors_exit_2(ckpt, tmp_path, capsys):
    for argv in (["predict", "--input", "x", "--output", "y"],  # no model
                 ["predict", "--model", str(ckpt), "--input", "x", "--output", "y", "--scale", "-1"],
                 ["predict", "--model", str(ckpt), "--onnx", "f", "--input", "x", "--output", "y"],
                 ["export", "--model", str(ckpt), "--output", "o", "--height", "100"]):
        with pytest.raises(SystemExit) as info:
            main(argv)
        assert info.value.code == 2
    capsys.readouterr()
