"""Tests for f2depth.losses.ssim."""

from __future__ import annotations

import torch

from f2depth.losses.ssim import ssim_dense, ssim_samples


def test_identical_images_have_zero_dissimilarity():
    x = torch.rand(2, 3, 8, 9)
    assert ssim_dense(x, x).abs().max() < 1e-6
    assert ssim_samples(x.flatten(2), x.flatten(2)).abs().max() < 1e-6


def test_dense_equals_samples_on_one_window():
    torch.manual_seed(0)
    x, y = torch.rand(1, 3, 3, 3, dtype=torch.float64), torch.rand(1, 3, 3, 3, dtype=torch.float64)
    dense = ssim_dense(x, y)[..., 1, 1]  # the centre window needs no padding
    sparse = ssim_samples(x.flatten(2), y.flatten(2))
    assert torch.allclose(dense, sparse, atol=1e-12)


def test_hand_computed_value_and_range():
    x = torch.tensor([0.0, 1.0], dtype=torch.float64)
    y = torch.tensor([1.0, 0.0], dtype=torch.float64)
    c1, c2 = 0.01**2, 0.03**2
    # μ = 0.5 each, σ² = 0.25 each, σxy = −0.25.
    ssim = ((2 * 0.25 + c1) * (-0.5 + c2)) / ((0.5 + c1) * (0.5 + c2))
    assert torch.allclose(ssim_samples(x, y), torch.tensor((1 - ssim) / 2, dtype=torch.float64))
    z = torch.rand(4, 3, 5, 5)
    out = ssim_dense(z, torch.rand(4, 3, 5, 5))
    assert out.shape == z.shape and (out >= 0).all() and (out <= 1).all()
