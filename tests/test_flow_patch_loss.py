"""F²Depth's patch census loss (f2depth.flow.patch_loss) and its `full` variant."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
import torch

from f2depth.flow.census import census_distance
from f2depth.flow.loss import non_occluded_by_consistency
from f2depth.flow.patch_loss import (
    FinetuneLossConfig,
    census_at,
    finetune_loss,
    interior_pixels,
    pad_keypoints,
    patch_offsets,
    patch_pixels,
)
from f2depth.flow.warp import warp

H, W = 40, 56


def texture(seed: int, b: int = 1, hw: tuple[int, int] = (H, W)) -> torch.Tensor:
    """Smooth random colour texture ``(b,3,H,W)`` in [0,1] (a few grey levels per pixel of gradient)."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(b):
        noise = rng.uniform(0, 255, (hw[0], hw[1], 3)).astype(np.float32)
        out.append(np.clip(cv2.GaussianBlur(noise, (0, 0), 1.5) * 2.5 - 190, 0, 255) / 255.0)
    return torch.from_numpy(np.stack(out)).permute(0, 3, 1, 2).float()


def smooth_flow(b: int = 1) -> torch.Tensor:
    """A smooth, non-constant flow field ``(b,2,H,W)`` of 1–3 px."""
    y, x = torch.meshgrid(torch.arange(H, dtype=torch.float32), torch.arange(W, dtype=torch.float32),
                          indexing="ij")
    u = 1.5 + 0.8 * torch.sin(x / 9.0) * torch.cos(y / 11.0)
    v = -0.7 + 0.5 * torch.cos(x / 13.0)
    return torch.stack([u, v])[None].repeat(b, 1, 1, 1)


def grid_keypoints(b: int = 1, step: int = 9) -> tuple[torch.Tensor, torch.Tensor]:
    pts = torch.tensor([(x, y) for y in range(4, H - 4, step) for x in range(4, W - 4, step)])
    return pad_keypoints([pts] * b)


def loss_of(flow, img1, img2, kp=None, mask=None, **cfg):
    return finetune_loss(flow, -flow, img1, img2, kp, mask, FinetuneLossConfig(**cfg))


def test_n2_pattern_is_the_papers():
    off = patch_offsets(2)
    assert {tuple(o) for o in off.tolist()} == {(i, j) for i in (-2, 0, 2) for j in (-2, 0, 2)}
    assert off.shape == (9, 2) and off[4].tolist() == [0, 0]
    kp, mask = pad_keypoints([torch.tensor([[20, 15]])])
    idx, valid = patch_pixels(kp, mask, H, W, spacing=2)
    got = {(int(i) % W, int(i) // W) for i in idx[0][valid[0]]}
    assert got == {(20 + i, 15 + j) for i in (-2, 0, 2) for j in (-2, 0, 2)}
    idx, valid = patch_pixels(kp, mask, H, W, spacing=3)
    assert {(int(i) % W, int(i) // W) for i in idx[0][valid[0]]} == {(20 + i, 15 + j) for i in (-3, 0, 3)
                                                                     for j in (-3, 0, 3)}


def test_patch_pixels_union_inside_image_and_mask():
    kp, mask = pad_keypoints([torch.tensor([[10, 10], [10, 10], [12, 10], [0, 0], [W - 1, H - 1]]),
                              torch.zeros(0, 2, dtype=torch.int64)])
    assert kp.shape == (2, 5, 2) and mask.sum(1).tolist() == [5, 0]
    idx, valid = patch_pixels(kp, mask, H, W, spacing=2)
    pix = {(int(i) % W, int(i) // W) for i in idx[0][valid[0]]}
    expect = {(x + i, y + j) for x, y in ((10, 10), (12, 10)) for i in (-2, 0, 2) for j in (-2, 0, 2)}
    expect |= {(2, 2), (W - 3, H - 3)}  # the corner keypoints keep only their patch pixels off the border
    assert pix == expect and int(valid[0].sum()) == len(expect)  # duplicates and overlaps counted once
    assert not valid[1].any()


def test_census_equals_arflow_for_constant_flow():
    img1, img2 = texture(0, 2), texture(1, 2)
    flow = torch.zeros(2, 2, H, W)
    flow[:, 0], flow[:, 1] = 1.3, -0.6
    idx, _ = interior_pixels(2, H, W)
    ours = census_at(img1, img2, flow, idx).reshape(2, H, W)
    arflow = census_distance(img1, warp(img2, flow))[:, 0]
    assert torch.allclose(ours[:, 1:-1, 1:-1], arflow[:, 1:-1, 1:-1], atol=1e-5)


@pytest.mark.parametrize("pixels", ["patch", "full"])
def test_true_flow_beats_perturbed(pixels):
    img2 = texture(3, 2)
    flow = smooth_flow(2)
    img1 = warp(img2, flow)  # the target is the source seen through the known flow
    kp, mask = grid_keypoints(2)
    gen = torch.Generator().manual_seed(0)
    loss_true, st_true = loss_of(flow, img1, img2, kp, mask, pixels=pixels)
    for delta in (torch.full_like(flow, 1.0), 1.0 * torch.randn(flow.shape, generator=gen)):
        loss_bad, st_bad = loss_of(flow + delta, img1, img2, kp, mask, pixels=pixels)
        assert loss_true < loss_bad
        assert st_true["photometric"] < 0.5 * st_bad["photometric"]
    assert st_true["noc_fraction"] > 0.9  # only pixels whose flow leaves the image fail the check


def test_gradient_only_at_patch_pixels():
    img1, img2 = texture(4, 2), texture(5, 2)
    flow = (smooth_flow(2) + 0.3 * torch.randn(2, 2, H, W, generator=torch.Generator().manual_seed(1)))
    flow.requires_grad_(True)
    kp, mask = pad_keypoints([torch.tensor([[10, 10], [30, 20], [50, 33]]), torch.tensor([[25, 25]])])
    loss, _ = finetune_loss(flow, -flow.detach(), img1, img2, kp, mask, FinetuneLossConfig(smooth_weight=0.0))
    loss.backward()
    touched = flow.grad.abs().sum(1) > 0                                    # (B,H,W)
    in_patch = torch.zeros(2, H * W, dtype=torch.bool)
    idx, valid = patch_pixels(kp, mask, H, W)
    in_patch.scatter_(1, idx, valid)
    in_patch = in_patch.view(2, H, W)
    noc, _ = non_occluded_by_consistency(flow.detach(), -flow.detach())
    assert not (touched & ~in_patch).any()
    assert torch.equal(touched, in_patch & (noc[:, 0] > 0))               # every visible patch pixel counts
    assert touched.sum() > 20


def test_full_variant_uses_every_interior_pixel():
    img1, img2 = texture(6), texture(7)
    flow = smooth_flow().requires_grad_(True)
    cfg = FinetuneLossConfig("full", smooth_weight=0)
    loss, stats = finetune_loss(flow, -flow.detach(), img1, img2, cfg=cfg)
    loss.backward()
    touched = flow.grad.abs().sum(1)[0] > 0
    assert stats["pixels"] == (H - 2) * (W - 2) and touched[1:-1, 1:-1].float().mean() > 0.95
    assert not touched[0].any() and not touched[:, -1].any()


def test_zero_keypoints_contribute_nothing_and_never_nan():
    img1, img2 = texture(8, 2), texture(9, 2)
    flow = smooth_flow(2).requires_grad_(True)
    pts = torch.tensor([[12, 12], [30, 20]])
    kp, mask = pad_keypoints([torch.zeros(0, 2, dtype=torch.int64), pts])
    cfg = FinetuneLossConfig(smooth_weight=0.0)
    loss, stats = finetune_loss(flow, -flow.detach(), img1, img2, kp, mask, cfg)
    loss.backward()
    assert flow.grad[0].abs().sum() == 0 and flow.grad[1].abs().sum() > 0
    kp1, mask1 = pad_keypoints([pts])
    alone, _ = finetune_loss(flow[1:], -flow[1:].detach(), img1[1:], img2[1:], kp1, mask1, cfg)
    assert torch.allclose(loss, alone)
    # no keypoints anywhere: photometric term exactly 0, finite loss and gradients
    kp0, mask0 = pad_keypoints([torch.zeros(0, 2), torch.zeros(0, 2)])
    flow.grad = None
    loss, stats = finetune_loss(flow, -flow.detach(), img1, img2, kp0, mask0)
    loss.backward()
    assert stats["photometric"] == 0.0 and stats["pixels"] == 0 and math.isfinite(stats["loss"])
    assert torch.isfinite(flow.grad).all()


@pytest.mark.parametrize("pixels", ["patch", "full"])
def test_all_occluded_is_finite(pixels):
    img1, img2 = texture(10), texture(11)
    flow = (torch.ones(1, 2, H, W) * 6.0).requires_grad_(True)
    kp, mask = grid_keypoints()
    # backward flow pointing the same way: the forward–backward check fails everywhere
    loss, stats = finetune_loss(flow, flow.detach(), img1, img2, kp, mask, FinetuneLossConfig(pixels))
    loss.backward()
    assert stats["noc_fraction"] == 0.0 and stats["used_pixels"] == 0 and stats["photometric"] == 0.0
    assert torch.isfinite(loss) and torch.isfinite(flow.grad).all()


def test_range_map_keeps_a_degenerate_flow_usable():
    """A constant flow predicted for both directions fails the forward–backward check everywhere; ARFlow's
    range map still finds the pixels visible."""
    img1, img2 = texture(14), texture(15)
    flow = torch.ones(1, 2, H, W)
    kp, mask = grid_keypoints()
    _, fb = finetune_loss(flow, flow, img1, img2, kp, mask)
    _, rm = finetune_loss(flow, flow, img1, img2, kp, mask, FinetuneLossConfig(occlusion="range_map"))
    assert fb["used_pixels"] == 0 and fb["photometric"] == 0
    assert rm["used_pixels"] > 0.9 * rm["pixels"] and rm["photometric"] > 0


def test_patch_loss_is_the_mean_over_the_union():
    img1, img2 = texture(12), texture(13)
    flow = smooth_flow()
    kp, mask = pad_keypoints([torch.tensor([[10, 10], [12, 10], [12, 10]])])
    _, stats = loss_of(flow, img1, img2, kp, mask, smooth_weight=0.0)
    union = sorted({(y * W + x) for cx, cy in ((10, 10), (12, 10)) for x in (cx - 2, cx, cx + 2)
                    for y in (cy - 2, cy, cy + 2)})
    expect = census_at(img1, img2, flow, torch.tensor([union])).mean()
    assert stats["pixels"] == len(union) == 12  # x in {8, 10, 12, 14}, y in {8, 10, 12}
    assert stats["photometric"] == pytest.approx(float(expect), rel=1e-5)


def test_bad_config_and_missing_keypoints():
    with pytest.raises(ValueError, match="pixels must be one of"):
        FinetuneLossConfig("sparse")
    with pytest.raises(ValueError, match="occlusion must be one of"):
        FinetuneLossConfig(occlusion="none")
    img = texture(0)
    with pytest.raises(ValueError, match="needs keypoints"):
        finetune_loss(smooth_flow(), -smooth_flow(), img, img)
