"""EPE statistics, low-texture pixels and the colour wheel (f2depth.flow.evaluation)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from f2depth.colour import color_wheel, flow_to_color
from f2depth.flow.evaluation import (
    COSINE_MIN_FLOW,
    EPEAccumulator,
    epe_stats,
    gradient_energy,
    low_texture_mask,
)


def test_epe_sets_and_counts():
    gt = torch.zeros(1, 2, 2, 3)
    pred = torch.zeros(1, 2, 2, 3)
    pred[0, 0, 0, 0] = 3.0
    pred[0, 1, 0, 0] = 4.0  # error 5 at (0, 0)
    pred[0, 0, 1, 2] = 1.0  # error 1 at (1, 2)
    occ = torch.zeros(1, 1, 2, 3, dtype=torch.bool)
    occ[0, 0, 0, 0] = True
    low = torch.zeros(1, 1, 2, 3, dtype=torch.bool)
    low[0, 0, 1] = True
    r = epe_stats(pred, gt, occ, low)
    assert r["epe_all"] == pytest.approx(6 / 6)
    assert r["epe_noc"] == pytest.approx(1 / 5) and r["epe_occ"] == pytest.approx(5.0)
    assert r["epe_low_texture"] == pytest.approx(1 / 3)
    assert (r["pixels_all"], r["pixels_noc"], r["pixels_occ"], r["pixels_low_texture"]) == (6, 5, 1, 3)


def test_accumulator_pools_pixels_and_respects_valid():
    acc = EPEAccumulator()
    acc.add(torch.ones(1, 2, 1, 2), torch.zeros(1, 2, 1, 2))  # error √2 on 2 pixels
    valid = torch.tensor([[[[True, False, False]]]])
    acc.add(torch.zeros(1, 2, 1, 3), torch.full((1, 2, 1, 3), 3.0), valid=valid)  # 3√2 on 1 pixel
    r = acc.result()
    assert r["epe_all"] == pytest.approx((2 * 2**0.5 + 3 * 2**0.5) / 3)
    assert r["pixels_all"] == 3 and r["epe_noc"] is None and r["epe_low_texture"] is None


def _gt_1x4():
    """``(1,2,1,4)``: lengths 5, 1, 0.05 (below COSINE_MIN_FLOW) and 2, all in different directions."""
    gt = torch.zeros(1, 2, 1, 4)
    gt[0, :, 0, 0] = torch.tensor([3.0, 4.0])
    gt[0, :, 0, 1] = torch.tensor([0.0, -1.0])
    gt[0, :, 0, 2] = torch.tensor([0.05, 0.0])
    gt[0, :, 0, 3] = torch.tensor([-2.0, 0.0])
    return gt


def test_magnitude_ratio_and_cosine_hand_computed():
    gt = _gt_1x4()
    assert 0.05 <= COSINE_MIN_FLOW < 1
    half = epe_stats(0.5 * gt, gt)
    assert half["magnitude_ratio"] == pytest.approx(0.5) and half["cosine"] == pytest.approx(1.0)
    opposite = epe_stats(-gt, gt)
    assert opposite["magnitude_ratio"] == pytest.approx(1.0) and opposite["cosine"] == pytest.approx(-1.0)
    zero = epe_stats(torch.zeros_like(gt), gt)
    assert zero["magnitude_ratio"] == 0.0 and zero["cosine"] == 0.0
    # the 0.05 px pixel counts in the ratio, not in the cosine: predicted there at right angles, length 8
    pred = gt.clone()
    pred[0, :, 0, 2] = torch.tensor([0.0, 8.0])
    r = epe_stats(pred, gt)
    assert r["magnitude_ratio"] == pytest.approx((5 + 1 + 8 + 2) / (5 + 1 + 0.05 + 2))
    assert r["cosine"] == pytest.approx(1.0)
    # per-pixel cosines 1, 0 (perpendicular), 0 (zero prediction) over the three moving pixels
    pred = gt.clone()
    pred[0, :, 0, 1] = torch.tensor([2.0, 0.0])
    pred[0, :, 0, 3] = 0.0
    r = epe_stats(pred, gt)
    assert r["cosine"] == pytest.approx(1 / 3)
    assert r["magnitude_ratio"] == pytest.approx((5 + 2 + 0.05 + 0) / (5 + 1 + 0.05 + 2))
    # valid restricts both: only pixels 0 (right) and 3 (opposite, length 4 of 2)
    pred = gt.clone()
    pred[0, :, 0, 3] = torch.tensor([4.0, 0.0])
    pred[0, :, 0, 1] = torch.tensor([100.0, 100.0])
    valid = torch.tensor([[[[True, False, False, True]]]])
    r = epe_stats(pred, gt, valid=valid)
    assert r["magnitude_ratio"] == pytest.approx((5 + 4) / (5 + 2)) and r["cosine"] == pytest.approx(0.0)
    assert r["pixels_all"] == 2


def test_direction_stats_accumulate_like_one_batch_and_skip_non_finite():
    g = torch.Generator().manual_seed(1)
    gt = torch.randn(3, 2, 4, 5, generator=g) * 2
    pred = torch.randn(3, 2, 4, 5, generator=g) * 2
    gt[0, :, 0, 0] = 0.01                      # too short for the cosine
    pred[1, 0, 2, 3] = float("nan")            # not scored at all
    occ = torch.rand(3, 1, 4, 5, generator=g) > 0.7
    acc = EPEAccumulator()
    acc.add(pred[:1], gt[:1], occ[:1])
    acc.add(pred[1:], gt[1:], occ[1:])
    two, one = acc.result(), epe_stats(pred, gt, occ)
    assert two.keys() == one.keys()
    for k in one:
        assert two[k] == pytest.approx(one[k]), k
    ok = torch.isfinite(pred).all(1)
    f, t = pred.permute(0, 2, 3, 1)[ok], gt.permute(0, 2, 3, 1)[ok]
    assert one["magnitude_ratio"] == pytest.approx(float(f.norm(dim=1).sum() / t.norm(dim=1).sum()), rel=1e-5)
    moving = t.norm(dim=1) > COSINE_MIN_FLOW
    cos = torch.nn.functional.cosine_similarity(f[moving], t[moving], dim=1)
    assert one["cosine"] == pytest.approx(float(cos.mean()), rel=1e-5)


def test_direction_stats_none_cases():
    empty = EPEAccumulator().result()
    assert empty["magnitude_ratio"] is None and empty["cosine"] is None
    still = torch.zeros(1, 2, 2, 2)
    r = epe_stats(torch.ones(1, 2, 2, 2), still)          # Σ|gt| = 0, nothing moves
    assert r["magnitude_ratio"] is None and r["cosine"] is None and r["pixels_all"] == 4
    slow = torch.full((1, 2, 2, 2), 0.05)                   # moves, but ≤ 0.1 px everywhere
    r = epe_stats(slow, slow)
    assert r["magnitude_ratio"] == pytest.approx(1.0) and r["cosine"] is None
    r = epe_stats(_gt_1x4(), _gt_1x4(), valid=torch.zeros(1, 1, 1, 4, dtype=torch.bool))
    assert r["magnitude_ratio"] is None and r["cosine"] is None and r["pixels_all"] == 0


def test_low_texture_is_flat_regions_only():
    img = torch.full((1, 3, 40, 40), 0.5)
    g = torch.Generator().manual_seed(0)
    img[..., :, 20:] += 0.2 * torch.rand(1, 3, 40, 20, generator=g)  # right half textured
    mask = low_texture_mask(img)
    assert mask[..., :, :14].all() and not mask[..., :, 21:].any()
    ramp = torch.linspace(0, 1, 40).view(1, 1, 1, 40).expand(1, 3, 40, 40)  # 1/39 per pixel
    assert float(gradient_energy(ramp)[..., 5:-5, 5:-5].mean()) == pytest.approx(1 / 39, rel=1e-3)
    assert not low_texture_mask(ramp).any() and low_texture_mask(ramp * 0.2).all()


def test_color_wheel_and_flow_colours():
    wheel = color_wheel()
    assert wheel.shape == (55, 3) and wheel.min() >= 0 and wheel.max() <= 255
    flow = np.zeros((3, 4, 2), np.float32)
    flow[0, 0] = (1.0, 0.0)    # right
    flow[0, 1] = (-1.0, 0.0)   # left
    flow[0, 2] = (0.0, 1.0)    # down
    flow[0, 3] = (np.nan, 0)   # invalid
    img = flow_to_color(flow)
    assert img.shape == (3, 4, 3) and img.dtype == np.uint8
    assert tuple(img[1, 1]) == (255, 255, 255)        # zero flow is white
    assert tuple(img[0, 3]) == (0, 0, 0)              # invalid is black
    assert img[0, 0, 0] > 200 and img[0, 0, 1] < 60   # right → red
    assert img[0, 1, 2] > 200 and img[0, 1, 0] < 60   # left → cyan/blue
    assert np.array_equal(flow_to_color(flow.transpose(2, 0, 1)), img)  # (2,H,W) accepted
    with pytest.raises(ValueError, match="expected"):
        flow_to_color(np.zeros((3, 4)))


def test_max_flow_saturates_long_vectors():
    flow = np.array([[[10.0, 0.0], [1.0, 0.0]]], np.float32)
    img = flow_to_color(flow, max_flow=2.0)
    assert img[0, 0].max() <= int(255 * 0.75) + 1  # beyond max_flow: darkened
    assert img[0, 1].min() > 100                    # half of max_flow: pale


def test_swap_consistency_tells_matched_flow_from_a_constant_field():
    rng = torch.Generator().manual_seed(0)
    flow = torch.randn(2, 2, 6, 7, generator=rng) * 3
    matched, constant = EPEAccumulator(), EPEAccumulator()
    matched.add_swapped(flow, -flow)               # flow(2→1) = −flow(1→2): read from the images
    constant.add_swapped(flow, flow)               # the same field whatever the frame order
    assert matched.result()["swap_consistency"] == pytest.approx(1.0)
    assert constant.result()["swap_consistency"] == pytest.approx(-1.0)
    short = EPEAccumulator()                       # vectors shorter than COSINE_MIN_FLOW carry no direction
    short.add_swapped(torch.full((1, 2, 3, 3), COSINE_MIN_FLOW / 4), torch.ones(1, 2, 3, 3))
    assert short.result()["swap_consistency"] is None
    assert EPEAccumulator().result()["swap_consistency"] is None
