"""F²Depth's flow losses: optical-flow consistency L_rigid and feature-map synthesis L_feature.

Conventions (the paper §3.2–3.3; the reading is in docs/method.md §6): flows go from the target
(frame 0) to the source (frame +1), ``(B,2,H,W)`` pixels, x first. The flow network is frozen: its flow
and features are detached here, so gradients reach depth and pose only through the rigid flow.
"""

from __future__ import annotations

import torch

from f2depth.geometry import in_view_mask, resize_flow, warp


def rigid_flow_loss(
    flow_rigid: torch.Tensor, flow_net: torch.Tensor, valid: torch.Tensor | None = None
) -> torch.Tensor:
    """L_rigid = mean |f_rigid − f_flow| over pixels and both components.

    flow_rigid (B,2,H,W) from predicted depth and pose, flow_net (B,2,H,W) from the frozen flow network
    (detached here), valid optional (B,1,H,W) {0, 1} weights: the mean is then over valid pixels only.
    """
    if flow_rigid.shape != flow_net.shape:
        raise ValueError(
            f"rigid flow {tuple(flow_rigid.shape)} and network flow {tuple(flow_net.shape)} differ in shape; "
            "run the flow network at the depth network's input size (or resize_flow its output)"
        )
    diff = (flow_rigid - flow_net.detach()).abs()
    if valid is None:
        return diff.mean()
    valid = valid.to(diff.dtype)
    return (diff * valid).sum() / (2 * valid.sum()).clamp(min=1.0)


def feature_synthesis_level(
    feat_tgt: torch.Tensor, feat_src: torch.Tensor, flow: torch.Tensor
) -> torch.Tensor:
    """One level: mean over channels and in-view pixels of |F_src(p + f(p)) − F_tgt(p)|.

    feat_tgt, feat_src (B,C,h,w) (detached here), flow (B,2,h,w) in pixels of this level → scalar.
    """
    warped = warp(feat_src.detach(), flow)
    mask = in_view_mask(flow)
    diff = (warped - feat_tgt.detach()).abs().mean(dim=1, keepdim=True)
    return (diff * mask).sum() / mask.sum().clamp(min=1.0)


def feature_synthesis_loss(
    feats_tgt: list[torch.Tensor], feats_src: list[torch.Tensor], flow_rigid: torch.Tensor
) -> torch.Tensor:
    """L_feature: mean over pyramid levels of ``feature_synthesis_level``.

    feats_tgt, feats_src: lists of (B,C_l,h_l,w_l) pyramid features of the target and source from the
    frozen flow network (any order of levels, matching between the two lists), flow_rigid (B,2,H,W)
    target → source at the input resolution; it is resized to each level with ``resize_flow``.
    """
    if len(feats_tgt) != len(feats_src) or not feats_tgt:
        raise ValueError(f"need matching feature pyramids, got {len(feats_tgt)} and {len(feats_src)} levels")
    losses = []
    for ft, fs in zip(feats_tgt, feats_src):
        if ft.shape != fs.shape:
            raise ValueError(
                f"target features {tuple(ft.shape)} and source features {tuple(fs.shape)} differ"
            )
        losses.append(feature_synthesis_level(ft, fs, resize_flow(flow_rigid, ft.shape[-2:])))
    return torch.stack(losses).mean()
