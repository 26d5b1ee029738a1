"""EPE statistics, low-texture pixels and the colour wheel (f2depth.flow.evaluation)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from f2depth.flow.evaluation import (
    EPEAccumulator,
    color_wheel,
    epe_stats,
    flow_to_color,
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
