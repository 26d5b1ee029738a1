"""Tests for f2depth.losses.smoothness."""

from __future__ import annotations

import torch

from f2depth.losses.smoothness import edge_aware_smoothness


def test_constant_disparity_is_smooth():
    assert edge_aware_smoothness(torch.full((2, 1, 6, 7), 0.3), torch.rand(2, 3, 6, 7)).item() == 0.0


def test_mean_normalisation_makes_it_scale_invariant():
    torch.manual_seed(0)
    disp, img = torch.rand(2, 1, 6, 7), torch.rand(2, 3, 6, 7)
    a = edge_aware_smoothness(disp, img)
    b = edge_aware_smoothness(0.1 * disp, img)
    assert torch.allclose(a, b, rtol=1e-5)


def test_image_edges_lower_the_penalty():
    disp = torch.full((1, 1, 8, 8), 0.2)
    disp[..., 4:] = 0.6  # a disparity step between columns 3 and 4
    flat = torch.full((1, 3, 8, 8), 0.5)
    edge = flat.clone()
    edge[..., 4:] = 1.0
    assert edge_aware_smoothness(disp, edge) < edge_aware_smoothness(disp, flat)
    # Hand value without an edge: d steps 0.5 → 1.5 (mean 1.0 after normalisation) at 8 of 56 x-pairs.
    assert torch.allclose(edge_aware_smoothness(disp, flat), torch.tensor(8 / 56), atol=1e-6)


def test_gradcheck():
    torch.manual_seed(1)
    disp = torch.rand(1, 1, 4, 5, dtype=torch.float64, requires_grad=True)
    img = torch.rand(1, 3, 4, 5, dtype=torch.float64)
    assert torch.autograd.gradcheck(lambda d: edge_aware_smoothness(d, img), (disp,))
