"""The synthetic world: determinism, exact ground truth, camera motion, and the real datasets' formats
as real users' readers see them (h5py, scipy, OpenCV, numpy, csv)."""

from __future__ import annotations

import csv
import json
import os
from dataclasses import replace
from pathlib import Path

import cv2
import h5py
import numpy as np
import pytest
import scipy.io

from f2depth.camera import NYU_RGB_DIST, NYU_RGB_K
from f2depth.formats.nyu_labeled import scene_names
from f2depth.formats.sintel import read_flo
from f2depth.params import ParamsError
from f2depth.synth import OutputPaths, SynthConfig, generate, jobs, plan, writers
from f2depth.synth.camera_path import PathStyle, handheld_path, rotation
from f2depth.synth.groundtruth import occlusion, relative_pose, rigid_flow
from f2depth.synth.layout import build
from f2depth.synth.render import render
from f2depth.synth.scene import Box, Light, Material, bake
from f2depth.synth.sensor import expose
from f2depth.synth.writers import DEPTH_STEP, FLOW_STEP

REPO = Path(__file__).resolve().parents[1]

TINY = SynthConfig(
    seed=3,
    workers=0,
    supersample=2,
    nyu_raw_scenes=1,
    nyu_raw_frames=3,
    labeled_images=2,
    sevenscenes_scenes=1,
    sevenscenes_frames=2,
    campus_scenes=1,
    campus_images=1,
    animated_sequences=1,
    animated_frames=2,
    animated_hw=(96, 128),
    flow_gt=True,
    sensor_effects=False,
)


@pytest.fixture(scope="module")
def tiny(tmp_path_factory) -> OutputPaths:
    """A tiny generated world without sensor noise (exact photometric consistency)."""
    paths = OutputPaths.under(tmp_path_factory.mktemp("synth"))
    generate(TINY, paths, progress=False)
    return paths


def _files(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def test_generation_is_deterministic_and_independent_of_workers(tmp_path):
    cfg = SynthConfig(**{**TINY.__dict__, "sensor_effects": True, "labeled_images": 2, "campus_scenes": 1})
    generate(cfg, OutputPaths.under(tmp_path / "a"), progress=False)
    generate(SynthConfig(**{**cfg.__dict__, "workers": 2}), OutputPaths.under(tmp_path / "b"), progress=False)
    a, b = _files(tmp_path / "a"), _files(tmp_path / "b")
    assert len(a) > 40
    assert a.keys() == b.keys()
    different = [k for k in a if a[k] != b[k]]
    assert not different, f"not byte-identical: {different[:5]}"


def test_different_seed_gives_a_different_world():
    K = NYU_RGB_K / 4
    K[2, 2] = 1
    images = []
    for seed in (0, 1):
        scene = jobs.room("nyu", "office", "office_0001", seed)
        pose = handheld_path(scene, 1, plan.rng_for(seed, "view"))[0][0]
        images.append(render(scene, pose, K, (120, 160), 1)[0])
    assert np.abs(images[0] - images[1]).mean() > 0.01
    again = render(jobs.room("nyu", "office", "office_0001", 0), pose, K, (120, 160), 1)[0]
    assert np.array_equal(
        again, render(jobs.room("nyu", "office", "office_0001", 0), pose, K, (120, 160), 1)[0]
    )


def _empty_room() -> tuple:
    flat = Material("flat", (0.7, 0.7, 0.7), 20.0, amp=0.02)
    room = Box((0.0, 0.0, 0.0), (4.0, 5.0, 2.6), (flat,) * 6, "room")
    table = Box((1.5, 2.5, 0.0), (2.5, 3.2, 0.75), (flat,) * 6, "table")
    scene = bake(
        "test", room, [table], [Light((2.0, 2.0, 2.3), (3.0, 3.0, 3.0))], 0.3, np.random.default_rng(0)
    )
    return scene, room, table


def test_render_depth_is_the_analytic_first_hit():
    scene, room, table = _empty_room()
    K = np.array([[100.0, 0, 79.5], [0, 100.0, 59.5], [0, 0, 1]])
    T = np.eye(4)
    T[:3, :3] = rotation(0.3, -0.4, 0.05)
    T[:3, 3] = (0.8, 0.9, 1.4)
    _, depth = render(scene, T, K, (120, 160), 2)
    u, v = np.meshgrid(np.arange(160.0), np.arange(120.0))
    d = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1) @ T[:3, :3].T
    o = T[:3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        # room: nearest exit plane; table: slab test
        exits = np.where(d > 0, (np.array(room.hi) - o) / d, (np.array(room.lo) - o) / d)
        expect = exits.min(-1)
        t0, t1 = (np.array(table.lo) - o) / d, (np.array(table.hi) - o) / d
        tn, tf = np.minimum(t0, t1).max(-1), np.maximum(t0, t1).min(-1)
        expect = np.where((tn <= tf) & (tn > 0), np.minimum(expect, tn), expect)
    np.testing.assert_allclose(depth, expect, rtol=1e-4)
    assert (expect < exits.min(-1) - 1e-3).sum() > 100  # the table is in view


def test_gt_flow_warps_the_next_frame_onto_the_frame():
    scene = jobs.room("nyu", "living_room", "living_room_0042", 0)
    K = NYU_RGB_K / 2
    K[2, 2] = 1
    poses, _ = handheld_path(scene, 4, np.random.default_rng(5))
    a_rad, a_depth = render(scene, poses[0], K, (240, 320), 2, adaptive=False)
    b_rad, b_depth = render(scene, poses[3], K, (240, 320), 2, adaptive=False)
    a = expose(a_rad, scene.exposure, None, 0.0, None).astype(np.float32)
    b = expose(b_rad, scene.exposure, None, 0.0, None).astype(np.float32)
    flow, z = rigid_flow(a_depth, K, relative_pose(poses[0], poses[3]))
    occ = occlusion(flow, z, b_depth)
    u, v = np.meshgrid(np.arange(320, dtype=np.float32), np.arange(240, dtype=np.float32))
    warped = cv2.remap(b, u + flow[..., 0], v + flow[..., 1], cv2.INTER_LINEAR)
    still = cv2.remap(b, u, v, cv2.INTER_LINEAR)
    ok = ~occ
    ok[:4], ok[-4:], ok[:, :4], ok[:, -4:] = False, False, False, False
    assert ok.mean() > 0.8
    assert np.linalg.norm(flow, axis=2)[ok].mean() > 2.0  # the camera did move
    err = np.abs(warped - a)[ok].mean()
    assert err < 1.5, err  # 8-bit levels
    assert err < 0.25 * np.abs(still - a)[ok].mean()


def test_the_ground_truth_shares_the_training_geometrys_pose_convention():
    """One pose convention: the synth's exact numpy ground truth (relative pose, rigid flow, target depth)
    equals f2depth.geometry's, which training uses, up to geometry's PROJ_EPS in the projection."""
    import torch

    from f2depth import geometry as G

    rng = np.random.default_rng(5)
    depth = (0.5 + 6 * rng.random((48, 64))).astype(np.float32)
    K = np.array([[52.0, 0, 31.5], [0, 53.0, 24.0], [0, 0, 1]])
    world_T = [G.pose_from_params(torch.tensor(rng.normal(size=(1, 3)) * 0.05),
                                  torch.tensor(rng.normal(size=(1, 3)) * 0.1))[0].numpy() for _ in range(2)]
    tgt_T_src = relative_pose(world_T[0], world_T[1])
    ours = G.relative_pose(torch.tensor(world_T[0]), torch.tensor(world_T[1])).numpy()
    np.testing.assert_allclose(tgt_T_src, ours, atol=1e-14)
    flow, z_tgt = rigid_flow(depth, K, tgt_T_src)
    depth_t = torch.from_numpy(depth.astype(np.float64))[None, None]
    K_t, T_t = torch.tensor(K)[None], torch.tensor(tgt_T_src)[None]
    train_flow = G.rigid_flow(depth_t, K_t, T_t)
    _, train_z = G.project(G.backproject(depth_t, torch.linalg.inv(K_t)), K_t, T_t)
    assert np.abs(flow).max() > 1.0  # a real motion, not the identity
    np.testing.assert_allclose(flow, train_flow[0].permute(1, 2, 0).numpy(), atol=1e-4)  # PROJ_EPS / z
    np.testing.assert_allclose(z_tgt, train_z[0, 0].numpy(), rtol=1e-6)


def test_stored_flow_is_the_projection_of_depth_with_the_relative_pose(tiny):
    scene = next((tiny.synth_gt / "nyu_raw").iterdir())
    files = sorted(scene.glob("*.npz"), key=lambda p: float(p.stem.split("-")[1]))
    g0, g1 = np.load(files[0]), np.load(files[1])
    assert "flow" not in np.load(files[-1]).files  # the last frame has no successor
    K, depth = g0["K"], g0["depth"].astype(np.float64)
    h, w = depth.shape
    u, v = np.meshgrid(np.arange(w), np.arange(h))
    pts = np.stack(
        [(u - K[0, 2]) / K[0, 0] * depth, (v - K[1, 2]) / K[1, 1] * depth, depth, np.ones_like(depth)], -1
    )
    cam1 = pts @ (np.linalg.inv(g1["world_T_cam"]) @ g0["world_T_cam"]).T
    proj = np.stack(
        [K[0, 0] * cam1[..., 0] / cam1[..., 2] + K[0, 2], K[1, 1] * cam1[..., 1] / cam1[..., 2] + K[1, 2]], -1
    )
    np.testing.assert_allclose(g0["flow"], proj - np.stack([u, v], -1), atol=2e-3)
    assert g0["flow"].dtype == np.float32 and g0["occluded"].dtype == bool
    assert g0["occluded"].mean() < 0.2


def test_compressed_ground_truth_stays_within_its_grid(tmp_path):
    rng = np.random.default_rng(0)
    v, u = np.mgrid[0:60, 0:80].astype(np.float32)
    depth = 1.0 / (0.3 + 0.001 * u + 0.002 * v)  # a plane, as the renders are made of
    flow = np.stack([0.1 * u + 3.0 / depth, 0.05 * v - 1.0 / depth], -1).astype(np.float32)
    occ = rng.random((60, 80)) < 0.1
    T, K = np.eye(4), np.eye(3)
    writers.write_gt(tmp_path / "a.npz", depth, T, K, flow, occ, compress=True)
    writers.write_gt(tmp_path / "b.npz", depth, T, K, flow, occ, compress=False)
    a, b = np.load(tmp_path / "a.npz"), np.load(tmp_path / "b.npz")
    np.testing.assert_array_equal(b["depth"], depth)
    np.testing.assert_array_equal(b["flow"], flow)
    assert np.abs(a["depth"] - depth).max() <= DEPTH_STEP / 2
    assert np.abs(a["flow"] - flow).max() <= FLOW_STEP / 2
    np.testing.assert_array_equal(a["occluded"], occ)
    assert (tmp_path / "a.npz").stat().st_size < 0.8 * (tmp_path / "b.npz").stat().st_size


def test_nyu_raw_frames_are_distorted_like_the_nyu_lens(tiny):
    scene_dir = next(tiny.nyu_raw.iterdir())
    frames = sorted(scene_dir.glob("r-*.ppm"), key=lambda p: float(p.stem.split("-")[1]))
    stamps = np.array([float(p.stem.split("-")[1]) for p in frames])
    np.testing.assert_allclose(np.diff(stamps), 1 / 30, atol=2e-6)
    assert frames[0].read_bytes()[:2] == b"P6"
    raw = cv2.imread(str(frames[0]))[..., ::-1]
    assert raw.shape == (480, 640, 3)
    gt = np.load(tiny.synth_gt / "nyu_raw" / scene_dir.name / f"{frames[0].stem}.npz")
    name, kind = plan.nyu_raw_scenes(TINY)[0]
    scene = jobs.room("nyu", kind, name, TINY.seed)
    ideal = expose(
        render(scene, gt["world_T_cam"], gt["K"], (480, 640), 2)[0], scene.exposure, None, 0.0, None
    )
    undist = cv2.undistort(raw, NYU_RGB_K, NYU_RGB_DIST)
    inner = (slice(40, 440), slice(40, 600))
    err = np.abs(undist[inner].astype(float) - ideal[inner]).mean()
    assert err < 2.0, err
    assert err < 0.5 * np.abs(raw[inner].astype(float) - ideal[inner]).mean()  # distortion is really there


def test_nyu_labeled_mat_has_the_real_layout(tiny):
    assert tiny.nyu_labeled.read_bytes()[:19] == b"MATLAB 7.3 MAT-file"
    with h5py.File(tiny.nyu_labeled, "r") as f:
        assert f.userblock_size == 512
        n = TINY.labeled_images
        assert f["images"].shape == (n, 3, 640, 480) and f["images"].dtype == np.uint8
        for key in ("depths", "rawDepths"):
            assert f[key].shape == (n, 640, 480) and f[key].dtype == np.float32
        assert f["scenes"].shape == (1, n) and f["scenes"].attrs["MATLAB_class"] == b"cell"
        assert "#refs#" in f
        depth = np.asarray(f["depths"][0]).T
        raw = np.asarray(f["rawDepths"][0]).T
        image = np.asarray(f["images"][0]).transpose(2, 1, 0)
    assert image.shape == (480, 640, 3) and image.std() > 5
    scenes = scene_names(tiny.nyu_labeled)  # read as the NYU loader reads the real file
    assert scenes == [im.scene for im in plan.labeled_images(TINY)]
    holes = raw == 0
    assert 0.01 < holes.mean() < 0.5 and depth.min() > 0
    np.testing.assert_allclose(raw[~holes], depth[~holes], rtol=0.05)
    gt = np.load(tiny.synth_gt / "nyu_labeled" / scenes[0] / "0001.npz")
    np.testing.assert_allclose(gt["depth"], depth, atol=DEPTH_STEP)

    splits = scipy.io.loadmat(tiny.nyu_splits)
    train, test = splits["trainNdxs"], splits["testNdxs"]
    assert train.ndim == 2 and train.shape[1] == 1 and test.shape[1] == 1
    assert sorted(np.concatenate([train, test]).ravel().tolist()) == list(range(1, n + 1))
    raw_scenes = {name for name, _ in plan.nyu_raw_scenes(TINY)}
    assert not {scenes[i - 1] for i in test.ravel()} & raw_scenes


def test_labeled_plan_keeps_test_scenes_out_of_the_raw_set():
    cfg = SynthConfig()
    images = plan.labeled_images(cfg)
    raw = {s for s, _ in plan.nyu_raw_scenes(cfg)}
    assert len(images) == cfg.labeled_images
    assert not {im.scene for im in images if im.test} & raw
    assert {im.scene for im in images if not im.test} & raw  # some train images share raw scenes
    assert sum(im.test for im in images) == round(cfg.labeled_images * cfg.labeled_test_fraction)


def test_sevenscenes_layout(tiny):
    scene = plan.sevenscenes_sequences(TINY)
    name, (test, train) = next(iter(scene.items()))
    root = tiny.sevenscenes / name
    assert (root / "TestSplit.txt").read_text().split() == [f"sequence{q}" for q in test]
    assert (root / "TrainSplit.txt").read_text().split() == [f"sequence{q}" for q in train]
    seq = root / f"seq-{test[0]:02d}"
    color = cv2.imread(str(seq / "frame-000000.color.png"))
    depth = cv2.imread(str(seq / "frame-000000.depth.png"), cv2.IMREAD_UNCHANGED)
    pose = np.loadtxt(seq / "frame-000000.pose.txt")
    assert color.shape == (480, 640, 3) and depth.dtype == np.uint16 and depth.shape == (480, 640)
    assert (depth == 65535).any() and ((depth > 0) & (depth < 65535)).mean() > 0.5
    gt = np.load(tiny.synth_gt / "sevenscenes" / name / seq.name / "frame-000000.npz")
    np.testing.assert_allclose(pose, gt["world_T_cam"], atol=1e-6)
    np.testing.assert_array_equal(gt["K"], [[585, 0, 320], [0, 585, 240], [0, 0, 1]])
    ok = depth < 65535
    np.testing.assert_allclose(depth[ok] / 1000.0, gt["depth"][ok], rtol=0.05, atol=0.002)


def test_campus_images_and_points(tiny):
    with open(tiny.campus / "points.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert rows and list(rows[0].keys()) == ["scene", "image", "u", "v", "depth_m"]
    per_image: dict[tuple[str, str], list] = {}
    for r in rows:
        per_image.setdefault((r["scene"], r["image"]), []).append(r)
    for (scene, image), pts in per_image.items():
        img = cv2.imread(str(tiny.campus / scene / f"{image}.jpg"))
        assert img.shape[:2] == TINY.campus_hw
        assert 13 <= len(pts) <= 16
        gt = np.load(tiny.synth_gt / "campus" / scene / f"{image}.npz")
        d = np.array([float(p["depth_m"]) for p in pts])
        for p in pts:
            u, v = float(p["u"]), float(p["v"])
            assert 0 <= u < img.shape[1] and 0 <= v < img.shape[0] and float(p["depth_m"]) > 0
            assert abs(gt["depth"][round(v), round(u)] - float(p["depth_m"])) < 1e-3
        assert d.max() > 1.5 * d.min()  # spread over near and far


def test_animated_sintel_layout_and_flo_round_trip(tiny, tmp_path):
    seq = plan.animated_sequences(TINY)[0]
    base = tiny.animated / "training"
    clean = sorted((base / "clean" / seq).glob("frame_*.png"))
    assert [p.name for p in clean] == [f"frame_{k + 1:04d}.png" for k in range(TINY.animated_frames)]
    assert sorted(p.name for p in (base / "final" / seq).glob("*.png")) == [p.name for p in clean]
    flo = base / "flow" / seq / "frame_0001.flo"
    raw = flo.read_bytes()
    assert raw[:4] == b"PIEH" and np.frombuffer(raw[:4], "<f4")[0] == np.float32(202021.25)
    w, h = np.frombuffer(raw[4:12], "<i4")
    assert (h, w) == TINY.animated_hw and len(raw) == 12 + 8 * w * h
    flow = read_flo(flo)
    gt = np.load(tiny.synth_gt / "animated" / seq / "frame_0001.npz")
    np.testing.assert_allclose(flow, gt["flow"], atol=FLOW_STEP)
    assert np.linalg.norm(flow, axis=2).mean() > 1.0
    occ = cv2.imread(str(base / "occlusions" / seq / "frame_0001.png"), cv2.IMREAD_UNCHANGED)
    assert set(np.unique(occ)) <= {0, 255}
    np.testing.assert_array_equal(occ == 255, gt["occluded"])
    assert not (base / "flow" / seq / f"frame_{TINY.animated_frames:04d}.flo").exists()


def test_manifest_lists_every_generated_frame(tiny):
    manifest = json.loads((tiny.synth_gt / "manifest.json").read_text())
    for ds, info in manifest["datasets"].items():
        n = len(list((tiny.synth_gt / ds).rglob("*.npz")))
        assert n == info["frames"], ds
    assert manifest["params"]["seed"] == TINY.seed


@pytest.mark.parametrize(
    ("style_name", "kind"), [("nyu", "bedroom"), ("nyu", "kitchen"), ("sevenscenes", "fire")]
)
def test_camera_path_speed_rotation_and_clearance(style_name, kind):
    scene = build(style_name, kind, f"{kind}_0007", np.random.default_rng(11))
    style = PathStyle()
    for k in range(8):
        poses, times = handheld_path(scene, 51, np.random.default_rng(k), style)
        speed = np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1) * style.fps
        assert speed.min() >= 0.2 and speed.max() <= 0.4, speed
        xy = poses[:, :2, 3]
        assert np.all(xy > scene.room_lo[:2] + style.wall_margin - 1e-6)
        assert np.all(xy < scene.room_hi[:2] - style.wall_margin + 1e-6)
        for x0, y0, x1, y1 in scene.obstacles:
            inside = (
                (xy[:, 0] > x0 - 0.3) & (xy[:, 0] < x1 + 0.3) & (xy[:, 1] > y0 - 0.3) & (xy[:, 1] < y1 + 0.3)
            )
            assert not inside.any()
        rel = [relative_pose(poses[i], poses[i + 1])[:3, :3] for i in range(50)]
        angles = np.degrees([np.arccos(np.clip((np.trace(r) - 1) / 2, -1, 1)) for r in rel])
        assert np.median(angles) > 0.05 and angles.sum() > 2.0  # it keeps rotating
        # yaw, pitch and roll all change: the optical axis and the horizon both move
        fwd, right = poses[:, :3, 2], poses[:, :3, 0]
        assert np.ptp(np.degrees(np.arctan2(fwd[:, 1], fwd[:, 0]))) > 0.5
        assert np.ptp(np.degrees(np.arcsin(fwd[:, 2]))) > 0.2
        assert np.ptp(np.degrees(np.arcsin(right[:, 2]))) > 0.2


def test_config_from_params_and_its_errors():
    import yaml

    params = yaml.safe_load((REPO / "params.yaml").read_text())
    cfg = SynthConfig.from_params(params["synth"])
    assert cfg.nyu_raw_frames == params["synth"]["nyu_raw"]["frames"]
    broken = json.loads(json.dumps(params["synth"]))
    del broken["campus"]["focal"]
    with pytest.raises(ParamsError, match="synth.campus.focal"):
        SynthConfig.from_params(broken, "p.yaml")


def test_stage_with_real_data_generates_nothing(tmp_path, monkeypatch):
    import importlib.util

    spec = importlib.util.spec_from_file_location("synth_stage", REPO / "stages" / "synth.py")
    stage = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(stage)
    text = (REPO / "params.yaml").read_text().replace("data_source: synthetic", "data_source: real")
    (tmp_path / "params.yaml").write_text(text)
    monkeypatch.chdir(tmp_path)
    stage.main(["synth.py", "params.yaml"])
    assert json.loads(Path("metrics/synth.json").read_text())["data_source"] == "real"
    assert sorted(os.listdir(tmp_path)) == ["data", "metrics", "params.yaml"]
    written = sorted(str(p.relative_to(tmp_path)) for p in (tmp_path / "data").rglob("*") if p.is_file())
    # placeholders, no data
    assert written == ["data/raw/README.txt", "data/raw/clips/README.txt", "data/raw/synth_gt/README.txt"]


def test_regenerating_smaller_removes_the_stale_frames_only(tmp_path):
    paths = OutputPaths.under(tmp_path)
    cfg = SynthConfig(**{**TINY.__dict__, "nyu_raw_frames": 4, "animated_frames": 3})
    generate(cfg, paths, progress=False)
    foreign = paths.nyu_raw / "bedroom_0099" / "r-1.000000-1.ppm"  # e.g. a user's own file
    foreign.parent.mkdir(parents=True)
    foreign.write_bytes(b"keep me")
    generate(TINY, paths, progress=False)
    assert foreign.read_bytes() == b"keep me"
    for scene, _ in plan.nyu_raw_scenes(TINY):
        frames = {p.stem for p in (paths.nyu_raw / scene).glob("*.ppm")}
        assert frames == {p.stem for p in (paths.synth_gt / "nyu_raw" / scene).glob("*.npz")}
        assert len(frames) == TINY.nyu_raw_frames
    seq = plan.animated_sequences(TINY)[0]
    for kind, n in (("clean", 2), ("final", 2), ("flow", 1), ("occlusions", 1)):
        assert len(list((paths.animated / "training" / kind / seq).iterdir())) == n


def test_video_flow_side_cars_only_on_request(tiny, tmp_path):
    """synth.flow_gt false (the default) leaves the flow out of the nyu_raw and 7-Scenes side-cars — most of
    their disk — and changes nothing else: the same images, depth, poses and statistics; the animated set
    keeps its flow (its .flo files are scored by flow_pretrain)."""
    paths = OutputPaths.under(tmp_path / "raw")
    lean = generate(replace(TINY, flow_gt=False), paths, progress=False)
    for dataset in ("nyu_raw", "sevenscenes"):
        files = sorted((paths.synth_gt / dataset).rglob("*.npz"))
        assert files and all("flow" not in np.load(f).files and "occluded" not in np.load(f).files
                             for f in files)
        for f in files:
            full = np.load(tiny.synth_gt / f.relative_to(paths.synth_gt))
            np.testing.assert_array_equal(np.load(f)["depth"], full["depth"])
            np.testing.assert_array_equal(np.load(f)["world_T_cam"], full["world_T_cam"])
    assert any("flow" in np.load(f).files for f in (paths.synth_gt / "animated").rglob("*.npz"))
    frame = next((paths.nyu_raw).rglob("*.ppm"))
    assert frame.read_bytes() == (tiny.nyu_raw / frame.relative_to(paths.nyu_raw)).read_bytes()
    full = json.loads((tiny.synth_gt / "manifest.json").read_text())
    lean_manifest = json.loads((paths.synth_gt / "manifest.json").read_text())
    assert lean_manifest["datasets"] == full["datasets"] and lean_manifest["params"]["flow_gt"] is False
    assert lean["frames"] > 0
