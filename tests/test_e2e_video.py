"""End to end on a video the project makes (issue 23): `train_source: video` in the tiny DVC repository of
test_e2e_pipeline. synth writes its NYU-raw scenes as MP4 clips (a static stretch first, NYU's lens, the
camera file beside them), the `ingest` stage drops the static frames and undistorts with the camera file,
prepare / keypoints / poses / train_depth run on the ingested frames (the last frames of each clip held out
and scored against the room's ground truth), and `f2depth predict` runs the trained model on a clip.
Marked ``e2e``."""

from __future__ import annotations

import json

import numpy as np
import pytest
from test_e2e_pipeline import BIN, run, tiny_repo

from f2depth.camera import NYU_RAW_CAMERA


@pytest.mark.e2e
def test_the_video_route_trains_on_the_ingested_clips_and_predicts_on_a_clip(tmp_path):
    repo, params, env = tiny_repo(tmp_path, {"train_source": "video", "prepare.frame_step": 1,
                                             "prepare.val_share": 0.3})
    run([str(BIN / "dvc"), "repro", "train_depth@baseline"], repo, env, timeout=900)

    ingest = json.loads((repo / "metrics" / "ingest.json").read_text())
    static = params["synth"]["clips"]["static_frames"]
    assert ingest["scenes"] == params["synth"]["nyu_raw"]["scenes"]
    for scene, row in ingest["per_scene"].items():
        assert row["static"] >= static, scene  # the static copies (and frame 0 twice) were dropped
    np.testing.assert_allclose(ingest["input_camera"]["K"], NYU_RAW_CAMERA.K)  # the camera file, exactly

    camera = json.loads((repo / "data" / "prepared" / "camera.json").read_text())
    assert "f2depth ingest" in camera["intrinsics_source"]  # prepared from the ingested frames
    frames = (repo / "data" / "prepared" / "frames.csv").read_text().splitlines()[1:]
    assert frames and all(row.split(",")[2].endswith(".png") for row in frames)  # raw_file: ingested PNG
    poses = json.loads((repo / "metrics" / "poses.json").read_text())
    assert poses["frames"] == ingest["kept"]  # tracked over every ingested frame (too few here to register:
    # the default-size clips register 100 %, docs/experiments/2026-12-04-video-route.md)
    # the clips were ingested with the camera they were rendered with: synth's clip index finds each frame's
    # ground truth, so the room's own held-out frames are scored (f2depth.train.heldout)
    assert all(row.split(",")[4] for row in frames)
    prepare = json.loads((repo / "metrics" / "prepare.json").read_text())
    assert prepare["val_tuples"] >= 1 and prepare["held_out_frames"] >= 3
    train = json.loads((repo / "metrics" / "train_depth" / "baseline.json").read_text())
    assert train["train_tuples"] >= 2
    assert train["heldout"]["tuples"] == prepare["val_tuples"]
    assert 0 <= train["heldout_trained"]["a1"] <= 1 and train["heldout_trained"]["ph"] > 0
    assert train["heldout"]["identity_ph"] > 0 and train["heldout"]["constant_a1"] is not None

    scene = sorted(ingest["per_scene"])[0]
    out = run([str(BIN / "f2depth"), "predict", "--model", "models/depth_baseline/model.pt", "--input",
               f"data/raw/clips/{scene}.mp4", "--output", "out", "--no-progress"], repo, env)
    clip_frames = json.loads((repo / "data" / "raw" / "clips" / "clips.json").read_text())["clips"][scene]
    assert f"wrote {clip_frames['frames']} frame(s)" in out.stdout
