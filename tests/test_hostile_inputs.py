"""Issue 53, items 2 (the rest of it), 3 and 4: what a hostile but honest user fed f2depth, and got silently
wrong results, gigabytes of memory or a traceback for. Each test says what happened before the fix; now
each is one line (or one warning line) and a non-zero exit where nothing right can be made."""

from __future__ import annotations

import errno
import json
import re
import resource
import time
from pathlib import Path

import cv2
import inference_data
import numpy as np
import pytest
import torch
from depth_scenes import rotation
from pose_scenes import camera_path, render

from f2depth import io as io_mod
from f2depth import params as P
from f2depth.cli import main
from f2depth.errors import DataError
from f2depth.ingest.camera_files import read_camera_file
from f2depth.ingest.selfcal import estimate_focal
from f2depth.stage import run_stage

ROOT = Path(__file__).resolve().parents[1]
HW = (120, 160)
K = np.array([[120.0, 0.0, 79.5], [0.0, 120.0, 59.5], [0.0, 0.0, 1.0]])
CAMERA = {"fx": 120.0, "fy": 120.0, "cx": 79.5, "cy": 59.5, "width": 160, "height": 120}


def one_line(capfd, command: str, kind: str = "error") -> str:
    err = capfd.readouterr().err.splitlines()
    assert len(err) == 1, err
    assert err[0].startswith(f"f2depth {command}: {kind}: "), err[0]
    return err[0]


def bomb(levels: int = 9) -> tuple[str, str]:
    """YAML anchors of 10 aliases of the one before ("billion laughs"): 10^8 values from 500 bytes; returns
    the anchors' text and an alias to the last one."""
    lines = ['a0: &a0 ["xxxxxxxxxx"]']
    lines += [f"a{i}: &a{i} [{', '.join([f'*a{i - 1}'] * 10)}]" for i in range(1, levels)]
    return "\n".join(lines) + "\n", f"*a{levels - 1}"


def params_with(key: str, value: str, before: str = "") -> str:
    """The repository's params.yaml text with ``ingest.<key>`` set to the YAML text ``value`` (and the text
    ``before`` in front of it all)."""
    head, tail = (ROOT / "params.yaml").read_text().split("\ningest:\n", 1)
    tail = re.sub(rf"^  {key}: .*$", lambda m: f"  {key}: {value}", tail, count=1, flags=re.M)
    return before + head + "\ningest:\n" + tail


def write_clip(path: Path, poses: np.ndarray) -> Path:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 30.0, (HW[1], HW[0]))
    for k, T in enumerate(poses):
        writer.write(cv2.cvtColor(render(T, K, HW, seed=k), cv2.COLOR_GRAY2BGR))
    writer.release()
    return path


@pytest.fixture(scope="module")
def clip(tmp_path_factory) -> Path:
    """A 24-frame video of a camera walking through the textured room, and its camera file."""
    root = tmp_path_factory.mktemp("clip")
    (root / "camera.json").write_text(json.dumps(CAMERA))
    return write_clip(root / "walk.avi", camera_path(24, step=0.02, yaw_deg=0.3))


def ingest(clip: Path, out: Path, *flags: str) -> int:
    return main(["ingest", str(clip), "--out", str(out), "--camera", str(clip.parent / "camera.json"),
                 "--params", str(ROOT / "params.yaml"), "--no-progress", "--min-motion", "0.005", *flags])


# ---- item 3: memory bombs ----------------------------------------------------------------------------

def test_a_yaml_alias_bomb_in_params_is_one_short_line_at_once(tmp_path, capfd):
    """Before: a 22 KB params file with a bomb in ingest.frame_step took 3.96 GB and printed the 34 MB value;
    in an unused key the MLflow mirror died with MemoryError. Now every params file is read by one loader
    that refuses aliases expanding beyond 100 000 values, in milliseconds, before any stage or mirror."""
    anchors, alias = bomb()
    used = tmp_path / "used.yaml"
    used.write_text(params_with("frame_step", alias, anchors))
    unused = tmp_path / "unused.yaml"
    unused.write_text(params_with("frame_step", "1", anchors + f"unused_key: {alias}\n"))
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    start = time.perf_counter()
    for path in (used, unused):
        with pytest.raises(P.ParamsError, match=rf"^{path}: line \d+: its aliases \(\*name\) expand to more "
                                                r"than 100000 values, a 'billion laughs' bomb"):
            P.load(path)
    assert time.perf_counter() - start < 2.0
    assert resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before < 100_000  # KiB: under 100 MB
    assert main(["ingest", str(tmp_path), "--out", str(tmp_path / "o"), "--params", str(used)]) == 1
    assert len(one_line(capfd, "ingest")) < 300
    (tmp_path / "self.yaml").write_text("a: &x [1, *x]\n")
    with pytest.raises(P.ParamsError, match="an alias .* refers to the value it is in"):
        P.load(tmp_path / "self.yaml")
    (tmp_path / "merge.yaml").write_text("base: &b {epochs: 1}\ntrain: {<<: *b, lr: 2}\n")  # still fine
    assert P.load(tmp_path / "merge.yaml")["train"] == {"epochs": 1, "lr": 2}


def test_long_values_are_cut_in_messages(tmp_path):
    """Before: the error line quoted the whole value (34 MB). Now at most 240 characters of it."""
    from f2depth.ingest.run import IngestConfig

    path = tmp_path / "params.yaml"
    path.write_text(params_with("frame_step", "x" * 100_000))
    with pytest.raises(P.ParamsError) as info:
        P.section(P.load(path), "ingest", IngestConfig)
    text = str(info.value)
    assert "ingest.frame_step is 'xxx" in text and "…" in text and len(text) - len(str(path)) < 300


def test_a_yaml_alias_bomb_in_a_camera_file_is_refused(tmp_path):
    """Before: the same bomb in a camera YAML took gigabytes. Now one line naming the file."""
    anchors, alias = bomb()
    path = tmp_path / "cam.yaml"
    path.write_text(anchors + f"fx: {alias}\nfy: 120\ncx: 79.5\ncy: 59.5\nwidth: 160\nheight: 120\n")
    with pytest.raises(DataError, match=rf"^{path}: its aliases .* 'billion laughs' bomb"):
        read_camera_file(path)


def test_a_voxel_too_small_for_memory_is_refused_with_the_smallest_allowed(tmp_path, capfd):
    """Before: `reconstruct --voxel 0.0005` took 4.4 GB, then Open3D failed to allocate. Now the volume's
    memory is estimated from the surface the frames see, and a voxel that does not fit is one line naming
    the smallest that does."""
    pytest.importorskip("open3d", reason="open3d (optional extra 'recon') is not installed")
    from f2depth.inference.reconstruct import TSDFSettings, check_voxel

    inference_data.write_box_sequence(tmp_path / "images", tmp_path / "gt", count=4)
    code = main(["reconstruct", "--sequence", str(tmp_path / "images"), "--poses", "synth", "--gt",
                 str(tmp_path / "gt"), "--output", str(tmp_path / "m.ply"), "--depth-source", "reference",
                 "--voxel", "0.0005", "--no-progress"])
    line = one_line(capfd, "reconstruct")
    assert code == 1 and "--voxel: a 0.0005 m voxel needs about" in line
    assert "the smallest voxel here is" in line
    assert not (tmp_path / "m.ply").exists()
    smallest = float(line.rsplit("is ", 1)[1].split(" m")[0])
    check_voxel(40.0, TSDFSettings(voxel=0.005), budget=2 << 30)  # a room at 5 mm in 2 GiB: fits
    with pytest.raises(DataError, match=r"the smallest voxel here is 0\.00\d+ m"):
        check_voxel(40.0, TSDFSettings(voxel=0.001), budget=2 << 30)
    assert smallest > 0.0005


# ---- item 4: tracebacks and misleading lines -----------------------------------------------------------

def test_a_garbage_opencv_calibration_is_one_line(tmp_path):
    """Before: `SystemError: <class 'cv2.FileStorage'> returned a result with an exception set`."""
    path = tmp_path / "calib.yaml"
    path.write_bytes(b"%YAML:1.0\n" + bytes(range(128, 256)) * 4)
    with pytest.raises(DataError, match=rf"^{path}: OpenCV cannot read this calibration file"):
        read_camera_file(path)


def test_a_comment_that_says_camera_matrix_does_not_make_our_yaml_opencvs(tmp_path):
    """Before: the word "camera_matrix" anywhere sent our YAML to OpenCV's parser, which found no matrix."""
    path = tmp_path / "cam.yaml"
    path.write_text("# converted from the camera_matrix of calib.yaml\n"
                    + "".join(f"{k}: {v}\n" for k, v in CAMERA.items()))
    cam = read_camera_file(path)
    assert cam.K[0, 0] == 120.0 and cam.hw == HW and "camera file" in cam.source


def test_ingest_blames_the_flag_that_dropped_the_frames(clip, tmp_path, capfd):
    """Before: --frame-step 100 and --min-sharpness 1e9 said "the camera hardly moves ... lower
    ingest.min_motion", and --min-motion=-1 blamed params.yaml. Now each line names the flag."""
    assert ingest(clip, tmp_path / "a", "--frame-step", "100") == 1
    line = one_line(capfd, "ingest")
    assert "only 1 frame(s) sampled: every 100-th of 24 decoded frames (--frame-step = 100)" in line
    assert line.endswith("lower --frame-step to sample at least 3 frames") and "hardly moves" not in line
    assert ingest(clip, tmp_path / "b", "--min-sharpness", "1e9") == 1
    line = one_line(capfd, "ingest")
    assert "than --min-sharpness = 1e+09; lower --min-sharpness (0 turns the blur filter off)" in line
    assert ingest(clip, tmp_path / "c", "--min-motion=-1") == 1
    assert one_line(capfd, "ingest").endswith("error: --min-motion is -1.0; set it to a value >= 0")
    assert not any((tmp_path / d).exists() for d in "abc")


def test_evaluate_probes_its_outputs_before_scoring(tmp_path, monkeypatch):
    """Before: `evaluate --metrics <read-only folder>` scored for 11 s, then ended in an OSError traceback.
    Now the metrics and reports folders are probed first, as train_depth's are."""
    import yaml
    from test_stage_evaluate import load_stage

    import f2depth.formats.writable as writable

    stage = load_stage()
    params = tmp_path / "params.yaml"
    params.write_text(yaml.safe_dump({"device": "cpu", "threads": 1, "evaluate": {
        "nyu_gt": "depths", "nyu_crop": "eigen", "sevenscenes_stride": 1, "datasets": ["nyu"], "height": None,
        "width": None, "interpolation": "area", "upsample": "nearest", "decoder_upsample": "bilinear",
        "batch_size": 2, "max_images": None, "timing_height": 64, "timing_width": 64, "timing_repeats": 2,
        "timing_warmup": 1, "figure_images": 2, "figure_width": 80}}))
    locked = tmp_path / "locked"

    def refuse(*args, dir=None, **kwargs):  # what mkstemp does in a folder without write permission
        raise PermissionError(13, "Permission denied", str(Path(dir) / ".f2depth-write-test.x"))

    monkeypatch.setattr(writable.tempfile, "mkstemp", refuse)
    monkeypatch.setattr(stage, "read_checkpoint", lambda f: pytest.fail("models read before the probe"))
    with pytest.raises(DataError, match=r"locked: output folder is not writable .*give --metrics a folder"):
        stage.main(["evaluate.py", "--variant", "full", "--params", str(params), "--metrics", str(locked)])


def test_bad_imagenet_weights_are_one_line_without_torchs_advice(tmp_path, capsys):
    """Before: a traceback that repeated torch's advice to load with weights_only=False (which would run the
    file's pickled code). Now one line naming the file and the params key."""
    from f2depth.depth.resnet import load_imagenet_resnet

    (tmp_path / "text.pth").write_text("not a checkpoint")
    torch.save({"conv1.weight": torch.zeros(1), "note": Path("x")}, tmp_path / "pickled.pth")
    for name in ("text.pth", "pickled.pth"):
        with pytest.raises(SystemExit) as info:
            run_stage("train_depth", lambda argv, n=name: load_imagenet_resnet(tmp_path / n), ["x"])
        err = capsys.readouterr().err.splitlines()
        assert info.value.code == 1 and len(err) == 1 and f"{tmp_path / name}: not" in err[0]
        assert "train_depth.imagenet_weights" in err[0] and "weights_only=False" not in err[0]


def test_an_image_on_a_full_disk_says_so(tmp_path, monkeypatch):
    """Before: a full disk with --max-side 2000 said "OpenCV could not write (unsupported extension ...)".
    Now the image is encoded in memory and written by Python: the error is the disk's."""
    def full(self, data):
        raise OSError(errno.ENOSPC, "No space left on device", str(self))

    monkeypatch.setattr(Path, "write_bytes", full)
    with pytest.raises(OSError, match="no space left on device") as info:
        io_mod.imwrite(tmp_path / "frame.png", np.zeros((2000, 1500, 3), np.uint8))
    assert info.value.errno == errno.ENOSPC and "unsupported" not in str(info.value)
    assert list(tmp_path.iterdir()) == []


def test_outputs_with_another_format_s_extension_are_refused(tmp_path, capfd):
    """Before: `reconstruct --output x.png` wrote a PLY named x.png."""
    ckpt = inference_data.make_checkpoint(tmp_path / "m.pt")
    code = main(["reconstruct", "--sequence", str(tmp_path), "--model", str(ckpt), "--output",
                 str(tmp_path / "x.png")])
    assert code == 2 and "--output " in one_line(capfd, "reconstruct") and not (tmp_path / "x.png").exists()
    assert main(["export", "--model", str(ckpt), "--output", str(tmp_path / "x.png")]) == 2
    assert "the name must end in .onnx" in one_line(capfd, "export")


# ---- item 2: silently wrong results ------------------------------------------------------------------

def test_onnx_and_pytorch_give_the_same_depth_and_another_size_is_said(tmp_path, capfd):
    """Before: the README exported at 288×384 a model trained at 96×128; `predict --onnx` and `--model` then
    correlated 0.08–0.35, without a word. Now the export is at the training size unless --height/--width
    say otherwise, which export and predict both say in a warning line (and predict.json records)."""
    pytest.importorskip("onnxruntime")
    ckpt = inference_data.make_checkpoint(tmp_path / "m.pt", seed=3)
    inference_data.write_images(tmp_path / "in", 2)
    assert main(["export", "--model", str(ckpt), "--output", str(tmp_path / "same.onnx")]) == 0
    assert capfd.readouterr().err == ""
    assert main(["export", "--model", str(ckpt), "--output", str(tmp_path / "big.onnx"), "--height", "128",
                 "--width", "192"]) == 0
    assert "exporting at 128×192, but" in one_line(capfd, "export", "warning")
    depth = {}
    for name, net in (("model", ["--model", str(ckpt)]), ("same", ["--onnx", str(tmp_path / "same.onnx")]),
                      ("big", ["--onnx", str(tmp_path / "big.onnx")])):
        assert main(["predict", *net, "--input", str(tmp_path / "in"), "--output", str(tmp_path / name),
                     "--no-progress"]) == 0
        err = capfd.readouterr().err
        assert ("runs the network at 128×192, but the model was trained at 64×96" in err) == (name == "big")
        depth[name] = np.load(tmp_path / name / "img_00_depth.npy")
    np.testing.assert_allclose(depth["same"], depth["model"], rtol=1e-3)
    summary = json.loads((tmp_path / "big" / "predict.json").read_text())
    assert summary["trained_hw"] == [64, 96] and summary["network_hw"] == [128, 192]


def test_a_turning_only_clip_does_not_self_calibrate():
    """Before: a camera turning in place was accepted (fx 251.5, "reprojection inf px") and ingest.json got
    the non-JSON `Infinity`. Now it is refused: a homography explains its pairs; F gives no focal length."""
    n = 30
    poses = np.tile(np.eye(4), (n, 1, 1))
    for k in range(n):
        poses[k, :3, :3] = rotation(np.radians([0.2 * np.sin(0.2 * k), 1.0 * k, 0.1 * k]))
        poses[k, :3, 3] = [0.0, 0.0, 1.0]
    Kb = np.array([[250.0, 0, 159.5], [0, 250, 119.5], [0, 0, 1]])
    frames = [np.repeat(render(T, Kb, (240, 320), seed=k)[..., None], 3, axis=2) for k, T in enumerate(poses)]
    with pytest.raises(DataError, match=r"^turning: unknown intrinsics and self-calibration failed: a "
                                        r"homography explains \d+ % .*turns in place"):
        estimate_focal([frames], "turning")


def test_json_outputs_hold_no_infinity(tmp_path):
    io_mod.write_json(tmp_path / "a.json", {"reprojection_px": float("inf"), "x": [np.float32("nan"), 1.5]})
    text = (tmp_path / "a.json").read_text()
    assert json.loads(text, parse_constant=pytest.fail) == {"reprojection_px": None, "x": [None, 1.5]}


@pytest.mark.parametrize("change,problem", [
    ({"cx": -5000, "cy": 9000}, r"principal point \(-5000, 9000\) px lies outside the 160×120 image"),
    ({"fx": 1e-9}, r"focal length fx 1e-09, fy 120 px is outside 16–1600 px"),
    ({"dist": [1e6, 0, 0, 0, 0]}, r"distortion \[1000000\.0, .*\] leaves only 0 % of an undistorted frame"),
])
def test_absurd_cameras_are_refused(tmp_path, change, problem):
    """Before: cx −5000 / cy 9000, fx 1e-9 ("fx 0.0 px") and k1 = 1e6 (every frame black, "kept 12 of
    12") were accepted."""
    path = tmp_path / "cam.json"
    path.write_text(json.dumps({**CAMERA, **change}))
    with pytest.raises(DataError, match=rf"^{path}: {problem}"):
        read_camera_file(path)


def test_a_damaged_video_is_said_and_an_input_given_twice_is_refused(clip, tmp_path, capfd):
    """Before: a damaged MP4 ingested 15 of 60 frames without a word (predict warns on the same file), and
    one input given twice became two identical training scenes."""
    cut = tmp_path / "cut.avi"
    cut.write_bytes(clip.read_bytes()[: int(clip.stat().st_size * 0.6)])
    (tmp_path / "camera.json").write_text(json.dumps(CAMERA))
    assert ingest(cut, tmp_path / "out") == 0
    err = capfd.readouterr().err.splitlines()
    report = json.loads((tmp_path / "out" / "ingest.json").read_text())
    n = report["scenes"]["cut"]["decoded"]
    assert 3 <= n < 24 and report["scenes"]["cut"]["frames_expected"] == 24
    assert err == [f"f2depth ingest: warning: {cut}: only {n} of the 24 frames its container announces could "
                   f"be decoded (a truncated or damaged file?); ingested from those {n}"]
    assert report["warnings"] == [err[0].split("warning: ", 1)[1]]
    code = main(["ingest", str(clip), str(clip.parent / "." / clip.name), "--out", str(tmp_path / "twice"),
                 "--fov", "60", "--params", str(ROOT / "params.yaml"), "--no-progress"])
    assert code == 1 and "is given twice (also as" in one_line(capfd, "ingest")
    assert not (tmp_path / "twice").exists()


def test_an_extreme_scale_is_refused_before_writing(tmp_path, capfd):
    """Before: `predict --scale 1e308` wrote all-inf depth maps, exit 0."""
    ckpt = inference_data.make_checkpoint(tmp_path / "m.pt")
    inference_data.write_images(tmp_path / "in", 1)
    code = main(["predict", "--model", str(ckpt), "--input", str(tmp_path / "in"), "--output",
                 str(tmp_path / "out"), "--scale", "1e308", "--no-progress"])
    line = one_line(capfd, "predict")
    assert code == 1 and "--scale: depth scale 1e+308 is outside 1e-06..1e+06" in line
    assert not list(tmp_path.glob("out/*_depth.npy"))
