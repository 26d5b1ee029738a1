"""One depth-training step as functions: networks → frozen flow network → loss terms → total → update.

Conventions (Monodepth2 / P²Net, ``f2depth.depth.model``): the pose network sees ``[I−1, I0]`` and
``[I0, I+1]`` (colour-augmented); the source-from-target transforms used for warping are
``T−1 = −1_T_0 = predict_pose(I−1, I0, invert=True)`` and ``T+1 = 1_T_0 = predict_pose(I0, I+1)``.
With pose priors in the batch (``train_depth.pose_prior: geometric``) PoseCNN refines them: the prior of
``[I−1, I0]`` is ``0_T_−1 = (prior_prev)⁻¹``, that of ``[I0, I+1]`` is ``prior_next``; a sample whose flag is
False gets PoseCNN's own pose (``DepthModel.predict_pose`` chooses per sample with ``torch.where``).

Terms (the paper §3.2–3.4), all on the un-augmented frames (:data:`TERMS`; ph has weight 1, each other's
weight is the params.yaml key in :data:`WEIGHT_KEYS`):
  ph       P²Net's patch photometric loss, minimum over the two sources;
  smooth   L_sm, edge-aware smoothness of the mean-normalised sigmoid disparity;
  planar   L_spp, planar loss over superpixels larger than P²Net's 1000 px at 288×384, scaled by image area;
  rigid    L_rigid, mean |f_rigid − f_flow| for target → +1 (``f_rigid = rigid_flow(depth, K, T+1)``);
  feature  L_feature, multi-scale feature synthesis with the frozen network's pyramids, warped by ``f_rigid``.
rigid and feature need a flow teacher (:data:`FLOW_TERMS`); without one (P²Net baseline) they are left out.
A term whose weight is 0 but that can be computed (e.g. feature for ``no_feature``) is computed without
gradients, for the logs only. ``f2depth.losses.total_loss`` multiplies each term by its weight by name,
sums them and guards against NaN/inf.

Mixed precision (``train_depth.amp``, off in the paper's profile: P²Net trains in float32): with ``amp``
the networks run under ``torch.autocast`` — float16 on CUDA (with a GradScaler in the loop), bfloat16 on
a CPU —; the geometry and every loss run in float32 with autocast off.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from contextlib import nullcontext
from dataclasses import dataclass, replace

import torch
from torch import nn

from f2depth.geometry import MAX_DEPTH, MIN_DEPTH, invert_pose, rigid_flow
from f2depth.losses import (
    NonFiniteLossError,
    edge_aware_smoothness,
    feature_synthesis_loss,
    patch_photometric_loss,
    planar_loss,
    rigid_flow_loss,
    total_loss,
)
from f2depth.precision import autocast, backward_and_step, full_precision
from f2depth.train.teacher import FlowTeacher, TeacherOutput

#: The weighted terms of L_depth (history.csv's columns after ph, in this order). Adding a term: compute it
#: in :func:`loss_terms`, name it here (and in FLOW_TERMS when it needs the flow network) and give its
#: weight a top-level key of params.yaml in WEIGHT_KEYS.
TERMS = ("smooth", "planar", "rigid", "feature")
#: The top-level params.yaml key of each term's weight: the paper's names of eq. (11),
#: L_depth = L_ph + λ1·L_sm + λ2·L_spp + L_rigid + λ3·L_feature; L_rigid has no λ there (weight 1),
#: ``lambda_rigid`` weighs it here.
WEIGHT_KEYS = {"smooth": "lambda1", "planar": "lambda2", "rigid": "lambda_rigid", "feature": "lambda3"}
#: The terms that need the frozen flow network: a variant without one (``flow: null``) must switch them off.
FLOW_TERMS = ("rigid", "feature")


@dataclass(frozen=True)
class StepConfig:
    weights: Mapping[str, float]  # term → weight, every name of TERMS (f2depth.train.settings.loss_weights)
    min_area: float  # superpixels of more pixels take part in L_spp
    min_depth: float = MIN_DEPTH
    max_depth: float = MAX_DEPTH
    amp: bool = False  # autocast the networks: float16 on CUDA, bfloat16 on a CPU

    def with_flow_factor(self, factor: float) -> StepConfig:
        """This config with the weights of the flow terms (:data:`FLOW_TERMS`) times ``factor`` (itself at
        1)."""
        if factor == 1.0:
            return self
        weights = {t: w * factor if t in FLOW_TERMS else w for t, w in self.weights.items()}
        return replace(self, weights=weights)


@dataclass
class NetOutput:
    """disp (B,1,H,W) sigmoid output, depth (B,1,H,W) metres, T_prev / T_next (B,4,4) src_T_tgt; float32."""

    disp: torch.Tensor
    depth: torch.Tensor
    T_prev: torch.Tensor
    T_next: torch.Tensor


def batch_to(batch: dict[str, torch.Tensor], device: torch.device | str) -> dict[str, torch.Tensor]:
    non_blocking = torch.device(device).type == "cuda"
    return {k: v.to(device, non_blocking=non_blocking) for k, v in batch.items()}


def pose_priors(batch: dict[str, torch.Tensor]) -> list[tuple[torch.Tensor, torch.Tensor]] | None:
    """[(prior, ok)] of PoseCNN's two pairs: the priors ``0_T_−1`` and ``1_T_0`` (B,4,4) float32 — the
    identity where a sample's flag ``prior_*_ok`` (B,) is False — with those flags; None when the batch has
    no priors (module docstring)."""
    if "prior_next" not in batch:
        return None
    eye = torch.eye(4, dtype=torch.float32, device=batch["prior_next"].device)
    out = []
    for key, invert in (("prior_prev", True), ("prior_next", False)):
        ok = batch[f"{key}_ok"].bool()
        T = torch.where(ok[:, None, None], batch[key].float(), eye)
        out.append((invert_pose(T) if invert else T, ok))
    return out


def network_forward(model: nn.Module, batch: dict[str, torch.Tensor], amp: bool = False) -> NetOutput:
    """Depth of the target and the two source poses, through ``model.forward`` (so DDP sees one call).

    ``model`` is a DepthModel or its DDP wrapper; the depth is recomputed from the float32 disparity.
    """
    core = model.module if hasattr(model, "module") else model
    device = batch["target_aug"].device
    pairs = [(batch["prev_aug"], batch["target_aug"], True), (batch["target_aug"], batch["next_aug"], False)]
    priors = pose_priors(batch)
    if priors is not None:
        pairs = [(*pair, *prior) for pair, prior in zip(pairs, priors)]
    with autocast(device, amp):
        disp, _, poses = model(batch["target_aug"], pairs)
    disp = disp.float()
    return NetOutput(disp, core.disp_to_depth(disp), poses[0].float(), poses[1].float())


def teacher_forward(teacher: FlowTeacher | None, batch: dict[str, torch.Tensor], features: bool,
                    amp: bool = False) -> TeacherOutput | None:
    """The frozen network's flow target → +1 (and pyramids) on the un-augmented frames, or None."""
    if teacher is None:
        return None
    with autocast(batch["target"].device, amp):
        return teacher(batch["target"], batch["next"], features=features)


def photometric_term(batch: dict[str, torch.Tensor], depth: torch.Tensor, T_prev: torch.Tensor,
                     T_next: torch.Tensor) -> torch.Tensor:
    """L_ph of a batch of tuples — target, prev, next (B,3,H,W), K (B,3,3), points (B,N,2) from the batch —
    with depth (B,1,H,W) metres and T_prev, T_next (B,4,4) src_T_tgt → scalar (float32)."""
    return patch_photometric_loss(batch["target"].float(), [batch["prev"].float(), batch["next"].float()],
                                  depth.float(), batch["K"].float(), [T_prev.float(), T_next.float()],
                                  batch["points"])


def loss_terms(net: NetOutput, batch: dict[str, torch.Tensor], flow: TeacherOutput | None,
               config: StepConfig) -> dict[str, torch.Tensor]:
    """The scalar loss terms by name (float32, autocast off); see the module docstring."""
    w = config.weights
    device = net.depth.device
    ctx = full_precision(device) if config.amp else nullcontext()
    with ctx:
        target, K = batch["target"].float(), batch["K"].float()
        terms = {
            "ph": photometric_term(batch, net.depth, net.T_prev, net.T_next),
            "smooth": edge_aware_smoothness(net.disp, target),
            "planar": planar_loss(net.depth, torch.linalg.inv(K), batch["segments"], min_area=config.min_area,
                                  min_depth=config.min_depth, max_depth=config.max_depth),
        }
        if flow is None:
            return terms
        grad = torch.is_grad_enabled()
        with torch.set_grad_enabled(grad and (w["rigid"] != 0 or w["feature"] != 0)):
            f_rigid = rigid_flow(net.depth, K, net.T_next)
        with torch.set_grad_enabled(grad and w["rigid"] != 0):
            terms["rigid"] = rigid_flow_loss(f_rigid, flow.flow, flow.valid)
        if flow.feats_tgt:
            with torch.set_grad_enabled(grad and w["feature"] != 0):
                terms["feature"] = feature_synthesis_loss(flow.feats_tgt, flow.feats_src, f_rigid)
    return terms


def compute_loss(model: nn.Module, batch: dict[str, torch.Tensor], teacher: FlowTeacher | None,
                 config: StepConfig, context: str = "") -> tuple[torch.Tensor, dict[str, float]]:
    """Forward everything for one batch → (L_depth, {term: float, "total": float}).

    Raises ``NonFiniteLossError`` naming the first NaN/inf term. Pyramid features are computed when a
    teacher is given (L_feature is logged even with its weight 0).
    """
    net = network_forward(model, batch, config.amp)
    flow = teacher_forward(teacher, batch, features=True, amp=config.amp)
    return total_loss(loss_terms(net, batch, flow, config), config.weights, context)


def train_step(
    model: nn.Module,
    optimizer: torch.optim.Optimizer,
    batch: dict[str, torch.Tensor],
    teacher: FlowTeacher | None,
    config: StepConfig,
    scaler: torch.amp.GradScaler | None = None,
    context: str = "",
    agree: Callable[[NonFiniteLossError | None], None] | None = None,
) -> tuple[torch.Tensor, dict[str, float]]:
    """One optimisation step on ``batch`` (already on the device) → (detached loss, logs).

    agree: called with the local NaN/inf error (or None) before backward; under DDP it raises the same
    error on every rank when any rank failed (``distributed.agree_finite``), so no rank is left waiting in
    an all-reduce. Without it a local error is raised directly.
    """
    optimizer.zero_grad(set_to_none=True)
    error: NonFiniteLossError | None = None
    loss = logs = None
    try:
        loss, logs = compute_loss(model, batch, teacher, config, context)
    except NonFiniteLossError as exc:
        error = exc
    if agree is not None:
        agree(error)
    if error is not None:
        raise error
    backward_and_step(loss, optimizer, scaler)
    return loss.detach(), logs
