"""Tests for the ``f2depth`` command line (f2depth.cli): --help everywhere, predict on images, folders and
video, scaling options, point clouds with given intrinsics, export and predict --onnx."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import fakes
import inference_data
import numpy as np
import pytest

from f2depth.cli import main
from f2depth.inference.backends import load_backend
from f2depth.inference.predict import Predictor, PredictSettings, run_predict
from f2depth.ingest.sources import Frame
from f2depth.io import OUTPUT_MARKER


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


# ---- issue 53: one run's frames per folder, nothing of the user's deleted, damaged models refused ---------


def _err_line(capfd) -> str:
    err = capfd.readouterr().err.splitlines()
    assert len(err) == 1, err
    return err[0]


def _stems(folder: Path) -> list[str]:
    return sorted(p.name[: -len("_depth.npy")] for p in folder.glob("*_depth.npy"))


def test_a_new_run_replaces_the_frames_of_the_last_one(ckpt, tmp_path, capfd):
    """Issue 53 item 2. Before: predicting 5 images into a folder that held 60 kept the 55 stale depth maps
    under a predict.json that said 5. Now the folder holds the new run's frames only; a folder of an
    earlier predict written before the output marker existed is recognised by its file names."""
    inference_data.write_images(tmp_path / "many", 8, hw=(24, 32))
    inference_data.write_images(tmp_path / "few", 3, hw=(24, 32), seed=50)
    common = ["--model", str(ckpt), "--device", "cpu", "--no-progress"]
    out = tmp_path / "out"
    assert main(["predict", *common, "--input", str(tmp_path / "many"), "--output", str(out)]) == 0
    assert len(_stems(out)) == 8 and (out / OUTPUT_MARKER).read_text() == "predict\n"
    (out / OUTPUT_MARKER).unlink()  # as an output of before the marker: still ours by its names
    assert main(["predict", *common, "--input", str(tmp_path / "few"), "--output", str(out)]) == 0
    assert _stems(out) == ["img_00", "img_01", "img_02"] and len(list(out.iterdir())) == 3 * 3 + 2
    assert json.loads((out / "predict.json").read_text())["frames"] == 3
    few = {s: np.load(out / f"{s}_depth.npy") for s in _stems(out)}
    assert main(["predict", *common, "--input", str(tmp_path / "many"), "--output", str(out)]) == 0
    assert len(_stems(out)) == 8 and not np.array_equal(np.load(out / "img_00_depth.npy"), few["img_00"])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["few", "many", "out"]  # no temporaries, no lock
    capfd.readouterr()


def test_a_second_run_into_the_same_folder_at_once_is_refused(ckpt, tmp_path, capfd):
    """Issue 53 item 2. Before: two predict runs into one folder at once (different models) left 156 frames
    of one and 44 of the other under a predict.json naming one. Now the second is refused in one line while
    the first runs, and the folder holds the first run's frames only."""
    other = inference_data.make_checkpoint(tmp_path / "other.pt", seed=9)
    images = inference_data.write_images(tmp_path / "in", 4, hw=(24, 32))
    out = tmp_path / "out"
    backend = load_backend(ckpt, None, "cpu")
    second = []

    def frames():  # the first run's frames; after its first one, a second run into the same folder
        for i, path in enumerate(images):
            if i == 1:
                second.append(main(["predict", "--model", str(other), "--input", str(tmp_path / "in"),
                                    "--output", str(out), "--device", "cpu", "--no-progress"]))
                second.append(_err_line(capfd))
            yield Frame(path.stem, fakes.smooth_image((24, 32), i), str(path))

    summary = run_predict(frames(), Predictor(backend), PredictSettings(out, batch_size=1, progress=False))
    assert second[0] == 1 and second[1] == (
        f"f2depth predict: error: {out}: another f2depth run (pid {os.getpid()}) is writing this folder now; "
        "wait for it to end or give --output another folder (nothing was changed)")
    assert summary["frames"] == 4 and summary["model"] == str(ckpt)
    assert _stems(out) == [p.stem for p in images]
    assert json.loads((out / "predict.json").read_text())["model"] == str(ckpt)


def test_predict_replaces_no_folder_of_the_users_and_no_input(ckpt, tmp_path, capfd):
    """Issue 53 item 1 for predict, which now swaps its folder in: a non-empty folder it did not write, and
    one that holds the input, the model or the reference depth, are refused in one line, nothing touched."""
    (image,) = inference_data.write_images(tmp_path / "work", 1, hw=(24, 32))
    model = tmp_path / "work" / "m.pt"
    shutil.copyfile(ckpt, model)
    (tmp_path / "work" / "thesis.tex").write_text("four years of work")
    inference_data.write_images(tmp_path / "in", 1, hw=(24, 32))
    before = sorted((p.name, p.read_bytes()) for p in (tmp_path / "work").iterdir())
    lost = "which replacing the output folder with this run's would delete"
    apart = "give --output a folder apart from the inputs (nothing was changed)"
    work = tmp_path / "work"
    for argv, expected in (
        (["--model", str(ckpt), "--input", str(tmp_path / "in")],
         f"{work}: holds files that f2depth predict did not write (no .f2depth-output marker), and this run "
         "would replace the whole folder; give --output a new or empty folder (nothing was changed)"),
        (["--model", str(ckpt), "--input", str(image)], f"{work}: holds the input {image}, {lost}; {apart}"),
        (["--model", str(model), "--input", str(tmp_path / "in")],
         f"{work}: holds the input {model}, {lost}; {apart}"),
    ):
        code = main(["predict", *argv, "--output", str(work), "--device", "cpu", "--no-progress"])
        assert (code, _err_line(capfd)) == (1, f"f2depth predict: error: {expected}")
    assert sorted((p.name, p.read_bytes()) for p in work.iterdir()) == before


def test_a_damaged_model_file_is_refused(ckpt, tmp_path, capfd):
    """Issue 53 item 2. Before: a model file with 64 flipped bytes predicted depth up to 7.2× off, rc 0. Now
    every checkpoint carries the sha256 of its weights; a mismatch is one line naming the file. A model
    written before the digest existed still loads."""
    damaged = tmp_path / "damaged.pt"
    shutil.copyfile(ckpt, damaged)
    fakes.flip_weight_bytes(damaged, 64)
    inference_data.write_images(tmp_path / "in", 1, hw=(24, 32))
    code = main(["predict", "--model", str(damaged), "--input", str(tmp_path / "in"), "--output",
                 str(tmp_path / "out"), "--device", "cpu", "--no-progress"])
    assert (code, _err_line(capfd)) == (1, f"f2depth predict: error: {damaged}: damaged: its weights do "
                                           "not match the sha256 digest written with them (the file changed "
                                           "after it was written); re-run the stage that wrote it (`dvc "
                                           "repro train_depth`)")
    assert not (tmp_path / "out").exists()
    import torch

    older = torch.load(ckpt, weights_only=True)
    del older["weights_sha256"]  # as written before the digest existed
    torch.save(older, tmp_path / "older.pt")
    assert main(["predict", "--model", str(tmp_path / "older.pt"), "--input", str(tmp_path / "in"),
                 "--output", str(tmp_path / "out"), "--device", "cpu", "--no-progress"]) == 0
    capfd.readouterr()


def test_far_depth_is_clipped_below_the_no_depth_code(ckpt, tmp_path, capfd):
    """Issue 53 item 5. Before: depth beyond 65.535 m was written as 65535 mm, the "no depth" code, so those
    pixels read back as missing (--scale-from of such a map skipped them). Now they are 65534 mm, counted in
    predict.json (depth_mm) and said in one warning."""
    inference_data.write_images(tmp_path / "in", 1, hw=(24, 32))
    code = main(["predict", "--model", str(ckpt), "--input", str(tmp_path / "in"), "--output",
                 str(tmp_path / "out"), "--scale", "1000", "--device", "cpu", "--no-progress"])
    captured = capfd.readouterr()
    assert code == 0
    metres = np.load(tmp_path / "out" / "img_00_depth.npy")
    mm = cv2.imread(str(tmp_path / "out" / "img_00_depth_mm.png"), cv2.IMREAD_UNCHANGED)
    far = metres > 65.5345
    assert far.any() and (mm[far] == 65534).all() and mm.max() == 65534 and mm.min() > 0
    summary = json.loads((tmp_path / "out" / "predict.json").read_text())
    assert summary["depth_mm"]["max"] == 65534 and summary["depth_mm"]["clipped_pixels"] == int(far.sum())
    warning = [line for line in captured.err.splitlines() if "clipped" in line]
    assert warning == [f"f2depth predict: warning: {int(far.sum())} pixel(s) lie beyond 65.534 m or below 1 "
                       "mm: their value in <name>_depth_mm.png is clipped to 65534 or 1 mm (65535 and 0 mean "
                       "no depth); <name>_depth.npy holds the metres"]
