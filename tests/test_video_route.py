"""The embedded "own video" and the video route: synth's NYU-raw scenes as MP4 clips (a static stretch, a
fast stretch, NYU's lens), the `ingest` stage that turns data.video into data.ingested, and `train_source`,
which points prepare, keypoints and poses at it."""

from __future__ import annotations

import importlib.util
import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from f2depth.camera import NYU_RAW_CAMERA
from f2depth.data.training_video import training_video
from f2depth.errors import DataError
from f2depth.formats.nyu_raw import list_frames, read_frame
from f2depth.ingest.camera_files import read_camera_file
from f2depth.io import OUTPUT_MARKER
from f2depth.synth import OutputPaths, SynthConfig, generate
from f2depth.synth.clips import ClipsParams, clip_frames, write_clips

ROOT = Path(__file__).resolve().parents[1]
CLIPS = ClipsParams(static_frames=5, fast_share=0.3, fast_step=3, fps=30.0)
SMALL = SynthConfig(seed=1, workers=0, supersample=1, nyu_raw_scenes=2, nyu_raw_frames=10, labeled_images=2,
                    sevenscenes_scenes=1, sevenscenes_frames=2, campus_scenes=1, campus_images=1,
                    animated_sequences=1, animated_frames=2, animated_hw=(64, 64), clips=CLIPS)


@pytest.fixture(scope="module")
def world(tmp_path_factory) -> OutputPaths:
    paths = OutputPaths.under(tmp_path_factory.mktemp("world"))
    generate(SMALL, paths, progress=False)
    return paths


def _decode(path: Path) -> list[np.ndarray]:
    cap = cv2.VideoCapture(str(path))
    frames = []
    while True:
        ok, bgr = cap.read()
        if not ok:
            break
        frames.append(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB))
    cap.release()
    return frames


def test_the_clip_order_has_the_static_and_the_fast_stretch():
    order, fast_from = clip_frames(10, ClipsParams(3, 0.3, 2, 30.0))
    assert order == [0, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 9] and fast_from == 10
    assert clip_frames(4, ClipsParams(0, 0.0, 5, 30.0)) == ([0, 1, 2, 3], 4)


def test_synth_writes_each_raw_scene_as_a_clip_of_its_frames(world):
    report = json.loads((world.clips / "clips.json").read_text())
    scenes = sorted(d.name for d in world.nyu_raw.iterdir() if d.is_dir())
    assert sorted(report["clips"]) == scenes and len(scenes) == 2
    for scene in scenes:
        raw = list_frames(world.nyu_raw, scene)
        order, _ = clip_frames(len(raw), CLIPS)
        decoded = _decode(world.clips / f"{scene}.mp4")
        assert len(decoded) == len(order) == report["clips"][scene]["frames"]
        assert report["clips"][scene]["raw_frames"] == [raw[i].stem for i in order]
        for k in (0, CLIPS.static_frames - 1, len(order) - 1):  # a static copy, the last frame
            truth = read_frame(raw[order[k]].path).astype(np.float64)
            assert np.abs(decoded[k].astype(np.float64) - truth).mean() < 4.0, (scene, k)  # MPEG-4 noise
        still = [np.abs(decoded[k].astype(np.float64) - decoded[0]).mean()
                 for k in range(CLIPS.static_frames)]
        assert max(still) < 1.0, still  # the static stretch decodes as one picture
    camera = read_camera_file(world.clips / "camera.json")
    np.testing.assert_allclose(camera.K, NYU_RAW_CAMERA.K)
    np.testing.assert_allclose(camera.dist, NYU_RAW_CAMERA.dist)
    assert camera.hw == NYU_RAW_CAMERA.hw


def test_a_smaller_generation_removes_only_the_clips_it_wrote_before(world, tmp_path):
    out = tmp_path / "clips"
    scenes = sorted(d.name for d in world.nyu_raw.iterdir() if d.is_dir())
    write_clips(world.nyu_raw, scenes, out, CLIPS)
    (out / "mine.mp4").write_bytes(b"a user's clip")
    write_clips(world.nyu_raw, scenes[:1], out, CLIPS)
    assert sorted(p.name for p in out.glob("*.mp4")) == [f"{scenes[0]}.mp4", "mine.mp4"]


def _stage(name: str):
    spec = importlib.util.spec_from_file_location(f"stage_{name}", ROOT / "stages" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _params(tmp_path: Path, world: OutputPaths, **top) -> Path:
    params = yaml.safe_load((ROOT / "params.yaml").read_text())
    params["threads"] = 1
    params["data"].update(video=str(world.clips), video_camera=str(world.clips / "camera.json"),
                          ingested=str(tmp_path / "ingested"), nyu_raw=str(world.nyu_raw))
    params.update(top)
    path = tmp_path / "params.yaml"
    path.write_text(yaml.safe_dump(params))
    return path


def test_the_ingest_stage_drops_the_static_stretch_and_keeps_the_camera(world, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("F2DEPTH_MLFLOW", "0")
    _stage("ingest").main(["ingest.py", str(_params(tmp_path, world))])
    metrics = json.loads((tmp_path / "metrics" / "ingest.json").read_text())
    assert metrics["scenes"] == 2 and metrics["static"] >= 2 * (CLIPS.static_frames - 1)
    assert "camera file" in metrics["input_camera"]["intrinsics_source"]
    np.testing.assert_allclose(metrics["input_camera"]["K"], NYU_RAW_CAMERA.K)
    for scene, row in metrics["per_scene"].items():
        kept = sorted(int(f.stem.split("-")[-1]) for f in (tmp_path / "ingested" / scene).glob("r-*.png"))
        assert len(kept) == row["kept"] >= 3
        assert kept[0] == 0 and kept[1] > CLIPS.static_frames  # clip frames 0..static are one raw frame
    assert (tmp_path / "ingested" / "scenes.txt").read_text().split() == sorted(metrics["per_scene"])


def test_without_a_camera_file_too_short_clips_ask_for_one_and_write_nothing(world, tmp_path, monkeypatch):
    """data.video_camera null: the stage self-calibrates (tests/test_ingest.py shows it on a longer clip);
    on clips with too little motion for it, one line asks for a camera file or --fov, nothing written."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("F2DEPTH_MLFLOW", "0")
    params = _params(tmp_path, world)
    data = yaml.safe_load(params.read_text())
    data["data"]["video_camera"] = None
    params.write_text(yaml.safe_dump(data))
    with pytest.raises(DataError, match=r"clips/\w+\.mp4: unknown intrinsics and self-calibration failed: "
                                        r"\d+ frame pairs .*; give --fov DEG"):
        _stage("ingest").main(["ingest.py", str(params)])
    assert not (tmp_path / "ingested").exists() and not (tmp_path / "metrics" / "ingest.json").exists()


def test_without_clips_the_nyu_route_ingests_nothing_and_the_video_route_stops(world, tmp_path, monkeypatch,
                                                                               capsys):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("F2DEPTH_MLFLOW", "0")
    empty = OutputPaths.under(tmp_path / "real")
    shutil.copytree(world.nyu_raw, empty.nyu_raw)
    empty.clips.mkdir(parents=True)
    (empty.clips / "README.txt").write_text("data_source is 'real'\n")
    stage = _stage("ingest")
    stage.main(["ingest.py", str(_params(tmp_path, empty))])
    assert json.loads((tmp_path / "metrics" / "ingest.json").read_text())["scenes"] == 0
    assert sorted(p.name for p in (tmp_path / "ingested").iterdir()) == [OUTPUT_MARKER, "README.txt"]
    params = _params(tmp_path, empty, train_source="video")
    with pytest.raises(SystemExit) as info:
        stage.run_stage("ingest", stage.main, ["ingest.py", str(params)])
    err = capsys.readouterr().err.strip()
    assert info.value.code == 1 and "\n" not in err and str(empty.clips) in err


def test_train_source_points_prepare_keypoints_and_poses_at_the_ingested_frames(world, tmp_path):
    params = {"_file": "p.yaml", "train_source": "nyu_raw",
              "data": {"nyu_raw": "data/raw/nyu_raw", "ingested": "data/ingested"}}
    nyu = training_video(params)
    assert (nyu.root, nyu.scenes_file) == ("data/raw/nyu_raw", None)
    video = training_video({**params, "train_source": "video"})
    assert (video.root, video.scenes_file) == ("data/ingested", "data/ingested/scenes.txt")
    from f2depth.params import ParamsError

    with pytest.raises(ParamsError, match="train_source"):
        training_video({**params, "train_source": "youtube"})
    for name in ("prepare", "keypoints", "poses"):
        assert "training_video(p)" in (ROOT / "stages" / f"{name}.py").read_text(), name


def test_ingesting_the_same_clips_twice_gives_the_same_bytes(world, tmp_path):
    """DVC hashes data.ingested: an identical re-run must not re-run prepare and everything after it."""
    import hashlib

    from f2depth.ingest.run import IngestConfig, ingest

    config = IngestConfig(frame_step=1, rate=None, min_motion=0.003, min_sharpness=0, max_side=640)
    digests = []
    for name in ("a", "b"):
        out = tmp_path / name
        ingest([world.clips], out, config, camera_file=world.clips / "camera.json", progress=False)
        digests.append({str(f.relative_to(out)): hashlib.sha256(f.read_bytes()).hexdigest()
                        for f in sorted(out.rglob("*")) if f.is_file()})
    assert digests[0] == digests[1] and len(digests[0]) > 6
