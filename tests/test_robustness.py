"""Hostile-but-honest inputs (issue 17, items 4 and 5 and the smaller points): every probe ends in one line
naming the file and the fix with a non-zero exit, writes nothing that looks valid, or — where the input
is merely short — says so in one warning line. Each test states the behaviour before the fix."""

from __future__ import annotations

import json
import logging
import struct
import zlib
from pathlib import Path

import cv2
import fakes
import inference_data
import numpy as np
import pytest
import torch
import train_fakes

from f2depth import params as P
from f2depth.cli import main
from f2depth.depth import load_checkpoint
from f2depth.errors import DataError
from f2depth.flow import load_flow_model
from f2depth.flow.net.checkpoint import CheckpointError
from f2depth.formats import writable as writable_mod
from f2depth.formats.images import MAX_PIXELS, header_hw, read_image
from f2depth.formats.samples import EvalSample
from f2depth.inference import limits
from f2depth.inference.backends import TorchBackend
from f2depth.inference.predict import Predictor, PredictSettings, run_predict
from f2depth.inference.sequences import read_gt_npz
from f2depth.ingest.sources import Frame
from f2depth.io import OUTPUT_MARKER
from f2depth.keypoints import KeypointFile, KeypointFileError, save_keypoints
from f2depth.protocols import campus as campus_eval
from f2depth.protocols import nyu, sevenscenes
from f2depth.train.data import DataConfig, TupleDataset
from f2depth.train.run import train_variant
from f2depth.train.settings import settings_from_params


@pytest.fixture(scope="module")
def ckpt(tmp_path_factory):
    torch.set_num_threads(1)
    return inference_data.make_checkpoint(tmp_path_factory.mktemp("model") / "depth.pt", seed=5)


@pytest.fixture
def images(tmp_path):
    inference_data.write_images(tmp_path / "in", 2)
    return tmp_path / "in"


def one_error_line(capfd, command: str) -> str:
    err = capfd.readouterr().err.splitlines()
    assert len(err) == 1, err
    assert err[0].startswith(f"f2depth {command}: error: "), err[0]
    return err[0]


def usage_error(argv: list[str], capsys) -> str:
    """argv must fail as a usage error: exit 2 (from argparse or from main) and exactly one stderr line."""
    try:
        code = main(argv)
    except SystemExit as exc:
        code = exc.code
    assert code == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1, err
    return err[0]


def png_with_header(path: Path, width: int, height: int) -> Path:
    """A complete, well-formed PNG chunk chain whose IHDR claims width × height (the pixels are absent)."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\0" * 64))
                     + chunk(b"IEND", b""))
    return path


# ---- 4. CLI paths that escaped the one-line contract -----------------------------------------------------


def test_huge_png_header_is_refused_before_decoding(ckpt, tmp_path, capfd):
    # before: cv2.imdecode raised cv2.error (pixels <= CV_IO_MAX_IMAGE_PIXELS), a 30-line traceback
    giant = png_with_header(tmp_path / "giant.png", 100_000, 100_000)
    with pytest.raises(DataError, match=r"giant\.png: its header claims 100000×100000 pixels"):
        read_image(giant)
    code = main(["predict", "--model", str(ckpt), "--input", str(giant), "--output", str(tmp_path / "out")])
    line = one_error_line(capfd, "predict")
    assert code == 1 and str(giant) in line and "100 megapixels" in line
    assert list((tmp_path / "out").iterdir()) == []  # nothing written
    # just under the limit the header is accepted (the check is on the header, not on the file size)
    side = int(MAX_PIXELS ** 0.5)
    assert header_hw("x.png", png_with_header(tmp_path / "ok.png", side, side).read_bytes()) == (side, side)


@pytest.mark.parametrize("ext", [".jpg", ".ppm", ".bmp", ".tif", ".webp"])
def test_header_size_of_every_supported_format(ext):
    ok, buf = cv2.imencode(ext, np.zeros((37, 53, 3), np.uint8))
    assert ok and header_hw(f"x{ext}", buf.tobytes()) == (37, 53)


def test_forged_jpeg_frame_header_is_refused(tmp_path):
    ok, buf = cv2.imencode(".jpg", np.zeros((16, 16, 3), np.uint8))
    data = bytearray(buf.tobytes())
    sof = next(i for i in range(2, len(data) - 1) if data[i] == 0xFF and data[i + 1] == 0xC0)
    data[sof + 5:sof + 9] = struct.pack(">HH", 60000, 60000)  # height, width
    (tmp_path / "forged.jpg").write_bytes(bytes(data))
    with pytest.raises(DataError, match=r"forged\.jpg: its header claims 60000×60000 pixels"):
        read_image(tmp_path / "forged.jpg")


def test_device_is_validated(ckpt, images, tmp_path, capsys):
    # before: --device foo reached torch (`Expected one of cpu, cuda, ... device type`, 28-line traceback)
    base = ["predict", "--model", str(ckpt), "--input", str(images), "--output", str(tmp_path / "out")]
    line = usage_error([*base, "--device", "foo"], capsys)
    assert "--device: unknown device 'foo'" in line and "cuda:N" in line
    beyond = f"cuda:{torch.cuda.device_count()}"  # never exists: no CUDA here, or one index too far
    line = usage_error([*base, "--device", beyond], capsys)
    assert beyond in line and ("CUDA is not available" in line or "CUDA device(s)" in line)
    assert not (tmp_path / "out").exists()
    assert main([*base, "--device", "cpu", "--no-progress"]) == 0


@pytest.mark.parametrize(("flags", "phrase"), [
    (["--height", "32", "--width", "32"], "--height: must be a multiple of 32 in 64..4096, got 32"),
    (["--height", "32000", "--width", "32000"], "--height: must be a multiple of 32 in 64..4096, got 32000"),
    (["--opset", "1"], "--opset: ONNX opset must be in 9..20"),
    (["--opset", "99"], "--opset: ONNX opset must be in 9..20"),
    (["--height", "4096", "--width", "4096"], "export size 4096×4096: at most 4194304 pixels"),
])
def test_export_sizes_and_opsets_are_bounded(ckpt, tmp_path, capsys, flags, phrase):
    # before: 32×32 and opsets 1/99 were torch tracebacks (106, 41, 45 lines); 32000×32000 ran until the
    # kernel killed it at 23 GB
    line = usage_error(["export", "--model", str(ckpt), "--output", str(tmp_path / "m.onnx"), *flags], capsys)
    assert phrase in line
    assert not (tmp_path / "m.onnx").exists()


def test_export_bounds_are_real(ckpt, tmp_path):
    """The documented opset range exports and passes the parity check at both ends."""
    model = load_checkpoint(ckpt)
    from f2depth.inference.export import export_onnx

    for opset in (limits.MIN_OPSET, limits.MAX_OPSET):
        parity = export_onnx(model, tmp_path / f"op{opset}.onnx", opset=opset)
        assert parity.max_rel < 1e-4
    with pytest.raises(ValueError, match="opset 8 is not supported"):
        export_onnx(model, tmp_path / "op8.onnx", opset=limits.MIN_OPSET - 1)
    with pytest.raises(ValueError, match="each side must lie in 64..4096"):
        export_onnx(model, tmp_path / "small.onnx", height=32, width=96)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["op20.onnx", "op9.onnx"]


@pytest.mark.parametrize(("error", "phrase"), [
    (MemoryError(), "out of memory"),
    (RuntimeError("CUDA out of memory. Tried to allocate 2 GiB\nsecond line\nthird"),
     "RuntimeError: CUDA out of memory. Tried to allocate 2 GiB; every file written so far is complete"),
])
def test_last_resort_handler_is_one_line(ckpt, images, tmp_path, capfd, monkeypatch, error, phrase):
    import f2depth.inference.predict as predict_mod

    def fail(*args, **kwargs):
        raise error

    monkeypatch.setattr(predict_mod, "run_predict", fail)
    code = main(["predict", "--model", str(ckpt), "--input", str(images), "--output", str(tmp_path / "out")])
    assert code == 1 and phrase in one_error_line(capfd, "predict")


def test_usage_errors_are_one_line(ckpt, capsys):
    argv = ["predict", "--model", str(ckpt), "--input", "x", "--output", "y", "--batch-size", "x"]
    line = usage_error(argv, capsys)
    assert line.startswith("f2depth predict: error: argument --batch-size: expected an integer, got 'x'")
    assert line.endswith("(see `f2depth predict --help`)")


# ---- 5. Silent wrong numbers --------------------------------------------------------------------------


def test_checkpoint_with_nan_weights_is_refused(ckpt, images, tmp_path, capfd):
    # before: exit 0, depth files full of NaN (the mm PNG 0) and a numpy cast warning
    data = torch.load(ckpt, weights_only=True)
    data["state_dict"]["depth_decoder.dispconv.bias"] = torch.full_like(
        data["state_dict"]["depth_decoder.dispconv.bias"], float("nan"))
    torch.save(data, tmp_path / "nan.pt")
    with pytest.raises(ValueError, match=r"nan\.pt: 1 non-finite weight\(s\) .* first depth_decoder\."):
        load_checkpoint(tmp_path / "nan.pt")
    code = main(["predict", "--model", str(tmp_path / "nan.pt"), "--input", str(images), "--output",
                 str(tmp_path / "out")])
    line = one_error_line(capfd, "predict")
    assert code == 1 and str(tmp_path / "nan.pt") in line and "retrain" in line
    assert not (tmp_path / "out").exists()


class BrokenAfter:
    """A backend (the DepthBackend protocol) that predicts 2 m, then NaN from call ``bad_call`` on."""

    name, source, input_hw, min_depth, max_depth = "fake", "broken.onnx", (32, 32), 0.1, 10.0

    def __init__(self, bad_call: int) -> None:
        self.calls, self.bad_call = 0, bad_call

    def depth(self, img: torch.Tensor) -> torch.Tensor:
        self.calls += 1
        value = float("nan") if self.calls >= self.bad_call else 2.0
        return torch.full((img.shape[0], 1, *img.shape[2:]), value)


def test_non_finite_prediction_stops_before_writing_that_batch(tmp_path):
    frames = [Frame(f"f{i}", fakes.smooth_image((20, 30), i), f"cam/f{i}.png") for i in range(4)]
    with pytest.raises(DataError, match=r"cam/f2\.png: the network predicted 600 non-finite .* broken\.onnx"):
        run_predict(frames, Predictor(BrokenAfter(2)), PredictSettings(tmp_path / "out", batch_size=2))
    names = sorted(p.name for p in (tmp_path / "out").iterdir() if p.name != OUTPUT_MARKER)
    suffixes = ("_depth.npy", "_depth_mm.png", "_depth_color.png")
    assert names == sorted(f"f{i}{s}" for i in (0, 1) for s in suffixes)
    np.testing.assert_allclose(np.load(tmp_path / "out" / "f0_depth.npy"), 2.0, rtol=1e-6)


def test_non_finite_scale_is_refused(ckpt, images, tmp_path, capsys):
    # before: --scale inf was accepted (exit 0, "scale inf, metric", every depth saturated)
    for value in ("inf", "nan", "-inf"):
        line = usage_error(["predict", "--model", str(ckpt), "--input", str(images), "--output",
                            str(tmp_path / "out"), f"--scale={value}"], capsys)
        assert "--scale: must be a finite number" in line
    with pytest.raises(ValueError, match="scale must be finite and > 0"):
        run_predict([], Predictor(TorchBackend.from_checkpoint(ckpt)),
                    PredictSettings(tmp_path / "out", scale=float("inf")))
    assert not (tmp_path / "out").exists()


def test_truncated_video_is_reported(ckpt, tmp_path, capfd):
    # before: exit 0 and "wrote 5 frame(s)" for a 12-frame video cut at 55 %, without a word
    inference_data.write_video(tmp_path / "full.avi", 12, hw=(32, 40))
    data = (tmp_path / "full.avi").read_bytes()
    (tmp_path / "cut.avi").write_bytes(data[: int(len(data) * 0.55)])
    assert main(["predict", "--model", str(ckpt), "--input", str(tmp_path / "full.avi"), "--output",
                 str(tmp_path / "full"), "--no-progress"]) == 0
    assert capfd.readouterr().err == ""  # a complete video: no warning
    assert main(["predict", "--model", str(ckpt), "--input", str(tmp_path / "cut.avi"), "--output",
                 str(tmp_path / "cut"), "--no-progress"]) == 0
    err = capfd.readouterr().err.splitlines()
    summary = json.loads((tmp_path / "cut" / "predict.json").read_text())
    n = summary["frames"]
    assert 0 < n < 12 and summary["frames_expected"] == 12
    assert err == [f"f2depth predict: warning: {tmp_path / 'cut.avi'}: only {n} of the 12 frames its "
                   f"container announces could be decoded (a truncated or damaged file?); wrote those {n}"]
    assert summary["warnings"] == [err[0].split("warning: ", 1)[1]]
    assert len(list((tmp_path / "cut").glob("*_depth.npy"))) == n


def nyu_sample(index: int, rgb: np.ndarray, depth: np.ndarray, scene: str) -> EvalSample:
    return EvalSample(rgb, scene, (index,), depth=depth)


def flat_predictor(x: torch.Tensor) -> torch.Tensor:
    return torch.full((x.shape[0], 1, *x.shape[2:]), 0.5)


def test_nan_ground_truth_is_rejected_or_reported(caplog):
    rgb = np.full((32, 32, 3), 128, np.uint8)
    good = np.full((32, 32), 2.0, np.float32)
    # NYU: before, an all-NaN depth map was skipped without a word (and NaN pixels silently dropped)
    nan_map = np.full((32, 32), np.nan, np.float32)
    samples = [nyu_sample(1, rgb, good, "a"), nyu_sample(2, rgb, nan_map, "b")]
    with pytest.raises(DataError, match=r"NYU sample 2: ground truth has 1024 non-finite value\(s\)"):
        nyu.PROTOCOL.evaluate(samples, flat_predictor, height=32, width=32, crop="none")
    # an image without any valid pixel (all 0 = missing) is still skipped, now with one warning line
    caplog.set_level(logging.WARNING)
    res = nyu.PROTOCOL.evaluate([nyu_sample(1, rgb, good, "a"), nyu_sample(2, rgb, 0 * good, "b")],
                                flat_predictor, height=32, width=32, crop="none")
    assert res.skipped == [(2,)] and res.summary.count == 1
    assert [r.getMessage() for r in caplog.records] == [
        "NYU: 1 of 2 test images skipped: no valid ground-truth pixel (first: 2); the metrics are over the "
        "other 1"]
    # 7-Scenes: NaN metres count as missing depth (documented), and the count is logged
    caplog.clear()
    depth = good.copy()
    depth[:3] = np.nan
    frame = EvalSample(rgb, "chess", ("chess", "seq-01", 0), depth=depth)
    sevenscenes.PROTOCOL.evaluate([frame], flat_predictor, height=32, width=32)
    assert [r.getMessage() for r in caplog.records] == [
        "7-Scenes: 96 ground-truth pixels in 1 image(s) are NaN or inf and count as missing depth "
        "(first: chess/seq-01/0)"]
    # Campus: a NaN point is damage
    pts = np.array([[3.0, 4.0, 2.0], [5.0, 6.0, np.nan]])
    with pytest.raises(DataError, match=r"Campus sample s1/a\.jpg: ground truth has 1 non-finite"):
        campus_eval.PROTOCOL.evaluate([EvalSample(rgb, "s1", ("s1", "a.jpg"), points=pts)], flat_predictor,
                                      height=32, width=32)


def test_nan_in_synthetic_ground_truth_is_rejected(tmp_path):
    depth = np.full((8, 8), 2.0, np.float32)
    depth[0, :3] = np.nan
    np.savez(tmp_path / "f.npz", depth=depth, world_T_cam=np.eye(4), K=np.eye(3))
    with pytest.raises(DataError, match=r"f\.npz: depth has 3 non-finite or negative value\(s\) of 64"):
        read_gt_npz(tmp_path / "f.npz")


def test_out_of_range_keypoints_are_rejected(tmp_path):
    # before: points at x ≥ width were clamped onto the border column by centre_depth, without a word
    root = train_fakes.write_prepared(tmp_path / "prepared", hw=(32, 32), scenes=1, frames=4)
    kp = KeypointFile(tmp_path / "keypoints" / "train.npz")
    kp.check_inside(32, 32)  # the file the fakes wrote fits
    points = [kp.points(f).astype(int) for f in kp.frame_ids]
    points[2] = np.vstack([points[2], [[40, 5, 0], [3, -1, 0]]])
    save_keypoints(tmp_path / "bad.npz", kp.frame_ids, points)
    with pytest.raises(KeypointFileError, match=r"bad\.npz: 2 of \d+ keypoints in 1 frame\(s\) lie outside "
                                                r"the 32×32 training images \(first: frame 2 at x=40, y=5\)"):
        TupleDataset(root, tmp_path / "bad.npz", DataConfig(num_points=20))
    assert isinstance(KeypointFileError("x"), DataError)  # stages print it in one line


# ---- smaller points ------------------------------------------------------------------------------------


def test_torch_advice_never_reaches_the_user(ckpt, images, tmp_path, capfd):
    # before: "... This file can still be loaded, to do so you have two options, do those steps only if
    # you trust the source of the checkpoint" (and weights_only=False further on)
    torch.save({"format": "f2depth.depth", "obj": Path("x")}, tmp_path / "pickled.pt")
    (tmp_path / "junk.pt").write_bytes(bytes(range(256)) * 4)
    for name, phrase in (("pickled.pt", "not an f2depth checkpoint: it holds pickled Python objects"),
                         ("junk.pt", "not a readable torch checkpoint (WeightsUnpickler: Unsupported")):
        code = main(["predict", "--model", str(tmp_path / name), "--input", str(images), "--output",
                     str(tmp_path / "out")])
        line = one_error_line(capfd, "predict")
        assert code == 1 and phrase in line
        assert "weights_only=False" not in line and "can still be loaded" not in line
        assert "Re-running" not in line
        with pytest.raises(CheckpointError) as info:
            load_flow_model(tmp_path / name)
        assert "weights_only=False" not in str(info.value) and "can still be loaded" not in str(info.value)
    assert "not an f2depth or ARFlow checkpoint" in str(pytest.raises(CheckpointError, load_flow_model,
                                                                      tmp_path / "pickled.pt").value)


def test_config_errors_name_the_checkpoint(ckpt, tmp_path):
    # before: "height=100, width=96: both must be positive multiples of 32" (no file named)
    data = torch.load(ckpt, weights_only=True)
    for name, change in (("h100.pt", {"config": {**data["config"], "height": 100}}),
                         ("cfg.pt", {"config": "abc"}), ("sd.pt", {"state_dict": [1, 2]})):
        torch.save({**data, **change}, tmp_path / name)
        with pytest.raises(ValueError) as info:
            load_checkpoint(tmp_path / name)
        assert str(info.value).startswith(f"{tmp_path / name}: ")


def test_directories_given_as_models(ckpt, images, tmp_path, capfd):
    # before: "<dir>: depth checkpoint not found; run `dvc repro train_depth` first"
    (tmp_path / "models").mkdir()
    (tmp_path / "models" / "seed0.pt").write_bytes(Path(ckpt).read_bytes())
    for flag, phrase in (("--model", "is a directory, not a depth checkpoint; give a checkpoint file in it "
                                     "(seed0.pt)"), ("--onnx", "is a directory, not an ONNX model")):
        code = main(["predict", flag, str(tmp_path / "models"), "--input", str(images), "--output",
                     str(tmp_path / "out")])
        assert code == 1 and phrase in one_error_line(capfd, "predict")


def test_output_folder_is_checked_before_inference(ckpt, images, tmp_path, capfd, monkeypatch):
    # before: the error named a temporary file (/sys/.img_00_depth_mm.png.8f2fdax8.png: Permission
    # denied) after the first batch had been predicted
    (tmp_path / "a_file").write_text("x")
    a_file = tmp_path / "a_file"
    code = main(["predict", "--model", str(ckpt), "--input", str(images), "--output", str(a_file)])
    assert code == 1 and f"{a_file}: exists and is not a folder" in one_error_line(capfd, "predict")

    locked = tmp_path / "locked"
    locked.mkdir()

    def refuse(*args, dir=None, **kwargs):  # what mkstemp does in a folder without write permission
        raise PermissionError(13, "Permission denied", str(Path(dir) / ".f2depth-write-test.x"))

    monkeypatch.setattr(writable_mod.tempfile, "mkstemp", refuse)
    predicted = []
    monkeypatch.setattr(Predictor, "predict", lambda self, *a, **k: predicted.append(1))
    code = main(["predict", "--model", str(ckpt), "--input", str(images), "--output", str(locked)])
    line = one_error_line(capfd, "predict")
    assert code == 1 and line.endswith(f"{locked}: output folder is not writable (Permission denied); give "
                                       "--output a folder you can write to")
    assert predicted == [] and list(locked.iterdir()) == []
    code = main(["export", "--model", str(ckpt), "--output", str(locked / "m.onnx")])
    assert code == 1 and f"{locked}: output folder is not writable" in one_error_line(capfd, "export")


def test_export_output_that_is_a_folder(ckpt, tmp_path, capfd):
    (tmp_path / "m.onnx").mkdir()
    code = main(["export", "--model", str(ckpt), "--output", str(tmp_path / "m.onnx")])
    assert code == 1 and f"{tmp_path / 'm.onnx'}: is a directory" in one_error_line(capfd, "export")


def test_missing_flow_model_names_the_variant_key(tmp_path):
    # before: "models/flow_patch.pt: checkpoint not found; check flow_pretrain.checkpoint in params.yaml"
    missing = tmp_path / "models" / "flow_patch.pt"
    params = P.load(train_fakes.write_params(tmp_path, tmp_path / "prepared", tmp_path / "labeled.mat",
                                             tmp_path / "splits.mat", missing))
    settings = settings_from_params(params, "full")
    with pytest.raises(DataError, match=r"flow_patch\.pt: flow model not found \(variants\.full\."
                                        r"flow\); `dvc repro train_depth@full` builds it first"):
        train_variant(settings, tmp_path / "out", progress=False)
    assert not (tmp_path / "out").exists()


def test_inputs_sharing_a_stem_get_distinct_outputs(ckpt, tmp_path, capfd):
    """Issue 25 item 2. Before: a.png, a.PNG, b.jpg, b_jpg.png and b.png → "wrote 5 frame(s)" and 3 sets of
    files (a_png twice, b_jpg twice). Now every input has its own files (numbered in name order),
    listed in predict.json."""
    names = ["a.png", "a.PNG", "b.jpg", "b_jpg.png", "b.png"]
    sizes = {name: (40 + 4 * i, 56 + 4 * i) for i, name in enumerate(names)}  # a size identifies its input
    (tmp_path / "in").mkdir()
    for i, name in enumerate(names):
        fakes.write_rgb(tmp_path / "in" / name, fakes.smooth_image(sizes[name], i))
    code = main(["predict", "--model", str(ckpt), "--input", str(tmp_path / "in"), "--output",
                 str(tmp_path / "out"), "--device", "cpu", "--no-progress"])
    assert code == 0 and "wrote 5 frame(s)" in capfd.readouterr().out
    summary = json.loads((tmp_path / "out" / "predict.json").read_text())
    stems = {name: summary["renamed"].get(str(tmp_path / "in" / name), Path(name).stem) for name in names}
    assert len({s.casefold() for s in stems.values()}) == 5  # distinct even on a case-blind file system
    assert stems == {"a.PNG": "a_png", "a.png": "a_png_2", "b.jpg": "b_jpg_2", "b_jpg.png": "b_jpg",
                     "b.png": "b_png"}
    for name, stem in stems.items():
        assert np.load(tmp_path / "out" / f"{stem}_depth.npy").shape == sizes[name]
    assert len(list((tmp_path / "out").glob("*_depth.npy"))) == 5
    assert any("share a file stem" in w for w in summary["warnings"])


def test_the_output_folder_may_not_be_the_input_folder(ckpt, images, tmp_path, capfd):
    """Issue 25 item 5. Before: --output equal to --input wrote depth maps beside the photos and a second
    run read them as photos (f0_depth_color_depth_mm.png). Now refused in one line, nothing written."""
    before = sorted(p.name for p in images.iterdir())
    link = tmp_path / "same"
    link.symlink_to(images, target_is_directory=True)
    for output in (images, link):
        code = main(["predict", "--model", str(ckpt), "--input", str(images), "--output", str(output)])
        line = one_error_line(capfd, "predict")
        assert code == 1 and line.endswith(f"{output}: the output folder is the input folder, so a later run "
                                           "would read these depth and colour maps as photos; give --output "
                                           f"another folder (e.g. {images}_depth)")
    assert sorted(p.name for p in images.iterdir()) == before
    code = main(["predict", "--model", str(ckpt), "--input", str(images), "--output", str(images / "depth"),
                 "--no-progress"])  # a folder inside is fine: folders are not read recursively
    assert code == 0 and len(list((images / "depth").glob("*_depth.npy"))) == 2


def test_an_exif_rotated_jpeg_is_predicted_upright(ckpt, tmp_path, capfd):
    """Issue 25 item 9: a phone JPEG stored landscape with EXIF orientation 6 (rotate 90° clockwise to
    show) gives a depth map in the orientation it is shown in, as predict.json says."""
    from PIL import Image

    stored = np.zeros((40, 64, 3), np.uint8)
    stored[:, :16] = 255  # a white band on the left of the stored image: on top once shown
    image = Image.fromarray(stored)
    exif = image.getexif()
    exif[0x0112] = 6  # Orientation 6: shown rotated 90° clockwise
    (tmp_path / "in").mkdir()
    image.save(tmp_path / "in" / "phone.jpg", exif=exif.tobytes(), quality=95)
    assert read_image(tmp_path / "in" / "phone.jpg").shape == (64, 40, 3)
    assert read_image(tmp_path / "in" / "phone.jpg")[:12].mean() > 200  # the band is on top
    code = main(["predict", "--model", str(ckpt), "--input", str(tmp_path / "in"), "--output",
                 str(tmp_path / "out"), "--no-progress"])
    assert code == 0 and np.load(tmp_path / "out" / "phone_depth.npy").shape == (64, 40)
    summary = json.loads((tmp_path / "out" / "predict.json").read_text())
    assert summary["orientation"].startswith("EXIF orientation applied")
