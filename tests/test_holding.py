"""What held in the 73-probe hostile run and must keep holding (issue 25): odd images through `predict`,
folders with symlink loops, a corrupted MLflow store, two `dvc repro` at once, and a flow fine-tuning
stage killed with -9 that resumes to the same weights."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import cv2
import fakes
import inference_data
import numpy as np
import pytest
import torch
from PIL import Image

from f2depth import tracking
from f2depth.cli import main

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent


@pytest.fixture(scope="module")
def ckpt(tmp_path_factory):
    torch.set_num_threads(1)
    return inference_data.make_checkpoint(tmp_path_factory.mktemp("model") / "depth.pt", seed=5)


def odd_images(folder: Path) -> dict[str, tuple[int, int]]:
    """Every kind of image the probes fed `predict`; returns name → the (H, W) its depth map must have."""
    folder.mkdir(parents=True)
    rgb = fakes.smooth_image((30, 40), 3)
    cv2.imwrite(str(folder / "gray.png"), cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY))
    cv2.imwrite(str(folder / "deep16.png"), (rgb.astype(np.uint16) * 257)[..., ::-1])
    Image.fromarray(rgb).convert("CMYK").save(folder / "cmyk.jpg")
    Image.fromarray(np.dstack([rgb, np.full((30, 40), 128, np.uint8)]), "RGBA").save(folder / "rgba.png")
    cv2.imwrite(str(folder / "one.png"), np.full((1, 1, 3), 90, np.uint8))
    cv2.imwrite(str(folder / "strip.png"), np.tile(rgb[:20, :1], (1, 500, 1))[:, :, ::-1].copy())  # 20×500
    cv2.imwrite(str(folder / "tall.png"), np.tile(rgb[:1, :20], (10000, 1, 1))[:, :, ::-1].copy())  # 10000×20
    return {"gray": (30, 40), "deep16": (30, 40), "cmyk": (30, 40), "rgba": (30, 40), "one": (1, 1),
            "strip": (20, 500), "tall": (10000, 20)}


def test_predict_takes_every_kind_of_image_and_ignores_symlink_loops(ckpt, tmp_path, capfd):
    sizes = odd_images(tmp_path / "in")
    (tmp_path / "in" / "loop.png").symlink_to(tmp_path / "in" / "loop.png")  # a link to itself
    (tmp_path / "in" / "dangling.png").symlink_to(tmp_path / "nowhere.png")
    (tmp_path / "in" / "sub").mkdir()
    (tmp_path / "in" / "sub" / "up").symlink_to(tmp_path / "in", target_is_directory=True)  # a folder loop
    code = main(["predict", "--model", str(ckpt), "--input", str(tmp_path / "in"), "--output",
                 str(tmp_path / "out"), "--no-progress"])
    assert code == 0 and f"wrote {len(sizes)} frame(s)" in capfd.readouterr().out
    for name, hw in sizes.items():
        depth = np.load(tmp_path / "out" / f"{name}_depth.npy")
        assert depth.shape == hw and np.isfinite(depth).all() and (depth > 0).all(), name
        assert cv2.imread(str(tmp_path / "out" / f"{name}_depth_mm.png"), cv2.IMREAD_UNCHANGED).shape == hw


def test_a_video_with_no_frames_is_one_line(ckpt, tmp_path, capfd):
    path = tmp_path / "empty.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10, (40, 30))
    writer.release()  # a container with no frame in it
    code = main(["predict", "--model", str(ckpt), "--input", str(path), "--output", str(tmp_path / "out")])
    err = capfd.readouterr().err.splitlines()
    assert code == 1 and len(err) == 1 and str(path) in err[0], err
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").glob("*_depth.npy"))


def test_a_corrupted_mlflow_store_only_warns(tmp_path, monkeypatch, caplog):
    db = tmp_path / "mlflow.db"
    db.write_bytes(b"this is not an SQLite database" * 100)
    monkeypatch.setenv("MLFLOW_TRACKING_URI", f"sqlite:///{db}")
    monkeypatch.setenv("F2DEPTH_MLFLOW", "1")
    ran = []
    with tracking.stage_run("probe", {"seed": 0}) as run:
        run.log_metrics({"x": 1.0}, step=0)
        ran.append(True)
    assert ran == [True]
    assert "MLflow mirror off" in caplog.text and str(db) in caplog.text


def test_two_dvc_repro_at_once_are_refused_naming_the_lock(tmp_path):
    repo = tmp_path / "repo"
    repo.mkdir()
    env = {**os.environ, "PATH": f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}"}
    for cmd in (["git", "init", "-q"], ["dvc", "init", "-q"], ["dvc", "config", "core.analytics", "false"]):
        subprocess.run(cmd, cwd=repo, env=env, check=True, capture_output=True)
    (repo / "dvc.yaml").write_text("stages:\n  slow:\n    cmd: touch started && sleep 20 && echo done > "
                                   "out.txt\n    outs:\n      - out.txt\n")
    first = subprocess.Popen(["dvc", "repro"], cwd=repo, env=env, stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60
        while not (repo / "started").exists():  # the first repro holds the lock and runs its stage
            assert first.poll() is None and time.monotonic() < deadline, first.communicate()
            time.sleep(0.1)
        second = subprocess.run(["dvc", "repro"], cwd=repo, env=env, capture_output=True, text=True,
                                timeout=120)
        assert second.returncode != 0
        # DVC's words: "... 'out.txt' is busy, it is being blocked by: (PID n): dvc repro ... remove
        # '.dvc/tmp/rwlock'" (it waits for the repository lock, then refuses on the stage's outputs)
        assert "is being blocked by" in second.stderr and "rwlock" in second.stderr, second.stderr
        assert not (repo / "out.txt").exists()  # nothing written by the refused run
    finally:
        first.kill()
        first.communicate()


def test_flow_finetune_killed_with_9_resumes_to_the_same_weights(tmp_path):
    """kill -9 after the first epoch's state is written, run again: the weights equal an uninterrupted
    run's (the per-epoch state is written atomically and shuffling is seeded by (seed, epoch))."""
    from test_flow_finetune import write_fake_prepared, write_stage_params

    from f2depth.flow.net.checkpoint import load_flow_model, save_flow_model
    from f2depth.flow.net.pwclite import PWCLite

    env = {**os.environ, "F2DEPTH_MLFLOW": "0", "OMP_NUM_THREADS": "1"}
    command = [sys.executable, str(ROOT / "stages" / "flow_finetune.py"), "--loss", "patch"]
    runs = {}
    for name in ("killed", "whole"):
        root = tmp_path / name
        write_fake_prepared(root / "data" / "prepared")
        torch.manual_seed(0)
        save_flow_model(root / "models" / "flow_pretrained.pt", PWCLite())
        write_stage_params(root, epochs=3)
        if name == "killed":
            proc = subprocess.Popen(command, cwd=root, env=env, stdout=subprocess.DEVNULL,
                                    stderr=subprocess.DEVNULL)
            state = root / "tmp" / "flow_finetune" / "patch.pt"
            deadline = time.monotonic() + 300
            while not state.exists():
                assert proc.poll() is None and time.monotonic() < deadline, "finished before it was killed"
                time.sleep(0.02)
            proc.send_signal(signal.SIGKILL)
            proc.wait()
            assert not (root / "models" / "flow_patch.pt").exists()
        subprocess.run(command, cwd=root, env=env, check=True, capture_output=True)
        metrics = json.loads((root / "metrics" / "flow_finetune" / "patch.json").read_text())
        runs[name] = (load_flow_model(root / "models" / "flow_patch.pt").state_dict(), metrics)
    (killed, killed_metrics), (whole, _) = runs["killed"], runs["whole"]
    assert killed_metrics["resumed_from"] >= 1
    assert all(torch.equal(killed[k], whole[k]) for k in whole)


def test_keypoints_killed_with_9_redo_the_same_file(tmp_path):
    """kill -9 in the middle of the `keypoints` stage leaves no output that looks valid, and the re-run
    writes the file an uninterrupted run writes, byte for byte."""
    import yaml
    from test_keypoints_stage import fake_prepared

    params = {"threads": 1, "data": {"prepared": "data/prepared", "keypoints": "data/keypoints"},
              "keypoints": {"source": "prepared", "preset": "p2net", "options": {}, "sequence": False,
                            "workers": 1, "overlays": 1, "overlay_dir": "reports/figures/keypoints"}}
    command = [sys.executable, str(ROOT / "stages" / "keypoints.py"), "params.yaml"]
    out = {}
    for name in ("killed", "whole"):
        root = tmp_path / name
        fake_prepared(root / "data" / "prepared", frames_per_scene=40)
        (root / "params.yaml").write_text(yaml.safe_dump(params))
        if name == "killed":
            proc = subprocess.Popen(command, cwd=root, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                                    text=True)
            deadline = time.monotonic() + 120
            while "frame" not in (line := proc.stderr.readline()):  # its progress bar: selection under way
                assert line or proc.poll() is None, "ended before it could be killed"
                assert time.monotonic() < deadline
            proc.send_signal(signal.SIGKILL)
            proc.wait()
            assert not (root / "data" / "keypoints" / "train.npz").exists()
        subprocess.run(command, cwd=root, check=True, capture_output=True, timeout=300)
        out[name] = (root / "data" / "keypoints" / "train.npz").read_bytes()
        leftovers = [p.name for p in (root / "data" / "keypoints").iterdir() if p.name != "train.npz"]
        assert leftovers == [], leftovers
    assert out["killed"] == out["whole"]


def test_a_locked_mlflow_store_only_warns(tmp_path, monkeypatch, caplog):
    import sqlite3

    db = tmp_path / "mlflow.db"
    monkeypatch.setenv("MLFLOW_TRACKING_URI", f"sqlite:///{db}")
    monkeypatch.setenv("F2DEPTH_MLFLOW", "1")
    with tracking.stage_run("first", {"seed": 0}) as run:  # creates the store
        run.log_metrics({"x": 1.0}, step=0)
    holder = sqlite3.connect(db, timeout=0.1)
    holder.execute("BEGIN EXCLUSIVE")  # another process holds the database
    try:
        ran = []
        with tracking.stage_run("second", {"seed": 0}) as run:
            run.log_metrics({"x": 2.0}, step=0)
            ran.append(True)
    finally:
        holder.rollback()
        holder.close()
    assert ran == [True] and "MLflow mirror off" in caplog.text


@pytest.mark.slow
def test_flow_pretrain_killed_with_9_resumes_to_the_same_weights(tmp_path):
    """The chairs route (the CPU default), killed with -9 once its first epoch's state is written, then run
    again: the teacher equals an uninterrupted run's, bit for bit."""
    from test_flow_pretrain import STAGE, tiny_chairs, write_stage_inputs

    from f2depth.flow.net.checkpoint import load_flow_model

    env = {**os.environ, "F2DEPTH_MLFLOW": "0", "OMP_NUM_THREADS": "1"}
    chairs = {**tiny_chairs(), "feature_epochs": 1, "epochs": 3, "steps_per_epoch": 3, "average_epochs": 2}
    weights = {}
    for name in ("killed", "whole"):
        root = tmp_path / name
        root.mkdir()
        write_stage_inputs(root, source="chairs", passes=["clean"], chairs=chairs)
        command = [sys.executable, str(STAGE), str(root / "params.yaml")]
        if name == "killed":
            proc = subprocess.Popen(command, cwd=root, env=env, stdout=subprocess.DEVNULL,
                                    stderr=subprocess.DEVNULL)
            deadline = time.monotonic() + 300
            while not [p for p in root.glob("tmp/flow_pretrain/*.pt") if not p.name.startswith(".")]:
                assert proc.poll() is None and time.monotonic() < deadline, "finished before it was killed"
                time.sleep(0.02)
            proc.send_signal(signal.SIGKILL)
            proc.wait()
            assert not (root / "models" / "flow_pretrained.pt").exists()
        subprocess.run(command, cwd=root, env=env, check=True, capture_output=True, timeout=300)
        weights[name] = load_flow_model(root / "models" / "flow_pretrained.pt").state_dict()
        training = json.loads((root / "metrics" / "flow_pretrain.json").read_text())["training"]
        assert (training["resumed_from"] >= 1) == (name == "killed")
    assert all(torch.equal(weights["killed"][k], weights["whole"][k]) for k in weights["whole"])


@pytest.mark.parametrize("kind", ["depth", "flow"])
def test_a_truncated_model_file_is_one_line(ckpt, tmp_path, capfd, kind):
    from f2depth.errors import CheckpointError
    from f2depth.flow.net.checkpoint import load_flow_model, save_flow_model
    from f2depth.flow.net.pwclite import PWCLite

    if kind == "depth":
        whole = Path(ckpt).read_bytes()
        (tmp_path / "cut.pt").write_bytes(whole[: len(whole) // 3])
        inference_data.write_images(tmp_path / "in", 1)
        code = main(["predict", "--model", str(tmp_path / "cut.pt"), "--input", str(tmp_path / "in"),
                     "--output", str(tmp_path / "out")])
        err = capfd.readouterr().err.splitlines()
        assert code == 1 and len(err) == 1 and str(tmp_path / "cut.pt") in err[0], err
    else:
        save_flow_model(tmp_path / "flow.pt", PWCLite())
        whole = (tmp_path / "flow.pt").read_bytes()
        (tmp_path / "cut.pt").write_bytes(whole[: len(whole) // 3])
        with pytest.raises(CheckpointError, match=rf"^{tmp_path / 'cut.pt'}: "):
            load_flow_model(tmp_path / "cut.pt")


@pytest.mark.slow
def test_twelve_hundred_images_stream_in_bounded_memory(ckpt, tmp_path):
    """`predict` streams a folder: a frame's image and depth are dropped once its files are written, so
    memory does not grow with the number of frames (1,000 frames after the first 200: ~86 MB of image and
    depth pixels, twice the bound on the growth)."""
    import resource

    from f2depth.inference.backends import TorchBackend
    from f2depth.inference.predict import Predictor, PredictSettings, run_predict
    from f2depth.ingest.sources import open_source

    folder = tmp_path / "in"
    folder.mkdir()
    for i in range(1200):
        cv2.imwrite(str(folder / f"f{i:04d}.png"), np.full((96, 128, 3), i % 251, np.uint8))
    frames = iter(open_source(folder))
    predictor = Predictor(TorchBackend.from_checkpoint(ckpt, "cpu"))
    settings = PredictSettings(tmp_path / "out", batch_size=8, progress=False)

    def head(n):
        for _ in range(n):
            yield next(frames)

    run_predict(head(200), predictor, settings)
    peak_after_200 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # KiB on Linux
    summary = run_predict(head(1000), predictor, settings)
    growth_mib = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - peak_after_200) / 1024
    # the second run replaced the first's frames (issue 53: an output folder holds one run's frames)
    assert summary["frames"] == 1000 and len(list((tmp_path / "out").glob("*_depth.npy"))) == 1000
    assert growth_mib < 40, f"peak memory grew by {growth_mib:.0f} MiB over 1,000 more frames"
