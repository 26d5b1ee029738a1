"""F²Depth's patch census loss (f2depth.flow.patch_loss): patches, census, one scale and direction (today's
form, value pinned), and ARFlow's way (four scales, both directions)."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
import torch
import torch.nn.functional as F

from f2depth.flow.census import census_distance
from f2depth.flow.loss import non_occluded_by_consistency, smoothness
from f2depth.flow.patch_loss import (
    FinetuneLossConfig,
    census_at,
    finetune_loss,
    pad_keypoints,
    patch_indices,
)
from f2depth.geometry import patch_offsets, warp

#: the paper's equation as written: the finest forward flow, N = 2, λ = 50, the forward–backward check
PAPER_EQUATION = {"spacing": 2, "w_scales": (1.0,), "backward": False, "smooth_weight": 50.0,
                  "occlusion": "forward_backward"}


def patch_cfg(**changes) -> FinetuneLossConfig:
    """The patch loss's settings: the paper's equation with ``changes``."""
    return FinetuneLossConfig(**{**PAPER_EQUATION, **changes})

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
    return finetune_loss(flow, -flow, img1, img2, kp, mask, patch_cfg(**cfg))


def pyramid(flow: torch.Tensor, levels: int = 5) -> list[torch.Tensor]:
    """Finest first, level i area-resized to ``⌈H/2^i⌉ × ⌈W/2^i⌉`` and in pixels of its grid (PWC-Lite's)."""
    h, w = flow.shape[-2:]
    return [flow if i == 0 else F.interpolate(flow, size=(-(-h // 2**i), -(-w // 2**i)), mode="area") / 2**i
            for i in range(levels)]


def both_frames(kp1, m1, kp2, m2):
    """``(B,K,2)`` keypoints of frames 1 and 2 → ``(B,2,K,2)``, ``(B,2,K)`` (as the fine-tuning collates)."""
    k = max(kp1.shape[1], kp2.shape[1])
    kp = torch.zeros(kp1.shape[0], 2, k, 2, dtype=torch.int64)
    mask = torch.zeros(kp1.shape[0], 2, k, dtype=torch.bool)
    kp[:, 0, :kp1.shape[1]], kp[:, 1, :kp2.shape[1]] = kp1, kp2
    mask[:, 0, :m1.shape[1]], mask[:, 1, :m2.shape[1]] = m1, m2
    return kp, mask


ARFLOW_WAY = {"w_scales": (1.0, 1.0, 1.0, 1.0, 0.0), "backward": True}


def test_n2_pattern_is_the_papers():
    off = patch_offsets(2)
    assert {tuple(o) for o in off.tolist()} == {(i, j) for i in (-2, 0, 2) for j in (-2, 0, 2)}
    assert off.shape == (9, 2) and off[4].tolist() == [0, 0]
    kp, mask = pad_keypoints([torch.tensor([[20, 15]])])
    idx, valid = patch_indices(kp, mask, H, W, spacing=2)
    got = {(int(i) % W, int(i) // W) for i in idx[0][valid[0]]}
    assert got == {(20 + i, 15 + j) for i in (-2, 0, 2) for j in (-2, 0, 2)}
    idx, valid = patch_indices(kp, mask, H, W, spacing=3)
    assert {(int(i) % W, int(i) // W) for i in idx[0][valid[0]]} == {(20 + i, 15 + j) for i in (-3, 0, 3)
                                                                     for j in (-3, 0, 3)}


def test_patch_indices_union_inside_image_and_mask():
    kp, mask = pad_keypoints([torch.tensor([[10, 10], [10, 10], [12, 10], [0, 0], [W - 1, H - 1]]),
                              torch.zeros(0, 2, dtype=torch.int64)])
    assert kp.shape == (2, 5, 2) and mask.sum(1).tolist() == [5, 0]
    idx, valid = patch_indices(kp, mask, H, W, spacing=2)
    pix = {(int(i) % W, int(i) // W) for i in idx[0][valid[0]]}
    expect = {(x + i, y + j) for x, y in ((10, 10), (12, 10)) for i in (-2, 0, 2) for j in (-2, 0, 2)}
    expect |= {(2, 2), (W - 3, H - 3)}  # the corner keypoints keep only their patch pixels off the border
    assert pix == expect and int(valid[0].sum()) == len(expect)  # duplicates and overlaps counted once
    assert not valid[1].any()


def test_census_equals_arflow_for_constant_flow():
    img1, img2 = texture(0, 2), texture(1, 2)
    flow = torch.zeros(2, 2, H, W)
    flow[:, 0], flow[:, 1] = 1.3, -0.6
    idx = torch.arange(H * W).expand(2, -1)
    ours = census_at(img1, img2, flow, idx).reshape(2, H, W)
    arflow = census_distance(img1, warp(img2, flow))[:, 0]
    assert torch.allclose(ours[:, 1:-1, 1:-1], arflow[:, 1:-1, 1:-1], atol=1e-5)


@pytest.mark.parametrize("way", [{}, ARFLOW_WAY], ids=["finest_forward", "arflow_way"])
def test_true_flow_beats_perturbed(way):
    # texture at every scale (the 5×7 level 3 of `texture` is noise); the target is the source seen
    # through the known flow
    coarse = torch.rand(2, 3, H // 4, W // 4, generator=torch.Generator().manual_seed(3))
    img2 = F.interpolate(coarse, size=(H, W), mode="bicubic", align_corners=False).clamp(0, 1)
    flow = smooth_flow(2)
    img1 = warp(img2, flow)
    kp, mask = grid_keypoints(2)
    kp, mask = both_frames(kp, mask, kp, mask)
    gen = torch.Generator().manual_seed(0)

    def loss(f):
        return finetune_loss(pyramid(f), pyramid(-f), img1, img2, kp, mask, patch_cfg(**way))

    loss_true, st_true = loss(flow)
    # i.i.d. noise on the flow averages out in the coarser levels, so it costs less there than a shift
    for delta, ratio in ((torch.full_like(flow, 1.0), 0.5),
                         (1.0 * torch.randn(flow.shape, generator=gen), 0.75 if way else 0.5)):
        loss_bad, st_bad = loss(flow + delta)
        assert loss_true < loss_bad
        assert st_true["photometric"] < ratio * st_bad["photometric"]
    assert st_true["noc_fraction"] > 0.9  # only pixels whose flow leaves the image fail the check


def test_gradient_only_at_patch_indices():
    img1, img2 = texture(4, 2), texture(5, 2)
    flow = (smooth_flow(2) + 0.3 * torch.randn(2, 2, H, W, generator=torch.Generator().manual_seed(1)))
    flow.requires_grad_(True)
    kp, mask = pad_keypoints([torch.tensor([[10, 10], [30, 20], [50, 33]]), torch.tensor([[25, 25]])])
    loss, _ = finetune_loss(flow, -flow.detach(), img1, img2, kp, mask, patch_cfg(smooth_weight=0.0))
    loss.backward()
    touched = flow.grad.abs().sum(1) > 0                                    # (B,H,W)
    in_patch = torch.zeros(2, H * W, dtype=torch.bool)
    idx, valid = patch_indices(kp, mask, H, W)
    in_patch.scatter_(1, idx, valid)
    in_patch = in_patch.view(2, H, W)
    noc, _ = non_occluded_by_consistency(flow.detach(), -flow.detach())
    assert not (touched & ~in_patch).any()
    assert torch.equal(touched, in_patch & (noc[:, 0] > 0))               # every visible patch pixel counts
    assert touched.sum() > 20


def test_zero_keypoints_contribute_nothing_and_never_nan():
    img1, img2 = texture(8, 2), texture(9, 2)
    flow = smooth_flow(2).requires_grad_(True)
    pts = torch.tensor([[12, 12], [30, 20]])
    kp, mask = pad_keypoints([torch.zeros(0, 2, dtype=torch.int64), pts])
    cfg = patch_cfg(smooth_weight=0.0)
    loss, stats = finetune_loss(flow, -flow.detach(), img1, img2, kp, mask, cfg)
    loss.backward()
    assert flow.grad[0].abs().sum() == 0 and flow.grad[1].abs().sum() > 0
    kp1, mask1 = pad_keypoints([pts])
    alone, _ = finetune_loss(flow[1:], -flow[1:].detach(), img1[1:], img2[1:], kp1, mask1, cfg)
    assert torch.allclose(loss, alone)
    # no keypoints anywhere: photometric term exactly 0, finite loss and gradients
    kp0, mask0 = pad_keypoints([torch.zeros(0, 2), torch.zeros(0, 2)])
    flow.grad = None
    loss, stats = finetune_loss(flow, -flow.detach(), img1, img2, kp0, mask0, patch_cfg())
    loss.backward()
    assert stats["photometric"] == 0.0 and stats["pixels"] == 0 and math.isfinite(stats["loss"])
    assert torch.isfinite(flow.grad).all()


@pytest.mark.parametrize("way", [{}, ARFLOW_WAY], ids=["finest_forward", "arflow_way"])
def test_all_occluded_is_finite(way):
    img1, img2 = texture(10), texture(11)
    flow = (torch.ones(1, 2, H, W) * 6.0).requires_grad_(True)
    kp, mask = grid_keypoints()
    kp, mask = both_frames(kp, mask, kp, mask)
    # backward flow pointing the same way: the forward–backward check fails everywhere
    fw = [flow] + [f.detach() for f in pyramid(flow.detach())[1:]]
    loss, stats = finetune_loss(fw, pyramid(flow.detach()), img1, img2, kp, mask, patch_cfg(**way))
    loss.backward()
    assert stats["noc_fraction"] == 0.0 and stats["used_pixels"] == 0 and stats["photometric"] == 0.0
    assert torch.isfinite(loss) and torch.isfinite(flow.grad).all()


def test_range_map_keeps_a_degenerate_flow_usable():
    """A constant flow predicted for both directions fails the forward–backward check everywhere; ARFlow's
    range map still finds the pixels visible."""
    img1, img2 = texture(14), texture(15)
    flow = torch.ones(1, 2, H, W)
    kp, mask = grid_keypoints()
    _, fb = finetune_loss(flow, flow, img1, img2, kp, mask, patch_cfg())
    _, rm = finetune_loss(flow, flow, img1, img2, kp, mask, patch_cfg(occlusion="range_map"))
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


def test_bad_config_and_missing_inputs():
    with pytest.raises(ValueError, match="occlusion must be one of"):
        patch_cfg(occlusion="none")
    with pytest.raises(ValueError, match="w_scales"):
        patch_cfg(w_scales=(0.0, 0.0))
    img = texture(0)
    kp, mask = grid_keypoints()
    with pytest.raises(ValueError, match="needs the keypoints of frame 2"):
        finetune_loss(smooth_flow(), -smooth_flow(), img, img, kp, mask, patch_cfg(backward=True))
    with pytest.raises(ValueError, match="only 1 flow level"):
        finetune_loss(smooth_flow(), -smooth_flow(), img, img, kp, mask, patch_cfg(w_scales=(1, 1)))


def test_one_scale_forward_reproduces_the_previous_value():
    """`w_scales (1,)` without `backward` is the loss as it was before the multi-scale change (finest forward
    flow only): the numbers below were printed by that implementation (f2depth at commit c42919b,
    `finetune_loss(fw, bw, img1, img2, kp, mask, FinetuneLossConfig("patch", occlusion=...))`) on exactly
    this float64 input."""
    g = torch.Generator().manual_seed(0)
    img1, img2 = texture(20, 2).double(), texture(21, 2).double()
    fw = smooth_flow(2).double() + 0.3 * torch.randn(2, 2, H, W, generator=g, dtype=torch.float64)
    bw = -fw + 0.4 * torch.randn(2, 2, H, W, generator=g, dtype=torch.float64)
    kp, mask = pad_keypoints([torch.tensor([[10, 10], [12, 10], [30, 20], [50, 33], [0, 5]]),
                              torch.tensor([[25, 25], [7, 30]])])
    before = {"forward_backward": (0.5898089711680621, 0.45943007295120797, 18.5),
              "range_map": (0.6056611619937823, 0.4752822637769282, 25.0)}
    for occlusion, (total, photometric, used) in before.items():
        cfg = patch_cfg(w_scales=(1.0,), backward=False, occlusion=occlusion)
        loss, stats = finetune_loss(fw, bw, img1, img2, kp, mask, cfg)
        assert float(loss) == pytest.approx(total, abs=1e-12)
        assert stats["photometric"] == pytest.approx(photometric, abs=1e-12)
        assert stats["smooth"] == pytest.approx(0.002607577964337082, abs=1e-15)
        assert stats["used_pixels"] == used and stats["pixels"] == 25.5
        # the same through the five-level path with the coarser levels weighted 0
        five, _ = finetune_loss(pyramid(fw), pyramid(bw), img1, img2, kp, mask,
                                patch_cfg(w_scales=(1.0, 0.0, 0.0, 0.0, 0.0), occlusion=occlusion))
        assert float(five) == float(loss)


def test_patch_indices_map_to_coarser_levels():
    kp, mask = pad_keypoints([torch.tensor([[21, 15]])])

    def level(i):
        idx, valid = patch_indices(kp, mask, H, W, 2, level_hw=(H >> i, W >> i))
        return {(int(p) % (W >> i), int(p) // (W >> i)) for p in idx[0][valid[0]]}, int(valid.sum())

    assert level(0)[0] == {(21 + i, 15 + j) for i in (-2, 0, 2) for j in (-2, 0, 2)}
    # x {19, 21, 23} → ⌊x/2⌋ {9, 10, 11}; y {13, 15, 17} → {6, 7, 8}
    assert level(1) == ({(x, y) for x in (9, 10, 11) for y in (6, 7, 8)}, 9)
    # ⌊x/4⌋ {4, 5, 5}, ⌊y/4⌋ {3, 3, 4}: duplicates count once
    assert level(2) == ({(4, 3), (5, 3), (4, 4), (5, 4)}, 4)
    # ⌊x/8⌋ {2}, ⌊y/8⌋ {1, 2} on a 7×5 level
    assert level(3) == ({(2, 1), (2, 2)}, 2)
    # a patch pixel outside the input is dropped before mapping; the level's border afterwards
    edge, emask = pad_keypoints([torch.tensor([[1, 20]])])
    idx, valid = patch_indices(edge, emask, H, W, 2, level_hw=(H >> 1, W >> 1))
    assert {(int(p) % (W >> 1), int(p) // (W >> 1)) for p in idx[0][valid[0]]} == {(1, 9), (1, 10), (1, 11)}


def _dense_term(img_a, img_b, flow, noc, pixels):
    """Reference of one level and direction: ARFlow's dense census map of the warped frame, averaged over a
    dense mask = patch pixels × non-occluded (valid for constant flows, where the windows agree)."""
    h, w = flow.shape[-2:]
    m = torch.zeros(1, 1, h, w, dtype=img_a.dtype)
    for x, y in pixels:
        if 1 <= x <= w - 2 and 1 <= y <= h - 2:
            m[0, 0, y, x] = 1
    m = m * noc
    d = census_distance(img_a, warp(img_b, flow))
    return (d * m).sum() / m.sum()


def test_arflow_way_is_the_weighted_mean_over_scales_and_directions():
    img1, img2 = texture(30).double(), texture(31).double()
    c = torch.tensor([1.3, -0.6], dtype=torch.float64).view(1, 2, 1, 1)
    fw, bw = pyramid(c.expand(1, 2, H, W).clone()), pyramid(-c.expand(1, 2, H, W).clone())
    pts1, pts2 = torch.tensor([[10, 10], [21, 15], [40, 30]]), torch.tensor([[30, 8], [45, 20], [12, 31]])
    kp, mask = both_frames(*pad_keypoints([pts1]), *pad_keypoints([pts2]))
    weights = (1.0, 0.5, 1.0, 0.25, 0.0)
    cfg = patch_cfg(w_scales=weights, backward=True, smooth_weight=50.0)
    loss, stats = finetune_loss(fw, bw, img1, img2, kp, mask, cfg)
    noc1, noc2 = non_occluded_by_consistency(fw[0], bw[0])
    expect = 0.0
    for i, wi in enumerate(weights[:4]):
        size = fw[i].shape[-2:]

        def mapped(pts, size=size):
            return {((x + a) * size[1] // W, (y + b) * size[0] // H) for x, y in pts.tolist()
                    for a in (-2, 0, 2) for b in (-2, 0, 2)}

        im1 = img1 if i == 0 else F.interpolate(img1, size=size, mode="area")
        im2 = img2 if i == 0 else F.interpolate(img2, size=size, mode="area")
        n1 = F.interpolate(noc1, size=size, mode="nearest")
        n2 = F.interpolate(noc2, size=size, mode="nearest")
        t_fw = _dense_term(im1, im2, fw[i], n1, mapped(pts1))
        t_bw = _dense_term(im2, im1, bw[i], n2, mapped(pts2))
        expect += wi * float(t_fw + t_bw) / 2
    assert stats["smooth"] == 0.0  # constant flows
    assert stats["photometric"] == pytest.approx(expect, abs=1e-9) and float(loss) == pytest.approx(expect)
    # smoothness: finest level only, both directions averaged, λ-weighted
    f = smooth_flow().double()
    g = -f + 0.2 * torch.sin(f)
    loss, stats = finetune_loss(pyramid(f), pyramid(g), img1, img2, kp, mask, cfg)
    s = float(min(H, W))
    sm = (smoothness(f / s, img1) + smoothness(g / s, img2)) / 2
    assert stats["smooth"] == pytest.approx(float(sm), rel=1e-12)
    assert float(loss) == pytest.approx(stats["photometric"] + 50.0 * float(sm), rel=1e-12)


def test_coarse_flows_are_read_in_pixels_of_their_level():
    """The true pyramid (level i divided by 2^i, as PWC-Lite returns it) scores better at the coarse
    levels than the same flows left in input pixels."""
    img2 = texture(32)
    flow = 2.0 * smooth_flow()
    img1 = warp(img2, flow)
    kp, mask = grid_keypoints(1, step=6)
    kp, mask = both_frames(kp, mask, kp, mask)
    cfg = patch_cfg(w_scales=(0.0, 1.0, 1.0), backward=False)
    true = pyramid(flow, 3)
    unscaled = [true[0]] + [f * 2**i for i, f in enumerate(true) if i > 0]
    _, good = finetune_loss(true, pyramid(-flow, 3), img1, img2, kp, mask, cfg)
    _, bad = finetune_loss(unscaled, pyramid(-flow, 3), img1, img2, kp, mask, cfg)
    assert good["photometric"] < 0.7 * bad["photometric"]


def test_backward_term_uses_the_source_keypoints_at_every_level():
    img1, img2 = texture(33), texture(34)
    gen = torch.Generator().manual_seed(3)
    base = smooth_flow() + 0.3 * torch.randn(1, 2, H, W, generator=gen)
    fw = [f.clone().requires_grad_(True) for f in pyramid(base, 2)]
    bw = [f.clone().requires_grad_(True) for f in pyramid(-base, 2)]
    pts1, pts2 = torch.tensor([[10, 10], [40, 30]]), torch.tensor([[30, 8], [20, 25]])
    kp1, m1 = pad_keypoints([pts1])
    kp2, m2 = pad_keypoints([pts2])
    kp, mask = both_frames(kp1, m1, kp2, m2)
    cfg = patch_cfg(w_scales=(1.0, 1.0), backward=True, smooth_weight=0.0, occlusion="range_map")
    loss, _ = finetune_loss(fw, bw, img1, img2, kp, mask, cfg)
    loss.backward()
    for flows, (k, m) in ((fw, (kp1, m1)), (bw, (kp2, m2))):
        for i, f in enumerate(flows):
            h, w = f.shape[-2:]
            idx, valid = patch_indices(k, m, H, W, 2, level_hw=(h, w))
            region = torch.zeros(h * w, dtype=torch.bool)
            region[idx[0][valid[0]]] = True
            touched = f.grad[0].abs().sum(0).reshape(-1) > 0
            assert touched.any() and not (touched & ~region).any(), (i, "outside the frame's patches")
    # swapping the frames' keypoints changes the loss only through the backward term
    swapped, _ = finetune_loss(fw, bw, img1, img2, kp.flip(1), mask.flip(1), cfg)
    assert float(swapped.detach()) != pytest.approx(float(loss.detach()), rel=1e-4)
    one_way = patch_cfg(w_scales=(1.0, 1.0), smooth_weight=0.0, occlusion="range_map")
    a, _ = finetune_loss(fw, bw, img1, img2, kp, mask, one_way)
    b, _ = finetune_loss(fw, bw, img1, img2, kp2.new_zeros(1, 2, 2, 2) + kp[:, :1], mask, one_way)
    assert float(a.detach()) == float(b.detach())
