"""AR self-supervision transforms (f2depth.flow.transforms)."""

from __future__ import annotations

import math

import torch

from f2depth.flow import PWCLite
from f2depth.flow.transforms import (
    KITTI_AR,
    SINTEL_AR,
    AppearanceConfig,
    SpatialConfig,
    appearance_transform,
    ar_loss,
    sample_affines,
    spatial_transform,
)
from f2depth.flow.warp import warp


def _pattern(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    return torch.stack([0.5 + 0.4 * torch.sin(x / 5 + y / 7), 0.5 + 0.4 * torch.cos(x / 4 - y / 6),
                        0.5 + 0.3 * torch.sin(x / 9) * torch.cos(y / 8)]).unsqueeze(0)


def _pair(u: float, v: float, hw=(48, 64)):
    ys, xs = torch.meshgrid(torch.arange(hw[0], dtype=torch.float32),
                            torch.arange(hw[1], dtype=torch.float32), indexing="ij")
    img1, img2 = _pattern(xs, ys), _pattern(xs - u, ys - v)  # img2(p + (u, v)) = img1(p)
    flow = torch.tensor([u, v]).view(1, 2, 1, 1).expand(1, 2, *hw).contiguous()
    return img1, img2, flow


def test_spatial_transform_keeps_image_flow_consistency():
    img1, img2, flow = _pair(2.5, -1.5)
    g = torch.Generator().manual_seed(0)
    for _ in range(4):
        a, b, f, m = spatial_transform(img1, img2, flow, torch.ones(1, 1, 48, 64), SpatialConfig(noise=0), g)
        inner = (slice(None), slice(None), slice(6, -6), slice(6, -6))
        assert float((warp(b, f) - a)[inner].abs().mean()) < 0.005  # the new flow maps the new frames
        assert float((b - a)[inner].abs().mean()) > 0.03
        assert f.shape == flow.shape and m.shape == (1, 1, 48, 64) and float(m.min()) >= 0


def test_affines_keep_corners_inside_and_flip():
    g = torch.Generator().manual_seed(1)
    t1, t2 = sample_affines(64, SpatialConfig(), g)
    corners = torch.tensor([[-1, -1, 1], [1, -1, 1], [-1, 1, 1], [1, 1, 1]], dtype=torch.float64).T
    for t in (t1, t2):
        assert float((t @ corners)[:, :2].abs().max()) <= 1 + 1e-9
    signs = torch.sign(t1[:, 0, 0] * t1[:, 1, 1] - t1[:, 0, 1] * t1[:, 1, 0])
    assert (signs < 0).any() and (signs > 0).any()  # some mirrored, some not


def test_appearance_same_parameters_for_both_frames_and_range():
    img1, _, _ = _pair(0, 0)
    g = torch.Generator().manual_seed(2)
    a, b = appearance_transform([img1, img1.clone()], AppearanceConfig(), g)
    assert torch.equal(a, b)
    assert float(a.min()) >= 0 and float(a.max()) <= 1 and float((a - img1).abs().mean()) > 1e-3
    none = appearance_transform([img1], AppearanceConfig(0, 0, 0, 0.0, 0.0, None), g)[0]
    assert torch.equal(none, img1)


def test_presets():
    assert SINTEL_AR.weight == 0.01 and SINTEL_AR.q == 1 and SINTEL_AR.eps == 0
    assert SINTEL_AR.spatial.rel_rotate == (-0.015, -0.015) and SINTEL_AR.spatial.vflip
    assert KITTI_AR.weight == 0.02 and not KITTI_AR.spatial.vflip and KITTI_AR.appearance.gamma is None


def test_ar_loss_finite_and_differentiable():
    torch.manual_seed(0)
    model = PWCLite()
    img1, img2, flow = _pair(1.0, 0.5, (64, 64))
    gen = torch.Generator().manual_seed(3)
    loss, stats = ar_loss(model, img1, img2, flow, torch.ones(1, 1, 64, 64), SINTEL_AR, gen)
    loss.backward()
    assert math.isfinite(float(loss.detach())) and set(stats) == {"ar", "ar_weighted"}
    assert any(p.grad is not None and float(p.grad.abs().sum()) > 0 for p in model.parameters())
    zero, _ = ar_loss(model, img1, img2, flow, torch.zeros(1, 1, 64, 64), SINTEL_AR, torch.Generator())
    assert float(zero.detach()) == 0.0  # empty mask: no NaN
