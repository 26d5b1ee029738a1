"""The held-out validation of train_depth (prepare.val_share; f2depth.train.heldout): it must tell a right
depth and pose from a still camera and from a wrong depth, and it must let training run without NYU."""

from __future__ import annotations

import csv
import importlib.util
import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch
import train_fakes
from depth_scenes import plane_scene

from f2depth import params as P
from f2depth.depth import DepthModel, DepthModelConfig
from f2depth.errors import DataError
from f2depth.formats.prepared import PreparedSet
from f2depth.keypoints import save_keypoints
from f2depth.train.heldout import HeldOutValidator
from f2depth.train.run import train_variant
from f2depth.train.settings import settings_from_params
from f2depth.train.step import NetOutput

ROOT = Path(__file__).resolve().parents[1]
HW = (64, 96)
MOTIONS = {"prev": ((-0.01, 0.02, 0.0), (-0.15, 0.04, -0.06)),
           "next": ((0.01, -0.03, 0.015), (0.2, -0.05, 0.08))}


def _png(path: Path, rgb01: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    rgb = np.round(rgb01 * 255).clip(0, 255).astype(np.uint8)
    cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))


def plane_prepared(root: Path) -> tuple[Path, dict]:
    """A prepared set whose one held-out tuple is a ray-traced plane seen from three cameras (depth_scenes):
    the target with its true depth, and the two sources with their true ``src_T_tgt``."""
    views = {k: plane_scene(*HW, aa=aa, t=t) for k, (aa, t) in MOTIONS.items()}
    s = views["next"]
    ids = {"prev": "room_00000", "target": "room_00010", "next": "room_00020"}
    frames = []
    for role, fid in ids.items():
        img = s.img_t if role == "target" else views[role].img_s
        _png(root / "images" / "room" / f"{fid}.png", img)
        # the world frame is the target camera's
        pose = np.eye(4) if role == "target" else np.linalg.inv(views[role].src_T_tgt)
        depth = s.depth_t if role == "target" else views[role].depth_s
        (root / "gt" / "room").mkdir(parents=True, exist_ok=True)
        np.savez(root / "gt" / "room" / f"{fid}.npz", depth=depth.astype(np.float32), world_T_cam=pose)
        frames.append(f"{fid},room,room/r-{fid}.png,images/room/{fid}.png,gt/room/{fid}.npz")
    (root / "segments").mkdir()
    cv2.imwrite(str(root / "segments" / "room_00010.png"), np.zeros(HW, np.uint16))
    (root / "camera.json").write_text(json.dumps({"K": s.K.tolist(), "height": HW[0], "width": HW[1]}))
    (root / "frames.csv").write_text("frame_id,scene,raw_file,image,gt\n" + "\n".join(frames) + "\n")
    header = "tuple_id,scene,target,prev,next,segments\n"
    (root / "tuples.csv").write_text(header)
    (root / "val_tuples.csv").write_text(header + "room_00010,room,room_00010,room_00000,room_00020,"
                                         "segments/room_00010.png\n")
    (root / "pairs.csv").write_text("pair_id,scene,frame1,frame2\n")
    rng = np.random.default_rng(0)
    save_keypoints(root.parent / "keypoints" / "train.npz", [0, 1, 2],
                   [np.stack([rng.integers(4, HW[1] - 4, 200), rng.integers(4, HW[0] - 4, 200),
                              np.zeros(200, int)], 1) for _ in range(3)])
    truth = {"depth": torch.from_numpy(s.depth_t).float()[None, None],
             "T_prev": torch.from_numpy(views["prev"].src_T_tgt).float()[None],
             "T_next": torch.from_numpy(views["next"].src_T_tgt).float()[None]}
    return root, truth


def test_the_held_out_loss_tells_the_true_depth_and_poses_from_a_still_camera_and_a_wrong_depth(tmp_path):
    prepared, truth = plane_prepared(tmp_path / "prepared")
    v = HeldOutValidator(PreparedSet(prepared), tmp_path / "keypoints" / "train.npz", num_points=500)

    def oracle(scale: float):
        depth = truth["depth"] * scale
        return lambda batch: NetOutput(depth, depth, truth["T_prev"], truth["T_next"])

    right, wrong, floors = v.score(oracle(1.0)), v.score(oracle(2.0)), v.floors()
    assert right["heldout_ph"] < 0.05 * floors["identity_ph"]  # the true geometry explains the sources
    assert right["heldout_ph"] < 0.1 * wrong["heldout_ph"]  # twice the depth with the same motion does not
    assert right["heldout_a1"] == pytest.approx(1.0) and right["heldout_abs_rel"] < 1e-6  # its ground truth
    assert floors["constant_abs_rel"] > 0.05  # a flat depth is not the tilted plane

    torch.manual_seed(0)  # and a network: finite, through the training forward pass
    got = v(DepthModel(DepthModelConfig(height=HW[0], width=HW[1])))
    assert all(math.isfinite(got[k]) for k in ("heldout_ph", "heldout_a1", "heldout_abs_rel"))


def _hold_out_last_scene(prep: Path) -> None:
    """Move the tuples (and pairs) of the last scene of a train_fakes set to val_tuples.csv."""
    rows = (prep / "tuples.csv").read_text().splitlines()
    last = rows[-1].split(",")[1]
    keep = [r for r in rows[1:] if r.split(",")[1] != last]
    held = [r for r in rows[1:] if r.split(",")[1] == last]
    (prep / "tuples.csv").write_text("\n".join([rows[0], *keep]) + "\n")
    (prep / "val_tuples.csv").write_text("\n".join([rows[0], *held]) + "\n")
    pairs = (prep / "pairs.csv").read_text().splitlines()
    kept_pairs = [p for p in pairs[1:] if p.split(",")[1] != last]
    (prep / "pairs.csv").write_text("\n".join([pairs[0], *kept_pairs]) + "\n")


def _stage():
    spec = importlib.util.spec_from_file_location("train_depth_stage", ROOT / "stages" / "train_depth.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_without_nyu_training_validates_on_the_held_out_tuples_and_says_so(tmp_path, capsys, monkeypatch):
    prep = train_fakes.write_prepared(tmp_path / "prepared", scenes=2, frames=5)
    _hold_out_last_scene(prep)
    path = train_fakes.write_params(tmp_path, prep, tmp_path / "none.mat", tmp_path / "none_splits.mat", None,
                                    epochs=2)
    p = P.load(path)
    p["data"]["nyu_labeled"] = p["data"]["nyu_splits"] = None
    path.write_text(json.dumps({k: v for k, v in p.items() if not k.startswith("_")}))
    settings = settings_from_params(P.load(path), "baseline")
    m = train_variant(settings, tmp_path / "models", progress=False).metrics
    assert m["val_trained"] == {"abs_rel": None, "a1": None}
    assert m["heldout"]["tuples"] == 2  # val_max_images, of 3
    for key in ("heldout_untrained", "heldout_trained"):
        assert all(math.isfinite(m[key][k]) for k in ("ph", "a1", "abs_rel")), key
    assert m["heldout"]["identity_ph"] > 0 and "heldout_ph" not in m["final_losses"]

    monkeypatch.chdir(tmp_path)
    _stage().main(["train_depth", "--variant", "baseline", "--params", str(path), "--models",
                   str(tmp_path / "models2"), "--metrics", str(tmp_path / "metrics")])
    out = capsys.readouterr().out
    assert "held-out L_ph" in out and "still camera" in out and "val δ1" not in out
    with (tmp_path / "metrics" / "baseline" / "validation.csv").open() as fh:
        measured = list(csv.DictReader(fh))
    assert [r["epoch"] for r in measured] == ["0", "1", "2"] and all(r["heldout_ph"] != "" for r in measured)

    (prep / "val_tuples.csv").write_text("tuple_id,scene,target,prev,next,segments\n")  # no validation at all
    with pytest.raises(DataError, match=r"val_tuples.csv: no validation set: .*set prepare.val_share"):
        train_variant(settings_from_params(P.load(path), "baseline"), tmp_path / "models3", progress=False)
