"""Training diagnostics on the synthetic default's ground truth, and the floor a depth result must beat.

Self-supervised training can lower its loss without learning depth (a nearly constant depth plus poses
that explain the image motion), so the loss curve alone does not say whether training works. When the
prepared set carries ground truth (the embedded synthetic default: ``gt`` column of frames.csv), every
epoch also measures, on the training tuples, without augmentation:

* ``train_a1``, ``train_abs_rel``: δ<1.25 and AbsRel of the target depth, median-scaled per image over
  the valid ground-truth pixels (``f2depth.protocols.metrics.image_metrics``), averaged over targets;
* ``pose_rot_err``: mean angle (degrees) between the predicted and the true rotation of both source
  transforms (``1_T_0`` and ``-1_T_0``); ``pose_rot_true`` / ``pose_rot_pred``: the mean rotation angles;
* ``pose_trans_cos``: mean cosine between the predicted and the true translation directions (1 = right
  direction; the scale is free in monocular training);
* ``rigid_epe``: mean end-point error (pixels) of the rigid flow target → +1 that L_rigid compares with the
  teacher, ``rigid_flow(depth, K, 1_T_0)`` from the predicted depth and pose (their common scale cancels),
  against the exact rigid flow of the true depth and pose, over the valid ground-truth pixels.
:func:`teacher_epe` measures the frozen teacher's flow on the same pairs once, beside zero flow's: when
the network's own rigid flow is already closer to the truth than the teacher's, L_rigid pulls it towards
the teacher's errors (docs/method.md §9).
With pose priors (``train_depth.pose_prior: geometric``) the poses measured are those the losses use:
PoseCNN's residual composed with the prior (PoseCNN alone for pairs without one).

``constant_depth_metrics`` gives the validation metrics of a constant depth map: with per-image median
scaling that is what a network scores when it has learned nothing (see docs/depth_training.md).
Real data has no ground truth: ``TrainTruth.from_prepared`` returns None and nothing is measured.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
import torch
from torch import nn

from f2depth.formats.images import to_tensor
from f2depth.formats.prepared import PreparedSet
from f2depth.geometry import MAX_DEPTH, MIN_DEPTH, endpoint_error, relative_pose, rigid_flow
from f2depth.poses.store import PosePriors
from f2depth.protocols.metrics import EmptyMaskError, aggregate, image_metrics
from f2depth.train.step import pose_priors
from f2depth.train.validate import evaluating

#: Keys ``diagnose`` returns (history.csv columns and MLflow metrics).
DIAGNOSTIC_KEYS = ("train_a1", "train_abs_rel", "pose_rot_err", "pose_rot_true", "pose_rot_pred",
                   "pose_trans_cos", "rigid_epe")


@dataclass(frozen=True)
class TrainTruth:
    """Ground truth of the training tuples.

    target, prev, next (N,3,H,W) float32 RGB in [0, 1]; depth (N,H,W) float32 metres (0 = invalid);
    T_prev, T_next (N,4,4) float64: the true ``-1_T_0`` and ``1_T_0`` (target camera → source camera);
    K (3,3) float64: the intrinsics of every frame; priors: None, or [(prior, ok)] of the pairs
    ``[I-1, I0]`` and ``[I0, I1]`` as ``step.pose_priors`` gives them: the priors ``0_T_-1``, ``1_T_0``
    (N,4,4) float32 that PoseCNN refines and their flags (N,).
    """

    target: torch.Tensor
    prev: torch.Tensor
    next: torch.Tensor
    depth: np.ndarray
    T_prev: torch.Tensor
    T_next: torch.Tensor
    K: torch.Tensor
    priors: list[tuple[torch.Tensor, torch.Tensor]] | None = None

    def __len__(self) -> int:
        return int(self.target.shape[0])

    @cached_property
    def exact_flow(self) -> tuple[torch.Tensor, torch.Tensor]:
        """The exact rigid flow target → +1 (N,2,H,W) pixels, x first, float32, and where the target's
        ground-truth depth is valid (N,1,H,W) bool (computed on first use, then kept)."""
        depth = torch.from_numpy(self.depth)[:, None].double()
        flow = rigid_flow(depth, self.K.expand(len(self), 3, 3), self.T_next)
        return flow.float(), depth > 0

    @classmethod
    def from_prepared(cls, prepared: PreparedSet, max_tuples: int | None = None,
                      priors: PosePriors | None = None) -> TrainTruth | None:
        """Tuples whose three frames have ground truth (at most ``max_tuples``, evenly spread), or None."""
        tuples = [t for t in prepared.tuples if all(prepared.has_gt(f) for f in (t.target, t.prev, t.next))]
        if not tuples:
            return None
        if max_tuples is not None and len(tuples) > max_tuples:
            keep = np.unique(np.linspace(0, len(tuples) - 1, int(max_tuples)).round().astype(int))
            tuples = [tuples[i] for i in keep]
        # a frame is the target of one tuple and a source of up to two: read each once
        fids = {f for t in tuples for f in (t.target, t.prev, t.next)}
        img = {f: to_tensor(prepared.image(f)) for f in fids}
        gt = {f: prepared.gt(f) for f in fids}
        world = {f: torch.from_numpy(gt[f][1]) for f in fids}
        prior = None
        if priors is not None:
            p = [priors[t.tuple_id] for t in tuples]
            prior = pose_priors({"prior_prev": torch.from_numpy(np.stack([x.T_prev for x in p])),
                                 "prior_next": torch.from_numpy(np.stack([x.T_next for x in p])),
                                 "prior_prev_ok": torch.tensor([x.prev_ok for x in p]),
                                 "prior_next_ok": torch.tensor([x.next_ok for x in p])})
        return cls(
            torch.stack([img[t.target] for t in tuples]), torch.stack([img[t.prev] for t in tuples]),
            torch.stack([img[t.next] for t in tuples]), np.stack([gt[t.target][0] for t in tuples]),
            torch.stack([relative_pose(world[t.target], world[t.prev]) for t in tuples]),
            torch.stack([relative_pose(world[t.target], world[t.next]) for t in tuples]),
            torch.from_numpy(prepared.K).double(), prior,
        )


def rotation_angle(R: torch.Tensor) -> torch.Tensor:
    """Rotation angle in degrees of rotation matrices (..., 3, 3) → (...)."""
    trace = R[..., 0, 0] + R[..., 1, 1] + R[..., 2, 2]
    return torch.rad2deg(torch.arccos(((trace - 1) / 2).clamp(-1.0, 1.0)))


def pose_errors(T_pred: torch.Tensor, T_true: torch.Tensor) -> dict[str, float]:
    """Predicted vs true rigid transforms (N,4,4) → mean rotation error / angles (degrees) and the mean
    cosine of the translation directions (a zero-length translation counts as cosine 0)."""
    T_pred, T_true = T_pred.double(), T_true.double()
    R_err = T_pred[:, :3, :3] @ T_true[:, :3, :3].transpose(1, 2)
    t_pred, t_true = T_pred[:, :3, 3], T_true[:, :3, 3]
    cos = torch.nn.functional.cosine_similarity(t_pred, t_true, dim=1, eps=1e-12)
    return {
        "pose_rot_err": float(rotation_angle(R_err).mean()),
        "pose_rot_true": float(rotation_angle(T_true[:, :3, :3]).mean()),
        "pose_rot_pred": float(rotation_angle(T_pred[:, :3, :3]).mean()),
        "pose_trans_cos": float(cos.mean()),
    }


def flow_epe(flow: torch.Tensor, exact: torch.Tensor, valid: torch.Tensor) -> float:
    """flow, exact (N,2,H,W) pixels, valid (N,1,H,W) bool → mean end-point error over the valid pixels."""
    return float(endpoint_error(flow.float(), exact)[valid].mean())


@torch.no_grad()
def teacher_epe(teacher, truth: TrainTruth, device: torch.device | str = "cpu",
                batch_size: int = 8) -> dict[str, float]:
    """The frozen teacher's flow target → +1 on ``truth``'s pairs against the exact rigid flow →
    ``{"teacher": EPE, "zero_flow": EPE}`` (pixels). ``teacher``: a ``FlowTeacher`` (its ``flow``)."""
    exact, valid = truth.exact_flow
    flows = [teacher.flow(truth.target[s:s + batch_size].to(device), truth.next[s:s + batch_size].to(device))
             .cpu() for s in range(0, len(truth), batch_size)]
    return {"teacher": flow_epe(torch.cat(flows), exact, valid),
            "zero_flow": flow_epe(torch.zeros_like(exact), exact, valid)}


def depth_accuracy(pred: np.ndarray, gt: np.ndarray, min_depth: float = MIN_DEPTH,
                   max_depth: float = MAX_DEPTH) -> dict[str, float]:
    """pred, gt (N,H,W) metres → mean over images of median-scaled δ1 and AbsRel (images without valid
    ground truth are left out; NaN when none has any)."""
    per_image = []
    for p, g in zip(pred, gt):
        try:
            per_image.append(image_metrics(g, p, min_depth=min_depth, max_depth=max_depth)[0])
        except EmptyMaskError:
            continue
    mean = aggregate(per_image).mean
    return {"train_a1": mean["a1"], "train_abs_rel": mean["abs_rel"]}


@torch.no_grad()
def diagnose(model: nn.Module, truth: TrainTruth, device: torch.device | str = "cpu",
             batch_size: int = 8) -> dict[str, float]:
    """Depth accuracy and pose errors of ``model`` (a DepthModel, eval mode while measuring) on ``truth``
    (module docstring) → ``{key: float for key in DIAGNOSTIC_KEYS}``."""
    depths, T_prev, T_next = [], [], []
    with evaluating(model):
        for s in range(0, len(truth), batch_size):
            tgt, prv, nxt = (x[s:s + batch_size].to(device) for x in (truth.target, truth.prev, truth.next))
            pp, pn = ([tuple(x[s:s + batch_size].to(device) for x in pair) for pair in truth.priors]
                      if truth.priors is not None else ((), ()))
            depths.append(model.predict_depth(tgt)[:, 0].float().cpu().numpy())
            T_prev.append(model.predict_pose(prv, tgt, True, *pp).cpu())
            T_next.append(model.predict_pose(tgt, nxt, False, *pn).cpu())
    cfg = model.config
    depth = np.concatenate(depths)
    out = depth_accuracy(depth, truth.depth, cfg.min_depth, cfg.max_depth)
    out.update(pose_errors(torch.cat(T_prev + T_next), torch.cat([truth.T_prev, truth.T_next])))
    exact, valid = truth.exact_flow
    rigid = rigid_flow(torch.from_numpy(depth)[:, None].double(), truth.K.expand(len(truth), 3, 3),
                       torch.cat(T_next).double())
    out["rigid_epe"] = flow_epe(rigid, exact, valid)
    return out


def constant_depth_metrics(validator) -> dict[str, float]:
    """``{"val_abs_rel", "val_a1"}`` of a constant depth on ``validator``'s images (the learned-nothing
    floor: median scaling makes every constant the same)."""
    return validator.score(lambda x: torch.ones(x.shape[0], 1, x.shape[2], x.shape[3], device=x.device))
