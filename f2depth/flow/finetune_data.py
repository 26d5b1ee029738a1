"""Data of the flow fine-tuning: the prepared pairs (t, t+1) with the keypoints of both frames (t's for the
forward term of the patch loss, t+1's for the backward term), the split into training and EPE test pairs,
and ground-truth flow of prepared pairs from synthetic depth and pose.

**Split.** The last ``holdout_scenes`` scenes of ``pairs.csv`` whose pairs have ground truth are the EPE
test scenes; their pairs are not trained on. If that would leave no training scene, every pair is
trained on and the EPE is measured on the training pairs (``test_on_train`` says so).

**Ground truth** (rigid, static scene): ``flow = rigid_flow(D_t, K, s_T_t)`` with ``s_T_t =
relative_pose(world_T_t, world_T_s)``; a pixel is *occluded* when the depth test against ``D_s`` hides it
(:func:`f2depth.geometry.occlusion_by_depth`) or its flow leaves the image; pixels without depth are not
scored; *low texture* as :func:`f2depth.flow.evaluation.low_texture_mask` on frame t. K is the geometric
intrinsics of the prepared images: with ``p2net_cxcy_bug`` set, camera.json's K is P²Net's misplaced one,
so the correct K is recomputed from ``source_K`` and the crop.
"""

from __future__ import annotations

import warnings
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
import torch

from f2depth.camera import crop_resize_intrinsics
from f2depth.flow.evaluation import low_texture_mask
from f2depth.flow.patch_loss import pad_keypoints
from f2depth.formats.images import to_tensor
from f2depth.formats.prepared import PairRecord, PreparedSet
from f2depth.geometry import in_view_mask, occlusion_by_depth, relative_pose, rigid_flow
from f2depth.keypoints.store import KeypointFile


@dataclass(frozen=True)
class PairSplit:
    train: list[PairRecord]
    test: list[PairRecord]
    train_scenes: list[str]
    test_scenes: list[str]
    test_on_train: bool


def _has_gt(ds: PreparedSet, p: PairRecord) -> bool:
    return ds.has_gt(p.frame1) and ds.has_gt(p.frame2)


def split_pairs(ds: PreparedSet, holdout_scenes: int) -> PairSplit:
    """Training pairs and EPE test pairs (see the module docstring)."""
    if not ds.pairs:
        raise ValueError(f"{ds.root / 'pairs.csv'}: no frame pairs to fine-tune on; re-run "
                         "`dvc repro prepare` with more frames per scene")
    scenes = list(dict.fromkeys(p.scene for p in ds.pairs))
    gt_scenes = [s for s in scenes if any(_has_gt(ds, p) for p in ds.pairs if p.scene == s)]
    held = gt_scenes[len(gt_scenes) - holdout_scenes:] if holdout_scenes > 0 else []
    if held and len(held) >= len(scenes):
        warnings.warn(f"flow_finetune: holding out {holdout_scenes} scene(s) leaves no training scene out of "
                      f"{len(scenes)}; the EPE is measured on the training pairs", stacklevel=2)
        return PairSplit(list(ds.pairs), [p for p in ds.pairs if _has_gt(ds, p)], scenes, gt_scenes, True)
    train = [p for p in ds.pairs if p.scene not in held]
    test = [p for p in ds.pairs if p.scene in held and _has_gt(ds, p)]
    return PairSplit(train, test, [s for s in scenes if s not in held], held, False)


class FlowPairs(torch.utils.data.Dataset):
    """Prepared pairs → ``{"img1", "img2" (3,H,W) in [0,1], "keypoints1", "keypoints2" (n,2) int64}``
    (the DSO keypoints of frame 1 and of frame 2; empty without a keypoint file)."""

    def __init__(self, ds: PreparedSet, pairs: list[PairRecord], keypoints: KeypointFile | None = None):
        self.ds, self.pairs, self.keypoints = ds, list(pairs), keypoints
        if keypoints is not None:
            frames = dict.fromkeys(f for p in self.pairs for f in (p.frame1, p.frame2))
            missing = [f for f in frames if ds.frame_index(f) not in keypoints]
            if missing:
                raise KeyError(f"{keypoints.path}: no keypoints for {len(missing)} prepared frame(s) such as "
                               f"{missing[0]}; re-run `dvc repro keypoints`")

    def __len__(self) -> int:
        return len(self.pairs)

    def _keypoints(self, frame: str) -> torch.Tensor:
        if self.keypoints is None:
            return torch.zeros(0, 2, dtype=torch.int64)
        return self.keypoints.tensor(self.ds.frame_index(frame))[:, :2]

    def __getitem__(self, i: int) -> dict[str, torch.Tensor]:
        p = self.pairs[i]
        return {"img1": to_tensor(self.ds.image(p.frame1)), "img2": to_tensor(self.ds.image(p.frame2)),
                "keypoints1": self._keypoints(p.frame1), "keypoints2": self._keypoints(p.frame2)}


def collate(items: list[dict[str, torch.Tensor]]) -> dict[str, torch.Tensor]:
    """Stack images; pad keypoints → ``keypoints (B,2,K,2)`` and ``keypoint_mask (B,2,K)``, index 0 = frame 1,
    1 = frame 2 (one tensor, so that a flip mirrors both frames' keypoints together)."""
    b = len(items)
    kp, mask = pad_keypoints([it["keypoints1"] for it in items] + [it["keypoints2"] for it in items])
    return {"img1": torch.stack([it["img1"] for it in items]),
            "img2": torch.stack([it["img2"] for it in items]),
            "keypoints": kp.view(2, b, -1, 2).transpose(0, 1).contiguous(),
            "keypoint_mask": mask.view(2, b, -1).transpose(0, 1).contiguous()}


def true_intrinsics(ds: PreparedSet) -> np.ndarray:
    """Geometric K of the prepared images (undoes ``p2net_cxcy_bug``; see the module docstring)."""
    cam = ds.camera
    if not cam.get("p2net_cxcy_bug"):
        return ds.K
    src_hw = (int(cam["source_height"]), int(cam["source_width"]))
    return crop_resize_intrinsics(np.asarray(cam["source_K"], np.float64), src_hw, int(cam["crop"]), ds.hw)


@dataclass(frozen=True)
class GTPair:
    """One scored pair: images ``(1,3,H,W)``, ``flow (1,2,H,W)`` float32, bool ``(1,1,H,W)`` masks."""

    pair_id: str
    img1: torch.Tensor
    img2: torch.Tensor
    flow: torch.Tensor
    occluded: torch.Tensor
    valid: torch.Tensor
    low_texture: torch.Tensor


def gt_pair(ds: PreparedSet, p: PairRecord, K: np.ndarray | None = None) -> GTPair:
    """Ground truth of one prepared pair with synthetic depth and pose."""
    g1, g2 = ds.gt(p.frame1), ds.gt(p.frame2)
    if g1 is None or g2 is None:
        raise ValueError(f"{ds.root}: pair {p.pair_id} has no ground truth (real data)")
    K_t = torch.from_numpy(true_intrinsics(ds) if K is None else K)[None]
    depth1 = torch.from_numpy(g1[0]).double()[None, None]
    depth2 = torch.from_numpy(g2[0]).double()[None, None]
    s_T_t = relative_pose(torch.from_numpy(g1[1])[None], torch.from_numpy(g2[1])[None])
    flow = rigid_flow(depth1, K_t, s_T_t)
    occluded = occlusion_by_depth(depth1, depth2, K_t, s_T_t) | (in_view_mask(flow) == 0)
    img1 = to_tensor(ds.image(p.frame1))[None]
    return GTPair(p.pair_id, img1, to_tensor(ds.image(p.frame2))[None], flow.float(), occluded, depth1 > 0,
                  low_texture_mask(img1))


def spread(pairs: list[PairRecord], limit: int | None) -> list[PairRecord]:
    """At most ``limit`` of ``pairs`` (None: all), spread evenly over the list."""
    if limit is not None and len(pairs) > limit:
        return [pairs[int(i)] for i in np.linspace(0, len(pairs) - 1, limit).round()]
    return list(pairs)


def scored_pairs(ds: PreparedSet, pairs: list[PairRecord], limit: int | None = None) -> list[PairRecord]:
    """The pairs that have ground truth; with ``limit``, at most that many, spread evenly over the list."""
    return spread([p for p in pairs if _has_gt(ds, p)], limit)


def image_pairs(ds: PreparedSet, pairs: list[PairRecord]) -> Iterator[tuple[str, torch.Tensor, torch.Tensor]]:
    """``(pair_id, img1, img2)`` of each pair, images ``(1,3,H,W)`` in [0,1] (lazily)."""
    return ((p.pair_id, to_tensor(ds.image(p.frame1))[None], to_tensor(ds.image(p.frame2))[None])
            for p in pairs)


def gt_pairs(ds: PreparedSet, pairs: list[PairRecord], limit: int | None = None) -> Iterator[GTPair]:
    """:func:`gt_pair` of :func:`scored_pairs` (lazily)."""
    K = true_intrinsics(ds)
    return (gt_pair(ds, p, K) for p in scored_pairs(ds, pairs, limit))
