"""Keypoints selected on the full-resolution crop of the raw frame (as P²Net does), not on the prepared image.

A tiny NYU raw set is prepared with the real ``prepare``; the keypoints stage must give exactly the points
of P²Net's recipe computed here independently: ``cv2.undistort`` with the NYU calibration, the crop,
grey, bilinear resize to 640×480, the selector, then ``x·W // 640``, ``y·H // 480``.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import cv2
import fakes
import numpy as np
import pytest
import yaml

from f2depth.camera import NYU_RGB_DIST, NYU_RGB_K
from f2depth.data.prepare import PrepareConfig, SuperpixelParams, prepare
from f2depth.errors import DataError
from f2depth.formats.prepared import PreparedSet
from f2depth.keypoints import select_pixels
from f2depth.keypoints.extract import extract_keypoints
from f2depth.keypoints.store import KeypointFile

ROOT = Path(__file__).resolve().parents[1]
HW = (96, 128)
SCENE = "office_0002"


def _textured(seed: int) -> np.ndarray:
    """A raw-sized RGB frame with fine texture (lost by downsizing) on flat blocks."""
    rng = np.random.default_rng(seed)
    texture = cv2.GaussianBlur(rng.normal(0, 40, (480, 640, 3)).astype(np.float32), (0, 0), 0.8)
    base = fakes.blocky_image((480, 640), seed, blocks=5).astype(np.float32)
    return np.clip(base + texture, 0, 255).astype(np.uint8)


def _raw_set(root: Path, flat_last: bool = True) -> list[Path]:
    """Five raw frames of one scene (the last one flat); returns their paths in time order."""
    paths = []
    for k, ts in enumerate(fakes.raw_timestamps(5)):
        rgb = np.full((480, 640, 3), 120, np.uint8) if flat_last and k == 4 else _textured(k)
        path = root / SCENE / f"r-{ts:.6f}-{100 + k}.ppm"
        fakes.write_ppm(path, rgb)
        paths.append(path)
    return paths


def _prepared(tmp_path: Path, crop: int = 16) -> tuple[Path, Path, list[Path]]:
    raw = tmp_path / "raw"
    paths = _raw_set(raw)
    scenes = tmp_path / "scenes.txt"
    scenes.write_text(f"{SCENE}\n")
    out = tmp_path / "prepared"
    config = PrepareConfig(height=HW[0], width=HW[1], frame_step=1, crop=crop, workers=1,
                           superpixels=SuperpixelParams(100, 0.5, 10))
    prepare(raw, tmp_path / "unused.mat", tmp_path / "unused_splits.mat", out, config,
            train_scenes_file=scenes, progress=False)
    return raw, out, paths


def _p2net_recipe(raw_path: Path, crop: int, hw: tuple[int, int]) -> np.ndarray:
    """P²Net's points of a raw frame at ``hw``, written out step by step."""
    bgr = cv2.imread(str(raw_path))
    rgb = cv2.undistort(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), NYU_RGB_K, NYU_RGB_DIST)
    rgb = rgb[crop:480 - crop, crop:640 - crop]
    gray = cv2.resize(cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2GRAY), (640, 480),
                      interpolation=cv2.INTER_LINEAR)
    pts = select_pixels(gray, "p2net")  # at 640×480 already: no resize inside
    x, y = pts[:, 0] * hw[1] // 640, pts[:, 1] * hw[0] // 480
    order = np.argsort(y * hw[1] + x, kind="stable")
    return np.stack([x, y, pts[:, 2]], 1)[order]


@pytest.mark.parametrize("crop", [16, 8])
def test_full_resolution_source_is_p2nets_recipe_and_differs_from_prepared(tmp_path, crop):
    raw, prepared, paths = _prepared(tmp_path, crop)
    full = extract_keypoints(prepared, tmp_path / "full.npz", None, "p2net", workers=1, progress=False,
                             source="full_resolution", nyu_raw=raw)
    old = extract_keypoints(prepared, tmp_path / "old.npz", None, "p2net", workers=1, progress=False,
                            source="prepared")
    kp_full, kp_old = KeypointFile(tmp_path / "full.npz"), KeypointFile(tmp_path / "old.npz")
    ds = PreparedSet(prepared)
    assert ds.crop == crop and full["source"] == "full_resolution" and old["source"] == "prepared"
    assert full["selector_input"] == [480 - 2 * crop, 640 - 2 * crop] and old["selector_input"] == list(HW)
    assert full["raw_vs_prepared_max_diff"] < 0.01 and old["raw_vs_prepared_max_diff"] is None
    moved = []
    for i, path in enumerate(paths[:4]):
        got = kp_full.points(i)
        np.testing.assert_array_equal(got, _p2net_recipe(path, crop, HW))
        assert 1000 < len(got) <= 2500
        assert got[:, 0].min() >= 0 and got[:, 0].max() < HW[1] and got[:, 1].min() >= 0
        assert got[:, 1].max() < HW[0] and set(np.unique(got[:, 2])) <= {0, 1, 2}
        # the old source selects on the prepared image upsampled to 640×480
        gray = cv2.cvtColor(ds.image(ds.frames[i].frame_id), cv2.COLOR_RGB2GRAY)
        np.testing.assert_array_equal(kp_old.points(i), select_pixels(gray, "p2net"))
        new_set = {tuple(p) for p in got[:, :2].tolist()}
        old_set = {tuple(p) for p in kp_old.points(i)[:, :2].tolist()}
        moved.append(len(new_set - old_set) / len(new_set))
    assert min(moved) > 0.3, moved  # a substantially different set of pixels (about 80 % here)
    # the flat frame: no points, no error, from either source
    assert len(kp_full.points(4)) == 0 and len(kp_old.points(4)) == 0
    assert full["empty_frames"] == 1 == old["empty_frames"]


def test_dso_preset_maps_the_full_resolution_crop_to_the_training_size(tmp_path):
    raw, prepared, paths = _prepared(tmp_path)
    extract_keypoints(prepared, tmp_path / "kp.npz", None, "dso", {"density": 500}, progress=False,
                      source="full_resolution", nyu_raw=raw)
    got = KeypointFile(tmp_path / "kp.npz").points(1)
    rgb = cv2.undistort(cv2.cvtColor(cv2.imread(str(paths[1])), cv2.COLOR_BGR2RGB), NYU_RGB_K, NYU_RGB_DIST)
    gray = cv2.cvtColor(np.ascontiguousarray(rgb[16:464, 16:624]), cv2.COLOR_RGB2GRAY)
    at_full = select_pixels(gray, "dso", density=500)  # selected at 448×608, no working size
    x, y = at_full[:, 0] * HW[1] // 608, at_full[:, 1] * HW[0] // 448
    order = np.argsort(y * HW[1] + x, kind="stable")
    np.testing.assert_array_equal(got, np.stack([x, y, at_full[:, 2]], 1)[order])
    assert len(got) > 300 and got[:, 0].max() < HW[1] and got[:, 1].max() < HW[0]


def test_workers_and_sequence_give_the_same_points(tmp_path):
    raw, prepared, _ = _prepared(tmp_path)
    kw = {"progress": False, "source": "full_resolution", "nyu_raw": raw}
    extract_keypoints(prepared, tmp_path / "a.npz", None, "dso", {"density": 400}, workers=1, **kw)
    extract_keypoints(prepared, tmp_path / "b.npz", None, "dso", {"density": 400}, workers=2, **kw)
    a, b = KeypointFile(tmp_path / "a.npz"), KeypointFile(tmp_path / "b.npz")
    assert all(np.array_equal(a.points(i), b.points(i)) for i in range(5)) and a.offsets[-1] > 0
    seq = extract_keypoints(prepared, tmp_path / "s.npz", None, "dso", {"density": 400}, sequence=True, **kw)
    s = KeypointFile(tmp_path / "s.npz")
    assert seq["sequence"] is True
    np.testing.assert_array_equal(s.points(0), a.points(0))  # the first frame starts at pot 3 in both


def test_library_rejects_bad_source_and_missing_nyu_raw(tmp_path):
    _, prepared, _ = _prepared(tmp_path)
    with pytest.raises(ValueError, match="unknown keypoint source 'raw'"):
        extract_keypoints(prepared, tmp_path / "kp.npz", None, "p2net", source="raw", progress=False)
    with pytest.raises(ValueError, match="needs nyu_raw"):
        extract_keypoints(prepared, tmp_path / "kp.npz", None, "p2net", progress=False)
    assert not (tmp_path / "kp.npz").exists()


def test_wrong_raw_frame_is_refused(tmp_path):
    raw, prepared, paths = _prepared(tmp_path)
    fakes.write_ppm(paths[2], _textured(99))  # not the frame prepare read
    match = rf"{paths[2].name}: prepared again it differs from .*office_0002_00002"
    with pytest.raises(DataError, match=match):
        extract_keypoints(prepared, tmp_path / "kp.npz", None, "p2net", progress=False, nyu_raw=raw)


def test_camera_json_without_crop_is_a_data_error(tmp_path):
    raw, prepared, _ = _prepared(tmp_path)
    cam = json.loads((prepared / "camera.json").read_text())
    del cam["crop"]
    (prepared / "camera.json").write_text(json.dumps(cam))
    with pytest.raises(DataError, match=r"camera.json: no integer 'crop'; re-run `dvc repro prepare`"):
        extract_keypoints(prepared, tmp_path / "kp.npz", None, "p2net", progress=False, nyu_raw=raw)


def _params(tmp_path: Path, raw: Path, prepared: Path, source: str = "full_resolution") -> None:
    params = {
        "threads": 1, "train_source": "nyu_raw",
        "data": {"prepared": str(prepared), "keypoints": "data/keypoints", "nyu_raw": str(raw)},
        "keypoints": {"source": source, "preset": "p2net", "options": {}, "sequence": False, "workers": 2,
                      "overlays": 2, "overlay_dir": "reports/figures/keypoints"},
    }
    (tmp_path / "params.yaml").write_text(yaml.safe_dump(params))


def _stage(tmp_path: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(ROOT / "stages" / "keypoints.py"), "params.yaml"],
                          cwd=tmp_path, capture_output=True, text=True, timeout=300)


def test_stage_full_resolution_and_missing_raw_file(tmp_path):
    raw, prepared, paths = _prepared(tmp_path)
    _params(tmp_path, raw, prepared)
    run = _stage(tmp_path)
    assert run.returncode == 0, run.stderr
    assert "selected on the full_resolution image" in run.stdout
    kp = KeypointFile(tmp_path / "data" / "keypoints" / "train.npz")
    np.testing.assert_array_equal(kp.points(3), _p2net_recipe(paths[3], 16, HW))
    metrics = json.loads((tmp_path / "metrics" / "keypoints.json").read_text())
    assert metrics["source"] == "full_resolution" and metrics["frames"] == 5 and metrics["empty_frames"] == 1
    before = (tmp_path / "data" / "keypoints" / "train.npz").read_bytes()

    paths[1].unlink()
    run = _stage(tmp_path)
    assert run.returncode == 1
    assert "Traceback" not in run.stderr, run.stderr
    last = run.stderr.strip().splitlines()[-1]  # after the progress bar
    assert last.startswith(f"keypoints: {paths[1]}: raw frame not found") and "data.nyu_raw" in last
    assert (tmp_path / "data" / "keypoints" / "train.npz").read_bytes() == before  # the old output is kept


def test_stage_rejects_an_unknown_source_in_one_line(tmp_path):
    raw, prepared, _ = _prepared(tmp_path)
    _params(tmp_path, raw, prepared, source="raw")
    run = _stage(tmp_path)
    assert run.returncode == 1
    assert run.stderr.strip() == ("keypoints: params.yaml: keypoints.source is 'raw'; set it to one of "
                                  "full_resolution, prepared")


def test_lanczos_prepared_images_are_p2nets_and_pass_the_raw_check(tmp_path):
    """prepare.interpolation: lanczos shrinks the undistorted crop with PIL's LANCZOS (P²Net's
    transforms.Resize), records it in camera.json, and the keypoints stage re-prepares the raw frame with
    the same filter (an exact match), where the other filter would differ."""
    from PIL import Image

    from f2depth.keypoints.extract import raw_mismatch

    raw = tmp_path / "raw"
    paths = _raw_set(raw, flat_last=False)
    (tmp_path / "scenes.txt").write_text(f"{SCENE}\n")
    out = tmp_path / "prepared"
    config = PrepareConfig(height=HW[0], width=HW[1], frame_step=1, crop=16, workers=1,
                           superpixels=SuperpixelParams(100, 0.5, 10), interpolation="lanczos")
    prepare(raw, tmp_path / "unused.mat", tmp_path / "unused_splits.mat", out, config,
            train_scenes_file=tmp_path / "scenes.txt", progress=False)
    ds = PreparedSet(out)
    assert ds.interpolation == "lanczos" and json.loads((out / "camera.json").read_text())["interpolation"] \
        == "lanczos"
    frame = ds.frames[0]
    rgb = cv2.undistort(cv2.cvtColor(cv2.imread(str(paths[0])), cv2.COLOR_BGR2RGB), NYU_RGB_K, NYU_RGB_DIST)
    crop = np.ascontiguousarray(rgb[16:464, 16:624])
    expected = np.asarray(Image.fromarray(crop).resize((HW[1], HW[0]), Image.Resampling.LANCZOS))
    np.testing.assert_array_equal(ds.image(frame.frame_id), expected)
    assert raw_mismatch(crop, expected, "lanczos") == 0.0 and raw_mismatch(crop, expected, "area") > 0.3
    metrics = extract_keypoints(out, tmp_path / "kp" / "train.npz", tmp_path / "overlays", "p2net",
                                source="full_resolution", nyu_raw=raw, workers=1, progress=False)
    assert metrics["raw_vs_prepared_max_diff"] == 0.0
    with pytest.raises(ValueError, match="prepare.interpolation must be one of"):
        PrepareConfig(height=HW[0], width=HW[1], interpolation="cubic")
