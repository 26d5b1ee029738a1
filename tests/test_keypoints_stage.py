"""The `keypoints` stage on a small fake prepared set written in the docs/formats.md layout, with
``keypoints.source: prepared`` (selection on the prepared images; the full-resolution source, which
re-reads the raw frames, is tested in test_keypoints_source.py)."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import yaml

from f2depth.keypoints import select_pixels
from f2depth.keypoints.extract import extract_keypoints
from f2depth.keypoints.store import KeypointFile

ROOT = Path(__file__).resolve().parents[1]
H, W = 96, 128


def fake_prepared(root: Path, frames_per_scene: int = 5) -> list[np.ndarray]:
    """camera.json, frames.csv (+ empty tuples/pairs tables) and images; the last frame is flat."""
    rng = np.random.default_rng(0)
    rows, images = [], []
    for scene in ("kitchen_0001a", "office_0002"):
        for k in range(frames_per_scene):
            fid = f"{scene}_{k:04d}"
            noise = cv2.GaussianBlur(rng.normal(128, 50, (H, W, 3)).astype(np.float32), (0, 0), 1.2)
            rgb = np.clip(noise, 0, 255).astype(np.uint8)
            images.append(rgb)
            rel = f"images/{scene}/{fid}.png"
            (root / rel).parent.mkdir(parents=True, exist_ok=True)
            assert cv2.imwrite(str(root / rel), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
            rows.append([fid, scene, f"{scene}/r-{k}.ppm", rel, ""])
    flat = np.full((H, W, 3), 90, np.uint8)
    images[-1] = flat
    assert cv2.imwrite(str(root / rows[-1][3]), flat)
    K = [[0.9 * W, 0, W / 2], [0, 1.2 * H, H / 2], [0, 0, 1]]
    (root / "camera.json").write_text(json.dumps({"K": K, "height": H, "width": W, "p2net_cxcy_bug": False,
                                                  "crop": 16, "frame_step": 10}))
    tables = (("frames.csv", ["frame_id", "scene", "raw_file", "image", "gt"], rows),
              ("tuples.csv", ["tuple_id", "scene", "target", "prev", "next", "segments"], []),
              ("pairs.csv", ["pair_id", "scene", "frame1", "frame2"], []))
    for name, header, body in tables:
        with (root / name).open("w", newline="") as fh:
            csv.writer(fh).writerows([header, *body])
    return images


def test_stage_end_to_end(tmp_path):
    images = fake_prepared(tmp_path / "data" / "prepared")
    params = {
        "threads": 1,
        "data": {"prepared": "data/prepared", "keypoints": "data/keypoints"},
        "keypoints": {"source": "prepared", "preset": "p2net", "options": {}, "sequence": False, "workers": 2,
                      "overlays": 3, "overlay_dir": "reports/figures/keypoints"},
    }
    (tmp_path / "params.yaml").write_text(yaml.safe_dump(params))
    run = subprocess.run([sys.executable, str(ROOT / "stages" / "keypoints.py"), "params.yaml"], cwd=tmp_path,
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    kp = KeypointFile(tmp_path / "data" / "keypoints" / "train.npz")
    assert kp.frame_ids.tolist() == list(range(10))  # rows of frames.csv
    for i, rgb in enumerate(images):
        expected = select_pixels(cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY), "p2net")
        np.testing.assert_array_equal(kp.points(i), expected)
    assert len(kp.points(9)) == 0  # the flat frame
    metrics = json.loads((tmp_path / "metrics" / "keypoints.json").read_text())
    counts = np.diff(kp.offsets)
    assert metrics["frames"] == 10 and metrics["preset"] == "p2net" and metrics["size"] == [H, W]
    assert metrics["source"] == "prepared" and metrics["selector_input"] == [H, W]
    assert metrics["points_per_image"]["min"] == 0 == counts.min()
    assert metrics["points_per_image"]["max"] == counts.max()
    assert abs(metrics["points_per_image"]["mean"] - counts.mean()) < 1e-9
    assert metrics["share_below_100"] == 0.1 and metrics["empty_frames"] == 1
    assert metrics["seconds"] > 0 and 0 < metrics["duplicate_share"] < 1
    overlays = sorted((tmp_path / "reports" / "figures" / "keypoints").glob("*.png"))
    assert len(overlays) == 3
    picture = cv2.imread(str(overlays[0]))
    assert picture.shape[0] >= 480 + 24 and (picture.shape[0] - 24) % H == 0


def test_sequence_mode_carries_pot_within_scenes(tmp_path):
    fake_prepared(tmp_path / "prepared", frames_per_scene=3)
    out = tmp_path / "kp.npz"
    fresh = extract_keypoints(tmp_path / "prepared", out, None, "dso", {"density": 300}, workers=1,
                              progress=False, source="prepared")
    fresh_points = [KeypointFile(out).points(i).copy() for i in range(6)]
    seq = extract_keypoints(tmp_path / "prepared", out, None, "dso", {"density": 300}, workers=1,
                            sequence=True, progress=False, source="prepared")
    seq_points = [KeypointFile(out).points(i) for i in range(6)]
    assert fresh["sequence"] is False and seq["sequence"] is True
    assert fresh["options"]["density"] == 300 and seq["overlays"] == 0
    # first frame of each scene: both start at pot 3; later frames may differ
    np.testing.assert_array_equal(fresh_points[0], seq_points[0])
    np.testing.assert_array_equal(fresh_points[3], seq_points[3])
    assert any(not np.array_equal(a, b) for a, b in zip(fresh_points, seq_points))
