"""Characterization values of f2depth: what today's code computes on fixed, seeded, small inputs.

Issue #16 redesigns the library "without changing any result". These functions pin that: each builds its
own inputs (seeded generators, tiny fake data sets written into a temporary folder, no file of data/ or
models/), runs one group of the library's numbers and returns a flat ``{name: float}``. The stored values
are in ``tests/data/characterization.json``; ``tests/test_characterization.py`` recomputes every group and
compares (tolerances there).

Groups (:data:`GROUPS`): every depth loss term with its gradients, the geometry, every flow loss (ARFlow's
with ``SINTEL_RAW`` / ``SINTEL_FT``, census, the patch fine-tuning loss in four settings, ``batch_loss``),
every metric (per-image metrics, median scaling, flip post-processing, EPE), one depth training step
(``full`` with a random PWC-Lite teacher and ``baseline``: logs, per-tensor sums of weights, gradients and
BatchNorm statistics after the step), one flow fine-tuning step (``patch`` and ``full``), one evaluation
(NYU, 7-Scenes, Campus on their fakes, ± post-processing) and the DSO selector / ``prepare`` checksums.

The builders call the library's public functions as the stages do: every setting that comes from
params.yaml is spelled out here (with params.yaml's or the paper's value), while the library's own
constants (ARFlow's, P²Net's, DSO's: SSIM's C1/C2, the census ε, the planar ridge, the occlusion check's
scale and bias, …) are left to the library, so a change of any of them moves a value. A redesign that
renames an API may adapt a call here, but must not change a stored value.

Regenerate the stored values ONLY when a change of behaviour is intended, and say so in the commit
message ("characterization values rewritten: <why>")::

    .venv/bin/python tests/characterization.py --write        # rewrite tests/data/characterization.json
    .venv/bin/python tests/characterization.py --check        # list the values that differ, write nothing
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
from collections.abc import Callable, Mapping
from pathlib import Path

import cv2
import fakes
import numpy as np
import torch
import torch.nn.functional as F
import train_fakes

STORE = Path(__file__).resolve().parent / "data" / "characterization.json"
Values = dict[str, float]

# ---- helpers -----------------------------------------------------------------------------------------


def _array(x) -> np.ndarray:
    if isinstance(x, torch.Tensor):
        x = x.detach().cpu()
        x = x.to(torch.float64) if x.dtype != torch.bool else x.to(torch.int64)
        return x.numpy().astype(np.float64).ravel()
    return np.asarray(x, dtype=np.float64).ravel()


def summary(out: Values, name: str, x, samples: int = 4) -> None:
    """``name.sum``, ``name.abs_sum`` and ``samples`` values at evenly spaced flat positions of ``x``."""
    a = _array(x)
    out[f"{name}.sum"] = float(a.sum())
    out[f"{name}.abs_sum"] = float(np.abs(a).sum())
    if a.size:
        for i in np.unique(np.linspace(0, a.size - 1, samples).round().astype(int)):
            out[f"{name}.at{i}"] = float(a[i])


def checksum(out: Values, name: str, x) -> None:
    """Exact checksums of an integer-valued array: count, sum and a position-weighted sum."""
    a = _array(x)
    out[f"{name}.count"] = float(a.size)
    out[f"{name}.sum"] = float(a.sum())
    out[f"{name}.weighted"] = float((a * (np.arange(a.size) % 251 + 1)).sum())


#: The store's names of the terms L_sm and L_spp, from before issue #16 named each term as its weight in
#: params.yaml's weights (smooth, planar); the values are the same.
STORED_TERM_NAMES = {"smooth": "sm", "planar": "spp"}


def stored_terms(logs: Mapping[str, float]) -> dict[str, float]:
    """Loss logs (term → value) under the store's term names."""
    return {STORED_TERM_NAMES.get(k, k): v for k, v in logs.items()}


def put(out: Values, prefix: str, values: Mapping[str, object]) -> None:
    """Copy the numeric entries of ``values`` as ``prefix.key`` (None and text are left out)."""
    for k, v in values.items():
        if isinstance(v, bool | int | float | np.floating | np.integer):
            out[f"{prefix}.{k}"] = float(v)


def smooth(gen: torch.Generator, shape: tuple[int, ...], cells: tuple[int, int], texture: float = 0.05
           ) -> torch.Tensor:
    """Smooth random float64 field in [0, 1] of ``shape`` (B,C,H,W): a coarse random grid upsampled
    bilinearly plus a little per-pixel texture."""
    b, c, h, w = shape
    coarse = torch.rand(b, c, *cells, generator=gen, dtype=torch.float64)
    fine = F.interpolate(coarse, size=(h, w), mode="bilinear", align_corners=True)
    noise = torch.rand(b, c, h, w, generator=gen, dtype=torch.float64)
    return ((1 - texture) * fine + texture * noise).clamp(0.0, 1.0)


def intrinsics(h: int, w: int, b: int = 1) -> torch.Tensor:
    """(B,3,3) float64 pinhole K with an off-centre principal point."""
    K = torch.tensor([[0.8 * w, 0.0, 0.45 * w], [0.0, 0.85 * w, 0.55 * h], [0.0, 0.0, 1.0]],
                     dtype=torch.float64)
    return K.expand(b, 3, 3).clone()


def _f(x: torch.Tensor) -> float:
    return float(x.detach())


def _grad(out: Values, name: str, value: torch.Tensor, inputs: list[torch.Tensor]) -> None:
    grads = torch.autograd.grad(value, inputs, retain_graph=True, allow_unused=True)
    for i, g in enumerate(grads):
        if g is not None:
            summary(out, f"{name}.grad{i}", g, samples=2)


# ---- depth losses and geometry -------------------------------------------------------------------------


def _depth_scene():
    """Target, two sources, depth, sigmoid disparity, K, poses, points and superpixels (float64)."""
    from f2depth.geometry import pose_from_params

    g = torch.Generator().manual_seed(11)
    b, h, w = 2, 24, 32
    target = smooth(g, (b, 3, h, w), (4, 5))
    prev = (0.7 * target + 0.3 * smooth(g, (b, 3, h, w), (3, 4))).clamp(0, 1)
    nxt = (0.8 * target + 0.2 * smooth(g, (b, 3, h, w), (5, 6))).clamp(0, 1)
    depth = (1.0 + 3.0 * smooth(g, (b, 1, h, w), (3, 4))).requires_grad_()
    disp = torch.sigmoid(4 * smooth(g, (b, 1, h, w), (4, 4)) - 2).requires_grad_()
    K = intrinsics(h, w, b)
    aa = torch.tensor([[0.01, -0.02, 0.005], [-0.015, 0.01, 0.02]], dtype=torch.float64)
    t = torch.tensor([[0.05, 0.01, -0.03], [-0.04, 0.02, 0.06]], dtype=torch.float64)
    T_prev = pose_from_params(aa, t, invert=True)
    T_next = pose_from_params(-0.5 * aa, 2.0 * t, invert=False)
    n = 40
    xs = torch.randint(0, w, (b, n), generator=g).to(torch.float64)
    ys = torch.randint(0, h, (b, n), generator=g).to(torch.float64)
    points = torch.stack([xs, ys], -1)
    points[:, :4] = torch.tensor([[0.0, 0.0], [w - 1.0, h - 1.0], [0.4, 5.6], [w - 1.0, 0.0]],
                                 dtype=torch.float64)
    rows = torch.arange(h)[:, None] // 6
    cols = torch.arange(w)[None, :] // 8
    segments = torch.stack([rows * 4 + cols, (rows * 4 + cols) % 5 + 3 * rows]).to(torch.int64)
    segments[0, :5, :10] = -1  # ignored pixels; cuts the first superpixel below min_area
    return {"target": target, "prev": prev, "next": nxt, "depth": depth, "disp": disp, "K": K,
            "T_prev": T_prev, "T_next": T_next, "points": points, "segments": segments, "gen": g}


def depth_losses() -> Values:
    """L_ph, L_sm, L_spp, L_rigid, L_feature, their weighted sums and SSIM, with gradients."""
    from f2depth.geometry import in_view_mask, rigid_flow
    from f2depth.losses import (
        edge_aware_smoothness,
        feature_synthesis_loss,
        fit_planes,
        patch_photometric_errors,
        patch_photometric_loss,
        planar_depth,
        planar_loss,
        rigid_flow_loss,
        ssim_dense,
        ssim_samples,
        total_loss,
    )

    s = _depth_scene()
    g, depth, K = s["gen"], s["depth"], s["K"]
    out: Values = {}
    sources, poses = [s["prev"], s["next"]], [s["T_prev"], s["T_next"]]
    ph = patch_photometric_loss(s["target"], sources, depth, K, poses, s["points"])
    out["ph"] = _f(ph)
    _grad(out, "ph", ph, [depth])
    summary(out, "ph_errors", patch_photometric_errors(s["target"], sources, depth, K, poses, s["points"]))
    sm = edge_aware_smoothness(s["disp"], s["target"])
    out["sm"] = _f(sm)
    _grad(out, "sm", sm, [s["disp"]])
    K_inv = torch.linalg.inv(K)
    spp = planar_loss(depth, K_inv, s["segments"], min_area=40, min_depth=0.1, max_depth=10.0)
    out["spp"] = _f(spp)
    _grad(out, "spp", spp, [depth])
    d_plane, mask = planar_depth(depth, K_inv, s["segments"], min_area=40, min_depth=0.1, max_depth=10.0)
    summary(out, "spp_plane_depth", d_plane)
    out["spp_mask.sum"] = float(mask.sum())
    normals, _, area = fit_planes(depth, K_inv, s["segments"])
    summary(out, "spp_normals", normals)
    out["spp_area.sum_sq"] = float((area.double() ** 2).sum())

    f_rigid = rigid_flow(depth, K, s["T_next"])
    flow_net = f_rigid.detach() + 2.0 * (smooth(g, f_rigid.shape, (3, 4)) - 0.5)
    rigid = rigid_flow_loss(f_rigid, flow_net)
    out["rigid"] = _f(rigid)
    _grad(out, "rigid", rigid, [depth])
    rigid_valid = rigid_flow_loss(f_rigid, flow_net, in_view_mask(f_rigid))
    out["rigid_valid"] = _f(rigid_valid)
    big = rigid_flow(depth, K, s["T_next"] @ _shift(0.25, 0.1))  # leaves the view on one side
    feats_t = [smooth(g, (2, c, 24 // 2 ** (i + 1), 32 // 2 ** (i + 1)), (3, 3))
               for i, c in enumerate((4, 6, 8))]
    feats_s = [smooth(g, f.shape, (3, 3)) for f in feats_t]
    feature = feature_synthesis_loss(feats_t, feats_s, big)
    out["feature"] = _f(feature)
    out["feature.in_view"] = float(in_view_mask(big).sum())
    _grad(out, "feature", feature, [depth])

    terms = {"ph": ph, "smooth": sm, "planar": spp, "rigid": rigid, "feature": feature}
    weight_sets = {"paper": {"smooth": 0.001, "planar": 0.05, "rigid": 1.0, "feature": 3.0},
                   "other": {"smooth": 0.01, "planar": 0.1, "rigid": 0.5, "feature": 2.0}}
    for name, weights in weight_sets.items():
        loss, logs = total_loss(terms, weights)
        put(out, f"total_{name}", stored_terms(logs))
        _grad(out, f"total_{name}", loss, [depth])
    base = {"smooth": 0.001, "planar": 0.05, "rigid": 0.0, "feature": 0.0}
    _, logs = total_loss({k: terms[k] for k in ("ph", "smooth", "planar")}, base)
    put(out, "total_baseline", stored_terms(logs))

    summary(out, "ssim_dense", ssim_dense(s["target"], s["prev"]))
    a = smooth(g, (2, 3, 40, 9), (5, 3))
    summary(out, "ssim_samples", ssim_samples(a, (0.6 * a + 0.4 * smooth(g, a.shape, (4, 4))), dim=-1))
    return out


def _shift(tx: float, ty: float) -> torch.Tensor:
    T = torch.eye(4, dtype=torch.float64)[None].repeat(2, 1, 1)
    T[:, 0, 3], T[:, 1, 3] = tx, ty
    return T


def geometry() -> Values:
    """Back-projection, projection, rigid flow, poses, warping, flow resizing, view and occlusion masks,
    and the depth decoder's disparity → depth map."""
    from f2depth.depth.decoder import disp_to_depth, sigmoid_input_for_depth
    from f2depth.geometry import (
        axis_angle_to_matrix,
        backproject,
        in_view_mask,
        invert_pose,
        occlusion_by_depth,
        pose_from_params,
        project,
        relative_pose,
        resize_flow,
        rigid_flow,
        warp,
    )

    g = torch.Generator().manual_seed(12)
    b, h, w = 2, 12, 16
    depth = 1.0 + 2.0 * smooth(g, (b, 1, h, w), (3, 3))
    K = intrinsics(h, w, b)
    out: Values = {}
    summary(out, "backproject", backproject(depth, torch.linalg.inv(K)))
    aa = torch.tensor([[0.1, -0.2, 0.05], [3e-4, -2e-4, 1e-4]], dtype=torch.float64)  # normal, Taylor branch
    t = torch.tensor([[0.3, -0.1, 0.2], [0.05, 0.0, -0.02]], dtype=torch.float64)
    summary(out, "axis_angle", axis_angle_to_matrix(aa), samples=9)
    summary(out, "axis_angle_zero", axis_angle_to_matrix(torch.zeros(1, 3, dtype=torch.float64)), samples=3)
    T = pose_from_params(aa, t)
    T_inv = pose_from_params(aa, t, invert=True)
    summary(out, "pose", T, samples=16)
    summary(out, "pose_inverted", T_inv, samples=16)
    summary(out, "invert_pose", invert_pose(T), samples=16)
    world_a = pose_from_params(torch.tensor([[0.2, 0.1, -0.3]] * 2, dtype=torch.float64), t)
    summary(out, "relative_pose", relative_pose(world_a, T), samples=16)
    pix, z = project(backproject(depth, torch.linalg.inv(K)), K, T)
    summary(out, "project_pix", pix)
    summary(out, "project_z", z)
    flow = rigid_flow(depth, K, T)
    summary(out, "rigid_flow", flow, samples=8)
    img = smooth(g, (b, 3, h, w), (4, 4))
    summary(out, "warp_border", warp(img, flow, padding="border"))
    summary(out, "warp_zeros", warp(img, flow, padding="zeros"))
    summary(out, "resize_flow_down", resize_flow(flow, (6, 8)))
    summary(out, "resize_flow_up", resize_flow(flow, (20, 24)))
    out["in_view.sum"] = float(in_view_mask(flow).sum())
    sig = torch.linspace(0.0, 1.0, 11, dtype=torch.float64)
    scaled_disp, depth_m = disp_to_depth(sig, 0.1, 10.0)
    summary(out, "disp_to_depth.disp", scaled_disp, samples=11)
    summary(out, "disp_to_depth.depth", depth_m, samples=11)
    out["sigmoid_input_for_depth_2m"] = sigmoid_input_for_depth(2.0, 0.1, 10.0)
    depth_s = depth.clone()
    depth_s[:, :, 4:9, 5:12] *= 0.6  # a nearer object in the source hides part of the target
    depth_s[:, :, 0, :] = 0.0  # invalid source depth
    small = pose_from_params(0.1 * aa, 0.1 * t)
    occ = occlusion_by_depth(depth, depth_s, K, small)
    checksum(out, "occlusion", occ)
    return out


# ---- flow losses ---------------------------------------------------------------------------------------


def _flow_scene():
    """Two 64×64 frames, forward/backward five-level flows (finest first), keypoints of both frames."""
    from f2depth.flow.patch_loss import pad_keypoints
    from f2depth.geometry import resize_flow, warp

    g = torch.Generator().manual_seed(13)
    b, h, w = 2, 64, 64
    img1 = smooth(g, (b, 3, h, w), (9, 9), texture=0.15)
    fw = 6.0 * (smooth(g, (b, 2, h, w), (3, 3), texture=0.0) - 0.5)
    fw[:, 0] += 1.5
    bw = -fw.clone()
    bw[:, :, 20:34, 40:56] += 7.0  # inconsistent: the forward–backward check marks it occluded
    img2 = (warp(img1, bw) + 0.02 * torch.rand(b, 3, h, w, generator=g, dtype=torch.float64)).clamp(0, 1)
    sizes = [(h // 2**i, w // 2**i) for i in range(5)]
    fws = [resize_flow(fw, s).detach().requires_grad_() for s in sizes]
    bws = [resize_flow(bw, s).detach().requires_grad_() for s in sizes]
    kps = []
    for n in (30, 12, 25, 0):  # frame 1 of image 0, of image 1, frame 2 of image 0, of image 1
        kp = torch.stack([torch.randint(0, w, (n,), generator=g), torch.randint(0, h, (n,), generator=g)], -1)
        if n >= 4:
            kp[:4] = torch.tensor([[0, 0], [w - 1, h - 1], [1, 30], [10, 11]])
            kp[4] = kp[3]  # a duplicate keypoint counts once
        kps.append(kp)
    kp, mask = pad_keypoints(kps)
    keypoints = kp.view(2, b, -1, 2).transpose(0, 1).contiguous()
    keypoint_mask = mask.view(2, b, -1).transpose(0, 1).contiguous()
    return {"img1": img1, "img2": img2, "fws": fws, "bws": bws, "keypoints": keypoints,
            "keypoint_mask": keypoint_mask}


def flow_losses() -> Values:
    """ARFlow's loss (SINTEL_RAW, SINTEL_FT), its parts, census, the patch loss and ``batch_loss``."""
    from f2depth.flow.census import census_distance, ternary_transform
    from f2depth.flow.finetune import batch_loss
    from f2depth.flow.loss import (
        SINTEL_FT,
        SINTEL_RAW,
        flow_loss,
        non_occluded_by_consistency,
        non_occluded_by_range,
        range_map,
        smoothness,
        ssim_loss,
    )
    from f2depth.flow.patch_loss import FinetuneLossConfig, finetune_loss

    s = _flow_scene()
    img1, img2, fws, bws = s["img1"], s["img2"], s["fws"], s["bws"]
    out: Values = {}
    for name, cfg in {"sintel_raw": SINTEL_RAW, "sintel_ft": SINTEL_FT}.items():
        loss, stats = flow_loss(fws, bws, img1, img2, cfg)
        put(out, name, stats)
        _grad(out, name, loss, [fws[0], fws[1], bws[0]])
    summary(out, "census", census_distance(img1, img2))
    summary(out, "ternary", ternary_transform(img1))
    summary(out, "arflow_ssim", ssim_loss(img1, img2))
    out["smooth_1st"] = _f(smoothness(fws[0] / 64.0, img1, 10.0, False))
    out["smooth_2nd"] = _f(smoothness(fws[0] / 64.0, img1, 10.0, True))
    summary(out, "range_map", range_map(fws[0].detach()))
    f12, f21 = fws[0].detach(), bws[0].detach()
    masks_by_check = {"noc_range": non_occluded_by_range(f12, f21, 0.2),
                      "noc_fb": non_occluded_by_consistency(f12, f21, 0.01, 0.5)}
    for name, masks in masks_by_check.items():
        out[f"{name}.frame1"], out[f"{name}.frame2"] = float(masks[0].sum()), float(masks[1].sum())

    kp, km = s["keypoints"], s["keypoint_mask"]
    for occlusion in ("forward_backward", "range_map"):
        for tag, w_scales, backward in (("finest", (1.0,), False),
                                        ("arflow", (1.0, 1.0, 1.0, 1.0, 0.0), True)):
            cfg = FinetuneLossConfig(spacing=2, w_scales=w_scales, backward=backward, smooth_weight=50.0,
                                     occlusion=occlusion)
            loss, stats = finetune_loss(fws, bws, img1, img2, kp, km, cfg)
            put(out, f"patch_{tag}_{occlusion}", stats)
            _grad(out, f"patch_{tag}_{occlusion}", loss, [fws[0], fws[2], bws[0]])
    single = FinetuneLossConfig(spacing=3, w_scales=(1.0,), backward=False, smooth_weight=50.0,
                                occlusion="forward_backward")
    _, stats = finetune_loss(fws[0], bws[0], img1, img2, kp[:, 0], km[:, 0], single)
    put(out, "patch_single_spacing3", stats)

    for loss_name in ("patch", "full"):
        cfg = _finetune_config(loss_name)
        loss, stats = batch_loss(fws, bws, img1, img2, kp, km, cfg)
        put(out, f"batch_{loss_name}", stats)
        _grad(out, f"batch_{loss_name}", loss, [fws[0], bws[0]])
    return out


def _finetune_config(loss: str):
    from f2depth.flow.finetune import FinetuneConfig

    """As the flow_finetune stage builds it, with params.yaml's values (weight decay: the library's)."""
    return FinetuneConfig(loss=loss, epochs=1, batch_size=2, lr=5e-5, patch_spacing=2,
                          w_scales=(1.0, 1.0, 1.0, 1.0, 0.0), backward=True, smooth_weight=50.0, augment=True,
                          amp=False, seed=0, occlusion="range_map")


# ---- metrics -------------------------------------------------------------------------------------------


def metrics() -> Values:
    """Per-image metrics, median scaling, clipping, aggregation, flip post-processing, EPE."""
    from f2depth.colour import flow_to_color
    from f2depth.depth.predict import (
        depth_from_disparity,
        flip_post_process,
        pp_weights,
        predict_disparity,
        resize_disparity,
    )
    from f2depth.flow.evaluation import (
        EPEAccumulator,
        epe_stats,
        gradient_energy,
        low_texture_mask,
    )
    from f2depth.protocols.metrics import (
        aggregate,
        clip_depth,
        compute_errors,
        image_metrics,
        mean_of_rows,
        median_scale,
    )

    rng = np.random.default_rng(14)
    out: Values = {}
    gt = rng.uniform(0.5, 9.0, (30, 40))
    pred = gt * rng.uniform(0.4, 2.4, gt.shape) * 0.37  # wrong scale, errors around every δ threshold
    gt[:3, :5] = 0.0  # invalid pixels
    valid = gt > 0
    put(out, "compute_errors", compute_errors(gt[valid], np.clip(pred[valid] / 0.37, 0.1, 10.0)))
    on_edges = np.array([2.5, 3.125, 3.90625, 2.0, 2.0])  # ratios exactly 1.25, 1.25², 1.25³ (binary-exact)
    put(out, "compute_errors_on_thresholds", compute_errors(on_edges, np.array([2.0, 2.0, 2.0, 2.5, 3.125])))
    m, ratio = image_metrics(gt, pred, median_scaling=True, min_depth=0.1, max_depth=10.0)
    put(out, "image_median", {**m, "ratio": ratio})
    m, _ = image_metrics(gt, pred / 0.37, median_scaling=False, min_depth=0.1, max_depth=10.0)
    put(out, "image_unscaled", m)
    mask = np.zeros_like(gt, dtype=bool)
    mask[5:25, 10:30] = True
    m, ratio = image_metrics(gt, pred * 20.0, mask, median_scaling=True, min_depth=0.5, max_depth=6.0)
    put(out, "image_masked_clipped", {**m, "ratio": ratio})
    scaled, ratio = median_scale(np.arange(1.0, 11.0), np.arange(2.0, 31.0, 3.0))  # even counts
    out["median_scale.ratio"] = ratio
    out["median_scale.sum"] = float(scaled.sum())
    out["clip.sum"] = float(clip_depth(np.array([0.01, 0.5, 12.0, 3.0]), 0.1, 10.0).sum())
    records = [compute_errors(gt[valid] + 0.1 * k, np.clip(pred[valid] / 0.37, 0.1, 10.0)) for k in range(3)]
    agg = aggregate(records)
    put(out, "aggregate_mean", agg.mean)
    put(out, "aggregate_std", agg.std)
    put(out, "mean_of_rows", mean_of_rows(records))

    disp = rng.uniform(0.05, 1.0, (2, 1, 6, 10))
    disp[0, 0, 0, 0] = 0.0
    depth = depth_from_disparity(disp).ravel()
    out["depth_from_disparity.at_zero"] = float(depth[0])
    summary(out, "depth_from_disparity", depth[1:])
    t_disp = torch.from_numpy(disp)
    summary(out, "resize_nearest", resize_disparity(t_disp, (9, 25), "nearest"))
    summary(out, "resize_bilinear", resize_disparity(t_disp, (9, 25), "bilinear"))
    l_mask, r_mask = pp_weights(4, 41)
    summary(out, "pp_l_mask", l_mask[0], samples=6)
    summary(out, "pp_r_mask", r_mask[0], samples=6)
    other = rng.uniform(0.05, 1.0, disp.shape)
    summary(out, "flip_pp_numpy", flip_post_process(disp[0, 0], other[0, 0]), samples=8)
    summary(out, "flip_pp_torch", flip_post_process(t_disp, torch.from_numpy(other)), samples=8)

    def predict(x: torch.Tensor) -> torch.Tensor:  # not mirror-symmetric, so the flip matters
        ramp = torch.linspace(0.2, 1.0, x.shape[-1], dtype=x.dtype)
        return 0.1 + x.mean(1, keepdim=True) * ramp

    img = torch.from_numpy(rng.uniform(0, 1, (2, 3, 8, 12)))
    summary(out, "predict_pp", predict_disparity(predict, img, post_process=True, out_hw=(16, 20),
                                                 upsample="bilinear"), samples=8)
    summary(out, "predict_plain", predict_disparity(predict, img, post_process=False, out_hw=(16, 20),
                                                    upsample="nearest"), samples=8)

    g = torch.Generator().manual_seed(15)
    image = smooth(g, (2, 3, 32, 40), (4, 4), texture=0.0).float()
    image[:, :, 10:20, 10:20] += 0.3 * torch.rand(2, 3, 10, 10, generator=g)
    gt_flow = (8.0 * (smooth(g, (2, 2, 32, 40), (3, 3), texture=0.0) - 0.5)).float()
    flow = gt_flow + (torch.rand(2, 2, 32, 40, generator=g) - 0.5)
    flow[:, :, :4] = 0.0  # zero-length predictions (cosine 0)
    occluded = torch.zeros(2, 1, 32, 40, dtype=torch.bool)
    occluded[:, :, :, :6] = True
    flow_valid = torch.ones_like(occluded)
    flow_valid[0, :, -2:] = False
    low = low_texture_mask(image)
    out["low_texture.sum"] = float(low.sum())
    summary(out, "gradient_energy", gradient_energy(image))
    put(out, "epe_stats", epe_stats(flow, gt_flow, occluded, low, flow_valid))
    acc = EPEAccumulator()
    acc.add(flow[:1], gt_flow[:1], occluded[:1], low[:1])
    acc.add(flow[1:] * 0.5, gt_flow[1:], occluded[1:], low[1:], flow_valid[1:])
    put(out, "epe_accumulated", acc.result())
    checksum(out, "flow_to_color", flow_to_color(flow[0].numpy()))
    return out


# ---- one depth training step ----------------------------------------------------------------------------


def _model_values(out: Values, prefix: str, model: torch.nn.Module) -> None:
    """Per parameter: sum and |·| sum of the weights and of their gradients; BatchNorm statistics' sums."""
    for name, p in model.named_parameters():
        a = p.detach().double()
        out[f"{prefix}.w.{name}.sum"] = float(a.sum())
        out[f"{prefix}.w.{name}.abs_sum"] = float(a.abs().sum())
        if p.grad is not None:
            gr = p.grad.detach().double()
            out[f"{prefix}.g.{name}.sum"] = float(gr.sum())
            out[f"{prefix}.g.{name}.abs_sum"] = float(gr.abs().sum())
    for name, buf in model.named_buffers():
        if buf.is_floating_point():
            out[f"{prefix}.b.{name}.sum"] = float(buf.double().sum())


def _batch_values(out: Values, prefix: str, batch: Mapping[str, torch.Tensor]) -> None:
    for key in sorted(batch):
        v = batch[key]
        if v.is_floating_point():
            out[f"{prefix}.{key}.sum"] = float(v.double().sum())
            out[f"{prefix}.{key}.abs_sum"] = float(v.double().abs().sum())
        else:
            checksum(out, f"{prefix}.{key}", v)


def depth_train_step() -> Values:
    """One ``train_step`` of a seeded 64×64 DepthModel on a tiny prepared set: the ``full`` variant (random
    PWC-Lite teacher) and the ``baseline`` (no teacher, no flow terms); the batch (data pipeline and
    augmentation), the superpixel area threshold and the learning-rate schedule."""
    from torch.utils.data import default_collate

    from f2depth.depth import DepthModel, DepthModelConfig
    from f2depth.flow import PWCLite
    from f2depth.superpixels import scaled_min_area
    from f2depth.train.data import DataConfig, TupleDataset
    from f2depth.train.schedule import LRSchedule
    from f2depth.train.step import TERMS, StepConfig, train_step
    from f2depth.train.teacher import FlowTeacher

    out: Values = {}
    with tempfile.TemporaryDirectory() as tmp:
        prep = train_fakes.write_prepared(Path(tmp) / "prepared", hw=(64, 64), scenes=1, frames=4, seed=3)
        ds = TupleDataset(prep, Path(tmp) / "keypoints" / "train.npz",
                          DataConfig(num_points=64, augment=True), seed=0)
        batch = default_collate([ds.item(i, DEPTH_EPOCH) for i in range(2)])
    _batch_values(out, "batch", batch)
    out["scaled_min_area_64x64"] = scaled_min_area(64, 64)
    for epochs in (44, 8, 3):
        schedule = LRSchedule.scaled([1e-4, 1e-5, 1e-6], [27, 15, 2], epochs)
        for e in range(epochs):
            out[f"lr_{epochs}_epochs.{e}"] = schedule.lr(e)
    variants = {
        # every term of the step by name (a term added later: logged with weight 0, the store rewritten)
        "full": ({**dict.fromkeys(TERMS, 0.0), "smooth": 0.001, "planar": 0.05, "rigid": 1.0, "feature": 3.0},
                 True),
        "baseline": ({**dict.fromkeys(TERMS, 0.0), "smooth": 0.001, "planar": 0.05}, False),
    }
    for name, (weights, with_teacher) in variants.items():
        torch.manual_seed(100)
        teacher = FlowTeacher(PWCLite()) if with_teacher else None
        torch.manual_seed(0)
        model = DepthModel(DepthModelConfig(height=64, width=64))
        model.train()
        optimizer = torch.optim.Adam(model.parameters(), lr=1e-4)
        config = StepConfig(weights=weights, min_area=scaled_min_area(64, 64), amp=False)
        loss, logs = train_step(model, optimizer, batch, teacher, config)
        put(out, f"{name}.log", stored_terms(logs))
        out[f"{name}.loss"] = float(loss)
        _model_values(out, name, model)
    return out


#: The epoch whose draws the depth batch uses: item 0 flipped without jitter, item 1 jittered, not flipped.
DEPTH_EPOCH = 1


# ---- one flow fine-tuning step --------------------------------------------------------------------------


def flow_finetune_step() -> Values:
    """One fine-tuning ``train_step`` of a seeded random PWC-Lite in float64, ``patch`` and ``full``."""
    from f2depth.epochs import epoch_generator
    from f2depth.flow import PWCLite
    from f2depth.flow.finetune import make_optimizer, prepare_batch, train_step
    from f2depth.flow.finetune_data import FlowPairs, collate
    from f2depth.formats.prepared import PreparedSet
    from f2depth.keypoints import KeypointFile

    out: Values = {}
    with tempfile.TemporaryDirectory() as tmp:
        prep = train_fakes.write_prepared(Path(tmp) / "prepared", hw=(64, 64), scenes=1, frames=4, seed=4)
        ds = PreparedSet(prep)
        items = FlowPairs(ds, ds.pairs[:2], KeypointFile(Path(tmp) / "keypoints" / "train.npz"))
        raw = collate([items[0], items[1]])
    for name in ("patch", "full"):
        cfg = _finetune_config(name)
        batch = prepare_batch(raw, cfg, epoch_generator(cfg.seed, FLOW_EPOCH))
        batch = {k: v.double() if v.is_floating_point() else v for k, v in batch.items()}
        if name == "patch":
            _batch_values(out, "batch", batch)
        torch.manual_seed(1)
        model = PWCLite().double()
        model.train()
        stats = train_step(model, make_optimizer(model, cfg), batch, cfg)
        put(out, f"{name}.stats", stats or {})
        _model_values(out, name, model)
    return out


#: The (1-based) epoch whose draws the flow batch uses: pair 1 flipped, pair 0 jittered.
FLOW_EPOCH = 2


# ---- one evaluation ------------------------------------------------------------------------------------


def evaluation() -> Values:
    """NYU, 7-Scenes and Campus protocols with a seeded 64×96 DepthModel on the fakes, ± post-processing,
    and the evaluation suite's headline (the numbers of metrics/evaluate/<variant>.json)."""
    from f2depth.depth import DepthModel, DepthModelConfig
    from f2depth.eval.suite import DATASETS, SuiteConfig, evaluate_model, model_disparity
    from f2depth.eval.suite import GROUPS as GROUPS_OF_HEADLINE
    from f2depth.formats.campus import CampusSet
    from f2depth.formats.nyu_labeled import NYULabeledSet
    from f2depth.formats.sevenscenes import SevenScenesSet
    from f2depth.protocols.campus import PROTOCOL as CAMPUS
    from f2depth.protocols.metrics import METRIC_NAMES
    from f2depth.protocols.nyu import PROTOCOL as NYU
    from f2depth.protocols.sevenscenes import PROTOCOL as SEVENSCENES

    torch.manual_seed(7)
    # trained with nearest upsampling, evaluated with the decoder rebuilt bilinear (evaluate.decoder_upsample)
    model = DepthModel(DepthModelConfig(height=64, width=96, upsample_mode="bilinear")).eval()
    predict = model_disparity(model)
    common = {"height": 64, "width": 96, "interpolation": "lanczos", "device": "cpu"}  # as the suite passes
    out: Values = {}
    with tempfile.TemporaryDirectory() as tmp, torch.no_grad():
        root = Path(tmp)
        fakes.write_labeled_mat(root / "nyu" / "labeled.mat", ["bedroom_0001", "office_0002", "kitchen_0003",
                                                                "office_0004"], seed=5)
        fakes.write_splits(root / "nyu" / "splits.mat", [4], [1, 2, 3])
        # fire has twice chess's test frames: the scene average and the frame-weighted mean differ
        fakes.write_sevenscenes(root / "7scenes", {"chess": ([1], [2]), "fire": ([2, 3], [1])}, frames=2,
                                seed=6)
        fakes.write_campus(root / "campus", {"1": 2, "2": 1}, points_per_image=5, seed=7)
        mat, splits = root / "nyu" / "labeled.mat", root / "nyu" / "splits.mat"
        nyu = NYULabeledSet(mat, splits, "test", "depths")
        seven = SevenScenesSet(root / "7scenes", split="test", stride=1)
        campus = CampusSet(root / "campus")
        for pp in (False, True):
            tag = "_pp" if pp else ""
            r = NYU.evaluate(nyu, predict, crop="eigen", upsample="nearest", post_process=pp, batch_size=2,
                             **common)
            put(out, f"nyu{tag}.mean", r.summary.mean)
            put(out, f"nyu{tag}.std", r.summary.std)
            for (i,), ratio in zip(r.keys, r.per_image["ratio"]):
                out[f"nyu{tag}.ratio{int(i)}"] = float(ratio)
            r = SEVENSCENES.evaluate(seven, predict, upsample="nearest", post_process=pp, batch_size=2,
                                     **common)
            put(out, f"sevenscenes{tag}.frames", r.summary.mean)
            put(out, f"sevenscenes{tag}.average", r.average)
            for scene, summ in r.scenes.items():
                out[f"sevenscenes{tag}.{scene}.abs_rel"] = summ.mean["abs_rel"]
            r = CAMPUS.evaluate(campus, predict, post_process=pp, **common)
            put(out, f"campus{tag}.average", r.average)
            put(out, f"campus{tag}.images", r.summary.mean)
            put(out, f"campus{tag}.pooled", r.pooled)
        # the headline the evaluate stage writes (which summary row of each protocol; timing left out)
        suite = SuiteConfig(height=None, width=None, nyu_crop="eigen", interpolation="lanczos",
                            upsample="nearest", decoder_upsample="bilinear", batch_size=2, device="cpu",
                            datasets=DATASETS, timing_height=64, timing_width=64, timing_repeats=1,
                            timing_warmup=0, figure_images=0)
        headline = evaluate_model(predict, {"nyu": nyu, "sevenscenes": seven, "campus": campus}, suite,
                                  (64, 96)).headline
        nyu.close()
        for group in GROUPS_OF_HEADLINE:
            put(out, f"headline.{group}", headline[group])
    missing = [f"headline.{g}.{m}" for g in GROUPS_OF_HEADLINE for m in METRIC_NAMES
               if f"headline.{g}.{m}" not in out]
    if missing:
        raise AssertionError(f"evaluation: metrics missing from the results: {missing}")
    return out


# ---- keypoints and prepare -----------------------------------------------------------------------------


def keypoints_prepare() -> Values:
    """DSO's selector (``dso`` and ``p2net`` presets) on one synthetic image; ``prepare`` on a raw scene."""
    from f2depth.data.prepare import PrepareConfig, SuperpixelParams, prepare
    from f2depth.formats.prepared import PreparedSet
    from f2depth.keypoints import fill_up, select_pixels

    out: Values = {}
    rng = np.random.default_rng(16)
    base = fakes.blocky_image((240, 320), seed=16, blocks=7).astype(np.float32)
    texture = cv2.GaussianBlur(rng.normal(0, 25, (240, 320)).astype(np.float32), (0, 0), 1.2)
    gray = np.clip(cv2.cvtColor(base.astype(np.uint8), cv2.COLOR_RGB2GRAY) + texture, 0, 255).astype(np.uint8)
    gray[:60, :80] = 128  # a flat corner
    for preset in ("dso", "p2net"):
        pts = select_pixels(gray, preset)
        checksum(out, f"{preset}.x", pts[:, 0])
        checksum(out, f"{preset}.y", pts[:, 1])
        checksum(out, f"{preset}.level", pts[:, 2])
    pts = select_pixels(gray, "dso", out_hw=(96, 128), density=500)
    checksum(out, "dso_500_at_96x128.xy", pts[:, :2])
    xy, real = fill_up(pts[:20], 50, 96, 128, torch.Generator().manual_seed(17))
    checksum(out, "fill_up.xy", xy)
    out["fill_up.real"] = float(real.sum())

    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        scene = "office_0001"
        fakes.write_nyu_raw(root / "raw", {scene: 3}, seed=18, gt_root=root / "gt")
        (root / "scenes.txt").write_text(f"{scene}\n")
        config = PrepareConfig(height=48, width=64, frame_step=1, crop=16, p2net_cxcy_bug=False,
                               superpixels=SuperpixelParams(scale=100.0, sigma=0.5, min_size=50), workers=1,
                               interpolation="lanczos")
        stats = prepare(root / "raw", root / "none.mat", root / "none_splits.mat", root / "prepared", config,
                        synth_gt=root / "gt", train_scenes_file=root / "scenes.txt", progress=False)
        put(out, "prepare", {k: v for k, v in stats.items() if k != "seconds"})
        ds = PreparedSet(root / "prepared")
        summary(out, "prepare.K", ds.K, samples=9)
        for i, frame in enumerate(ds.frames):
            checksum(out, f"prepare.image{i}", ds.image(frame.frame_id))
            depth, pose = ds.gt(frame.frame_id)
            summary(out, f"prepare.gt{i}.depth", depth)
            summary(out, f"prepare.gt{i}.pose", pose, samples=16)
        for t in ds.tuples:
            checksum(out, f"prepare.segments.{t.tuple_id}", ds.segments(t.tuple_id))
    return out


# ---- registry, store, comparison -----------------------------------------------------------------------

GROUPS: dict[str, Callable[[], Values]] = {
    "depth_losses": depth_losses,
    "geometry": geometry,
    "flow_losses": flow_losses,
    "metrics": metrics,
    "depth_train_step": depth_train_step,
    "flow_finetune_step": flow_finetune_step,
    "evaluation": evaluation,
    "keypoints_prepare": keypoints_prepare,
}


def compute(name: str) -> Values:
    """One group's values, computed single-threaded."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        values = GROUPS[name]()
    finally:
        torch.set_num_threads(threads)
    bad = [k for k, v in values.items() if not math.isfinite(v)]
    if bad:
        raise ValueError(f"characterization group {name}: non-finite values {bad[:5]}")
    return values


def load_store(path: Path = STORE) -> dict[str, Values]:
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no stored characterization values; run "
                                "`python tests/characterization.py --write` on the unchanged code")
    return json.loads(path.read_text())["groups"]


def compare(computed: Values, stored: Values, rtol: float | Callable[[str], float]) -> list[str]:
    """Differences as readable lines; empty when every key matches within tolerance.

    A key matches when ``|computed − stored| ≤ rtol·scale`` with ``scale = |stored|``, or for a ``….sum``
    key whose ``….abs_sum`` is stored too, the larger of the two (a sum of mixed signs may cancel to near
    0; its round-off follows the magnitude of the summands). ``rtol``: a number or a function of the key.
    """
    missing = sorted(set(stored) - set(computed))
    extra = sorted(set(computed) - set(stored))
    lines = []
    if missing or extra:
        lines.append(f"keys differ: missing (stored, not computed) {missing}; extra (computed, not stored) "
                     f"{extra}")
    for key in sorted(set(stored) & set(computed)):
        want, got = stored[key], computed[key]
        scale = abs(want)
        if key.endswith(".sum") and f"{key[:-4]}.abs_sum" in stored:
            scale = max(scale, abs(stored[f"{key[:-4]}.abs_sum"]))
        tol = rtol(key) if callable(rtol) else rtol
        if not abs(got - want) <= tol * scale:
            rel = abs(got - want) / scale if scale else math.inf
            lines.append(f"{key}: computed {got!r}, stored {want!r} (relative difference {rel:.3g})")
    return lines


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    mode = ap.add_mutually_exclusive_group(required=True)
    mode.add_argument("--write", action="store_true", help=f"recompute every group and rewrite {STORE.name}")
    mode.add_argument("--check", action="store_true", help="recompute and list differences (rtol 1e-6)")
    ap.add_argument("--groups", nargs="*", default=list(GROUPS), choices=list(GROUPS))
    args = ap.parse_args(argv[1:])
    if args.write:
        groups = {name: compute(name) for name in GROUPS}
        doc = {"about": "f2depth characterization values (tests/characterization.py); rewrite only for an "
                        "intended change of behaviour and say so in the commit message",
               "torch": torch.__version__, "numpy": np.__version__, "groups": groups}
        STORE.parent.mkdir(parents=True, exist_ok=True)
        STORE.write_text(json.dumps(doc, indent=1, sort_keys=False) + "\n")
        sys.stdout.write(f"{STORE}: {sum(len(v) for v in groups.values())} values in {len(groups)} groups\n")
        return 0
    stored = load_store()
    failed = 0
    for name in args.groups:
        lines = compare(compute(name), stored.get(name, {}), rtol=1e-6)
        sys.stdout.write(f"{name}: {'OK' if not lines else f'{len(lines)} difference(s)'}\n")
        sys.stdout.writelines(f"  {line}\n" for line in lines[:20])
        failed += bool(lines)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
