"""Tests for f2depth.data.prepare: the prepare stage end to end on a tiny fake NYU raw set."""

from __future__ import annotations

import csv
import json

import cv2
import fakes
import numpy as np
import pytest

from f2depth.camera import NYU_RGB_DIST, NYU_RGB_K, NYU_SIZE_HW, crop_resize_intrinsics
from f2depth.data.prepare import (
    PrepareConfig,
    SuperpixelParams,
    crop_and_resize,
    held_out_count,
    prepare,
    read_scene_list,
    room_of,
    select_train_scenes,
    superpixel_stats,
    superpixels,
)
from f2depth.errors import DataError
from f2depth.formats.prepared import PreparedSet, crop_border, prepare_image, undistort_crop
from f2depth.io import OUTPUT_MARKER

pytestmark = pytest.mark.filterwarnings("ignore:.*fewer than 3 sampled frames:UserWarning")

# raw scenes: two training rooms, one test room recorded in two parts (a, b)
RAW = {"office_0002": 7, "bedroom_0076a": 4, "kitchen_0003a": 5, "kitchen_0003b": 3}
LABELED_SCENES = ["office_0001", "kitchen_0003a", "office_0002", "dining_0009"]
HW = (48, 64)


@pytest.fixture
def world(tmp_path):
    raw, gt = tmp_path / "raw" / "nyu_raw", tmp_path / "raw" / "synth_gt"
    ideal = fakes.write_nyu_raw(raw, RAW, seed=1, gt_root=gt)
    mat, splits = tmp_path / "raw" / "labeled.mat", tmp_path / "raw" / "splits.mat"
    fakes.write_labeled_mat(mat, LABELED_SCENES, seed=2)
    fakes.write_splits(splits, train=[1, 3], test=[2, 4])  # test rooms: kitchen_0003, dining_0009
    return {"raw": raw, "gt": gt, "mat": mat, "splits": splits, "out": tmp_path / "prepared", "ideal": ideal}


def _config(**kw) -> PrepareConfig:
    base = {"height": HW[0], "width": HW[1], "frame_step": 3, "crop": 16, "workers": 1,
            "superpixels": SuperpixelParams(100, 0.5, 10)}
    base.update(kw)
    return PrepareConfig(**base)


def _by_time(folder, ext):
    return sorted(folder.glob(f"r-*.{ext}"), key=lambda p: float(p.name.split("-")[1]))


def _rows(path):
    with path.open(newline="") as fh:
        return list(csv.DictReader(fh))


def test_room_matching_and_scene_selection():
    assert room_of("bedroom_0076b") == "bedroom_0076" and room_of("office_0002") == "office_0002"
    raw = ["bedroom_0076a", "bedroom_0076b", "kitchen_0003", "office_0002"]
    assert select_train_scenes(raw, {"bedroom_0076b", "kitchen_0003a"}) == ["office_0002"]


def test_prepare_end_to_end(world):
    with pytest.warns(UserWarning, match="1 scene.* fewer than 3 sampled frames .*: bedroom_0076a"):
        m = prepare(world["raw"], world["mat"], world["splits"], world["out"], _config(),
                    synth_gt=world["gt"], progress=False)
    out = world["out"]
    # office_0002: raw 0,3,6 → 3 frames, 1 tuple, 2 pairs; bedroom_0076a: raw 0,3 → 2 frames, 0 tuples, 1 pair
    assert {k: m[k] for k in ("raw_scenes", "scenes", "frames", "tuples", "pairs", "frames_with_gt")} == {
        "raw_scenes": 4, "scenes": 2, "frames": 5, "tuples": 1, "pairs": 3, "frames_with_gt": 5}
    assert m["scenes_without_tuples"] == 1 and m["superpixels_per_target"] > 1 and m["seconds"] >= 0

    frames = _rows(out / "frames.csv")
    assert [f["frame_id"] for f in frames] == ["bedroom_0076a_00000", "bedroom_0076a_00003",
                                               "office_0002_00000", "office_0002_00003", "office_0002_00006"]
    raw_sorted = _by_time(world["raw"] / "office_0002", "ppm")
    assert frames[3]["raw_file"] == f"office_0002/{raw_sorted[3].name}"
    assert frames[3]["image"] == "images/office_0002/office_0002_00003.png"
    assert frames[3]["gt"] == "gt/office_0002/office_0002_00003.npz"
    assert _rows(out / "tuples.csv") == [{
        "tuple_id": "office_0002_00003", "scene": "office_0002", "target": "office_0002_00003",
        "prev": "office_0002_00000", "next": "office_0002_00006",
        "segments": "segments/office_0002_00003.png"}]
    pairs = [(p["frame1"], p["frame2"]) for p in _rows(out / "pairs.csv")]
    assert pairs == [("bedroom_0076a_00000", "bedroom_0076a_00003"),
                     ("office_0002_00000", "office_0002_00003"), ("office_0002_00003", "office_0002_00006")]

    cam = json.loads((out / "camera.json").read_text())
    np.testing.assert_allclose(cam["K"], crop_resize_intrinsics(NYU_RGB_K, NYU_SIZE_HW, 16, HW))
    assert (cam["height"], cam["width"], cam["crop"], cam["frame_step"], cam["p2net_cxcy_bug"]) == (
        48, 64, 16, 3, False)
    np.testing.assert_allclose(cam["source_K"], NYU_RGB_K)

    ps = PreparedSet(out)
    img = ps.image("office_0002_00003")
    expect = crop_and_resize(world["ideal"]["office_0002"][3], 16, HW)  # undistortion undid the lens
    assert np.abs(img.astype(float) - expect)[4:-4, 4:-4].mean() < 2.0
    depth, pose = ps.gt("office_0002_00003")
    assert depth.shape == HW and depth.dtype == np.float32
    assert set(np.unique(depth)) == {3.0, np.float32(2.03)}  # nearest keeps the values
    assert pose[0, 3] == pytest.approx(0.03)
    seg = ps.segments("office_0002_00003")
    assert seg.shape == HW and seg.min() == 0 and seg.max() + 1 == m["superpixels_per_target"]

    # atomic: no temporary files or folders anywhere
    leftovers = list(out.parent.rglob(".*"))
    assert leftovers == [out / OUTPUT_MARKER] and (out / OUTPUT_MARKER).read_text() == "prepare\n"


def test_prepare_parallel_matches_serial_and_replaces_old_set(world, tmp_path):
    serial = prepare(world["raw"], world["mat"], world["splits"], world["out"], _config(p2net_cxcy_bug=True),
                     synth_gt=world["gt"], progress=False)
    (world["out"] / "stale.txt").write_text("from an earlier run")
    par_out = tmp_path / "par"
    parallel = prepare(world["raw"], world["mat"], world["splits"], par_out,
                       _config(workers=2, p2net_cxcy_bug=True), synth_gt=world["gt"], progress=False)
    for k in ("frames", "tuples", "pairs", "superpixels_per_target", "superpixel_share_over_1000px"):
        assert serial[k] == parallel[k]
    for rel in ("frames.csv", "tuples.csv", "camera.json", "segments/office_0002_00003.png",
                "images/office_0002/office_0002_00006.png"):
        assert (world["out"] / rel).read_bytes() == (par_out / rel).read_bytes()
    cam = json.loads((par_out / "camera.json").read_text())
    assert cam["p2net_cxcy_bug"] is True and cam["K"][0][2] == pytest.approx(325.58244941119034 / 608 * 64)
    prepare(world["raw"], world["mat"], world["splits"], world["out"], _config(), progress=False)
    assert not (world["out"] / "stale.txt").exists()  # a re-run replaces the whole set
    assert not (world["out"] / "gt").exists()  # no side-car GT given → real-data layout
    assert all(f["gt"] == "" for f in _rows(world["out"] / "frames.csv"))


def test_train_scenes_file(world, tmp_path):
    lst = tmp_path / "train.txt"
    lst.write_text("# chosen by hand\nkitchen_0003b\n\noffice_0002\n")
    m = prepare(world["raw"], tmp_path / "no_labeled.mat", tmp_path / "no_splits.mat", world["out"],
                _config(), train_scenes_file=lst, progress=False)
    assert m["scenes"] == 2 and m["frames"] == 1 + 3
    lst.write_text("office_0002\nliving_room_0001\n")
    with pytest.raises(DataError, match="train.txt: line 2: scene 'living_room_0001' is not a folder"):
        read_scene_list(lst, list(RAW))


def test_failure_leaves_previous_set_and_no_temp_files(world):
    prepare(world["raw"], world["mat"], world["splits"], world["out"], _config(), progress=False)
    before = sorted(p.relative_to(world["out"]) for p in world["out"].rglob("*"))
    victim = _by_time(world["raw"] / "office_0002", "ppm")[3]  # a sampled frame (step 3)
    fakes.truncate(victim, 0.5)
    with pytest.raises(DataError, match=rf"{victim.name}: truncated"):
        prepare(world["raw"], world["mat"], world["splits"], world["out"], _config(), progress=False)
    assert sorted(p.relative_to(world["out"]) for p in world["out"].rglob("*")) == before
    assert [p.name for p in world["out"].parent.iterdir() if p.name.startswith(".")] == []


def test_missing_or_misaligned_gt(world):
    gt_files = _by_time(world["gt"] / "nyu_raw" / "office_0002", "npz")
    bad_K = NYU_RGB_K.copy()
    bad_K[0, 2] += 1.0
    np.savez(gt_files[3], depth=np.ones(NYU_SIZE_HW, np.float32), world_T_cam=np.eye(4), K=bad_K)
    with pytest.raises(DataError, match=rf"{gt_files[3].name}: K differs from the camera the frames are "
                                        r"undistorted with \(NYU Depth V2 RGB calibration\)"):
        prepare(world["raw"], world["mat"], world["splits"], world["out"], _config(),
                synth_gt=world["gt"], progress=False)
    gone = gt_files[6]
    gone.unlink()  # its scene has ground truth, this sampled frame lost it
    with pytest.raises(DataError, match=rf"{gone.name}: missing side-car ground truth"):
        prepare(world["raw"], world["mat"], world["splits"], world["out"], _config(),
                synth_gt=world["gt"], progress=False)


def test_superpixels_on_flat_blocks():
    img = fakes.blocky_image((96, 128), seed=0, blocks=4)
    labels = superpixels(img, SuperpixelParams(100, 0.5, 50))
    assert labels.dtype == np.uint16 and labels.shape == (96, 128)
    inner = [labels[y + 3:y + 21, x + 3:x + 29] for y in range(0, 96, 24) for x in range(0, 128, 32)]
    assert all(len(np.unique(b)) == 1 for b in inner)  # each flat block's interior is one superpixel
    assert len({int(b[0, 0]) for b in inner}) == 16  # and no two blocks share one
    n, share = superpixel_stats(labels, min_area=500)
    assert n == labels.max() + 1 and share > 0.9


def test_full_resolution_crop_is_the_image_prepare_resizes():
    """undistort_crop (the keypoints' input, as in P²Net's datasets/nyu_dataset.py) and prepare_image
    share one pipeline."""
    raw = fakes.smooth_image(NYU_SIZE_HW, seed=3, cells=40)
    full = undistort_crop(raw, 16)
    assert full.shape == (448, 608, 3) and full.dtype == np.uint8
    np.testing.assert_array_equal(full, cv2.undistort(raw, NYU_RGB_K, NYU_RGB_DIST)[16:464, 16:624])
    np.testing.assert_array_equal(prepare_image(raw, 16, HW), crop_and_resize(full, 0, HW))
    np.testing.assert_array_equal(
        prepare_image(raw, 16, HW),
        cv2.resize(np.ascontiguousarray(full), (HW[1], HW[0]), interpolation=cv2.INTER_AREA))
    assert undistort_crop(raw, 0).shape == (480, 640, 3)
    with pytest.raises(ValueError, match="crop 240 leaves nothing"):
        crop_border(raw, 240)


def test_held_out_count_keeps_three_frames_and_a_training_tuple():
    assert [held_out_count(n, 0.0) for n in (3, 10, 100)] == [0, 0, 0]
    assert [held_out_count(n, 0.2) for n in (5, 6, 10, 20, 21)] == [0, 3, 3, 4, 5]
    assert held_out_count(10, 0.5) == 5


def test_val_share_holds_out_the_end_of_each_scene(world, tmp_path):
    lst = tmp_path / "train.txt"
    lst.write_text("office_0002\nbedroom_0076a\n")  # 7 and 4 frames at frame_step 1
    with pytest.warns(UserWarning, match=r"val_share 0.2: 1 scene\(s\) are too short .*bedroom_0076a"):
        m = prepare(world["raw"], world["mat"], world["splits"], world["out"], _config(frame_step=1,
                    val_share=0.2), synth_gt=world["gt"], train_scenes_file=lst, progress=False)
    ds = PreparedSet(world["out"])
    office = [f.frame_id for f in ds.frames if f.scene == "office_0002"]
    assert len(office) == 7
    # office: frames 0-3 train (tuples at 1, 2), frames 4-6 are held out (one tuple at 5)
    assert [(t.prev, t.target, t.next) for t in ds.val_tuples] == [tuple(office[4:7])]
    assert [t.target for t in ds.tuples if t.scene == "office_0002"] == office[1:3]
    assert len([t for t in ds.tuples if t.scene == "bedroom_0076a"]) == 2  # too short: all of it trains
    held = set(office[4:])
    used = {f for t in ds.tuples for f in (t.prev, t.target, t.next)} | {f for p in ds.pairs
                                                                          for f in (p.frame1, p.frame2)}
    assert not held & used  # no training tuple or fine-tuning pair sees a held-out frame
    assert (m["val_tuples"], m["held_out_frames"], m["tuples"]) == (1, 3, 4)
    assert ds.segments(ds.val_tuples[0].tuple_id).shape == HW and ds.has_gt(office[5])

    # a held-out tuple that shares a frame with a training tuple is refused in one line
    rows = (world["out"] / "val_tuples.csv").read_text().splitlines()
    t = ds.tuples[0]
    rows.append(f"x,{t.scene},{t.target},{t.prev},{t.next},{t.segments}")
    (world["out"] / "val_tuples.csv").write_text("\n".join(rows) + "\n")
    with pytest.raises(DataError, match=r"val_tuples.csv: held-out tuple x: frame .* is in a training tuple"):
        PreparedSet(world["out"])


def test_without_val_share_the_tables_are_those_of_a_set_without_held_out_frames(world):
    prepare(world["raw"], world["mat"], world["splits"], world["out"], _config(frame_step=1),
            synth_gt=world["gt"], progress=False)
    ds = PreparedSet(world["out"])
    assert ds.val_tuples == [] and (world["out"] / "val_tuples.csv").read_text().startswith("tuple_id,")
    per_scene = {s: sum(f.scene == s for f in ds.frames) for s in {f.scene for f in ds.frames}}
    assert len(ds.tuples) == sum(n - 2 for n in per_scene.values())
    assert len(ds.pairs) == sum(n - 1 for n in per_scene.values())
    (world["out"] / "val_tuples.csv").unlink()  # a set made before the file existed still loads
    assert PreparedSet(world["out"]).val_tuples == []
