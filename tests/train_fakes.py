"""A tiny prepared set + keypoints + NYU-format test set + random flow model for the train_depth tests.

Import as ``import train_fakes``. Everything is deterministic for a seed and small enough that a
training epoch takes well under a second.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import fakes
import numpy as np
import torch
import yaml

from f2depth.flow import PWCLite, save_flow_model
from f2depth.keypoints import save_keypoints
from f2depth.params import load as load_params
from f2depth.train.settings import loss_weights
from f2depth.train.step import WEIGHT_KEYS

HW = (64, 64)
#: The weight of every term of L_depth in the repository's params.yaml (``lambda1``, ``lambda2``,
#: ``lambda_rigid``, ``lambda3``: the CPU default's), for a StepConfig in tests; read from there, so a new
#: term with its weight needs no change here.
WEIGHTS = loss_weights(load_params(Path(__file__).resolve().parents[1] / "params.yaml"))


#: what LoopConfig takes from params.yaml, at the tests' values (every epoch validated and saved, no fade)
LOOP = {"workers": 0, "sync_bn": True, "val_every": 1, "state_every": 1, "flow_fade_epochs": None}


def tiny_K(hw: tuple[int, int] = HW) -> np.ndarray:
    h, w = hw
    return np.array([[0.8 * w, 0.0, 0.45 * w], [0.0, 0.8 * w, 0.55 * h], [0.0, 0.0, 1.0]])


def write_prepared(root: Path, hw: tuple[int, int] = HW, scenes: int = 2, frames: int = 5, seed: int = 0,
                   identical: bool = False) -> Path:
    """``root`` in the prepared-set format: ``scenes`` scenes of ``frames`` frames (a window sliding over
    a smooth image), tuples of consecutive frames, 4×4-block superpixels, GT depth 2 m, and ``root.parent /
    'keypoints' / 'train.npz'`` with a few keypoints per frame. ``identical``: every frame is the same
    image (tuples then differ only by index-seeded draws)."""
    h, w = hw
    root.mkdir(parents=True)
    camera = {"K": tiny_K(hw).tolist(), "height": h, "width": w, "crop": 16}
    (root / "camera.json").write_text(json.dumps(camera))
    frames_rows, tuple_rows, pair_rows = [], [], []
    kp_ids, kp_points = [], []
    rng = np.random.default_rng(seed)
    blocks = (np.arange(h)[:, None] // max(1, h // 4)) * 4 + np.arange(w)[None, :] // max(1, w // 4)
    for s in range(scenes):
        scene = f"room_{s:04d}"
        wide = fakes.smooth_image((h, w + 4 * frames), seed + s, cells=6)
        ids = []
        for k in range(frames):
            fid = f"{scene}_{10 * k:05d}"
            img = wide[:, :w] if identical else wide[:, 4 * k: 4 * k + w]
            fakes.write_rgb(root / "images" / scene / f"{fid}.png", np.ascontiguousarray(img))
            pose = np.eye(4)
            pose[0, 3] = 0.05 * k
            (root / "gt" / scene).mkdir(parents=True, exist_ok=True)
            np.savez(root / "gt" / scene / f"{fid}.npz", depth=np.full(hw, 2.0, np.float32), world_T_cam=pose)
            frames_rows.append(f"{fid},{scene},{scene}/r-{k}.ppm,images/{scene}/{fid}.png,gt/{scene}/{fid}.npz")
            kp_ids.append(len(kp_ids))
            n = 0 if k == 1 else 12  # one frame without keypoints (flat image case)
            kp_points.append(np.stack([rng.integers(2, w - 2, n), rng.integers(2, h - 2, n),
                                       np.zeros(n, int)], axis=1))
            ids.append(fid)
        for k in range(1, frames - 1):
            tid = ids[k]
            tuple_rows.append(f"{tid},{scene},{tid},{ids[k - 1]},{ids[k + 1]},segments/{tid}.png")
            (root / "segments").mkdir(exist_ok=True)
            cv2.imwrite(str(root / "segments" / f"{tid}.png"), blocks.astype(np.uint16))
        for k in range(frames - 1):
            pair_rows.append(f"{ids[k]},{scene},{ids[k]},{ids[k + 1]}")
    (root / "frames.csv").write_text("frame_id,scene,raw_file,image,gt\n" + "\n".join(frames_rows) + "\n")
    tuples_header = "tuple_id,scene,target,prev,next,segments\n"
    (root / "tuples.csv").write_text(tuples_header + "\n".join(tuple_rows) + "\n")
    (root / "pairs.csv").write_text("pair_id,scene,frame1,frame2\n" + "\n".join(pair_rows) + "\n")
    save_keypoints(root.parent / "keypoints" / "train.npz", kp_ids, kp_points)
    return root


def write_nyu_test(root: Path, n: int = 4, seed: int = 0) -> tuple[Path, Path]:
    """A labeled .mat with ``n`` test images and one training image, and its splits.mat."""
    mat, splits = root / "nyu_labeled" / "labeled.mat", root / "nyu_labeled" / "splits.mat"
    fakes.write_labeled_mat(mat, [f"office_{i:04d}" for i in range(n + 1)], seed=seed)
    fakes.write_splits(splits, [n + 1], list(range(1, n + 1)))
    return mat, splits


def write_flow_model(path: Path, seed: int = 0) -> Path:
    """A randomly initialised PWC-Lite saved in our format (stands in for models/flow_*.pt)."""
    torch.manual_seed(seed)
    save_flow_model(path, PWCLite(), config={"note": "random test model"})
    return path


def write_params(root: Path, prepared: Path, mat: Path, splits: Path, flow: Path | None, **train) -> Path:
    """A params.yaml for the stage, with the variants of params.yaml and tiny training settings."""
    td = {"epochs": 2, "batch_size": 2, "lr": [1e-4, 1e-5, 1e-6], "lr_epochs": [27, 15, 2], "num_points": 50,
          "imagenet_weights": None, "augment": True, "seeds": [0], "workers": 0, "val_max_images": 2,
          "seed_threads": None, "val_every": 1, "state_every": 1, "resume_dir": str(root / "ckpt"),
          "amp": False, "init_depth": None,
          "pose_prior": "none", "sync_bn": True, "diagnostic_tuples": 64, "teacher_memo_mb": 64,
          "teacher": "network", "rigid_mask": "none",
          "flow_fade_epochs": None}
    td.update(train)
    flow_s = str(flow) if flow else None
    params = {
        **{WEIGHT_KEYS[t]: w for t, w in WEIGHTS.items()}, "lambda_flow_smooth": 50,
        "device": "cpu", "threads": 1,
        "allow_random_init": True, "flow_pretrain": {"checkpoint": None},
        "data": {"prepared": str(prepared), "keypoints": str(prepared.parent / "keypoints"),
                 "nyu_labeled": str(mat), "nyu_splits": str(splits)},
        "evaluate": {"nyu_gt": "depths", "nyu_crop": "eigen"},
        "train_depth": td,
        "variants": {
            "full": {"flow": flow_s, "without": []},
            "no_feature": {"flow": flow_s, "without": ["feature"]},
            "baseline": {"flow": None, "without": ["rigid", "feature"]},
        },
    }  # fmt: skip
    path = root / "params.yaml"
    path.write_text(yaml.safe_dump(params, sort_keys=False))
    return path


class Crash(RuntimeError):
    """Stands in for the process dying right after an epoch's resume state is saved."""


def crash_after(epoch: int):
    """An ``on_epoch`` hook that raises :class:`Crash` once epoch ``epoch`` is saved."""
    def on_epoch(row: dict) -> None:
        if row["epoch"] == epoch:
            raise Crash
    return on_epoch
