"""Tests for f2depth.losses.planar (P²Net's superpixel plane loss L_spp)."""

from __future__ import annotations

import torch

from f2depth import geometry as G
from f2depth.losses.planar import fit_planes, planar_depth, planar_loss


def _K(h: int, w: int) -> torch.Tensor:
    return torch.tensor([[0.9 * w, 0, w / 2], [0, 0.9 * w, h / 2], [0, 0, 1]], dtype=torch.float64)[None]


def _plane_depth(n: torch.Tensor, K: torch.Tensor, h: int, w: int) -> torch.Tensor:
    rays = G.backproject(torch.ones(1, 1, h, w, dtype=torch.float64), torch.linalg.inv(K))
    return 1.0 / (n.reshape(1, 3, 1, 1) * rays).sum(1, keepdim=True)


def _two_plane_scene(h: int = 40, w: int = 60):
    K = _K(h, w)
    left = _plane_depth(torch.tensor([0.1, 0.05, 0.4], dtype=torch.float64), K, h, w)
    right = _plane_depth(torch.tensor([-0.15, 0.02, 0.3], dtype=torch.float64), K, h, w)
    depth = torch.where(torch.arange(w).reshape(1, 1, 1, w) < 30, left, right)
    seg = (torch.arange(w) >= 30).long().expand(1, h, w).clone()  # 1200 px each
    return depth, K, seg


def test_planar_depth_has_zero_loss():
    depth, K, seg = _two_plane_scene()
    K_inv = torch.linalg.inv(K)
    # Exact fit; only P²Net's 1e-6 in 1 / (nᵀK⁻¹p + 1e-6) remains (relative error ≈ 1e-6·D).
    assert planar_loss(depth, K_inv, seg, ridge=0.0).item() < 3e-5
    # With P²Net's ridge 0.01 the fit is biased by a negligible amount.
    assert planar_loss(depth, K_inv, seg).item() < 1e-4
    d_plane, mask = planar_depth(depth, K_inv, seg, ridge=0.0)
    assert mask.all() and torch.allclose(d_plane, depth, rtol=5e-6, atol=0)


def test_non_planar_depth_is_penalised_and_small_segments_ignored():
    depth, K, seg = _two_plane_scene()
    K_inv = torch.linalg.inv(K)
    bumpy = depth * (1 + 0.1 * torch.sin(torch.arange(60, dtype=torch.float64) / 3)).reshape(1, 1, 1, 60)
    assert planar_loss(bumpy, K_inv, seg).item() > 1e-3
    # Both superpixels have 1200 px: with min_area 1200 (strict >) nothing counts.
    assert planar_loss(bumpy, K_inv, seg, min_area=1200).item() == 0.0
    # Negative labels are ignored.
    assert planar_loss(bumpy, K_inv, torch.full_like(seg, -1)).item() == 0.0


def test_vectorised_fit_matches_a_per_segment_loop():
    torch.manual_seed(0)
    b, h, w = 2, 12, 16
    depth = 1 + torch.rand(b, 1, h, w, dtype=torch.float64)
    K_inv = torch.linalg.inv(_K(h, w)).expand(b, 3, 3)
    seg = torch.randint(0, 5, (b, h, w))
    seg[1] += 3  # labels overlap across the batch but are separate superpixels
    normals, ids, area = fit_planes(depth, K_inv, seg)
    X = G.backproject(depth, K_inv)
    for i in range(b):
        for label in seg[i].unique():
            m = seg[i] == label
            P = X[i].permute(1, 2, 0)[m]  # (n,3)
            A = P.T @ P + 0.01 * torch.eye(3, dtype=torch.float64)
            n_ref = torch.linalg.solve(A, P.sum(0))
            plane = ids[i][m].unique()
            assert plane.numel() == 1
            assert torch.allclose(normals[plane[0]], n_ref, atol=1e-10)
            assert area[plane[0]] == m.sum()
    assert normals.shape[0] == len(seg[0].unique()) + len(seg[1].unique())


def test_loss_is_mean_over_all_pixels():
    depth, K, seg = _two_plane_scene()
    K_inv = torch.linalg.inv(K)
    bumpy = depth + 0.05 * torch.rand_like(depth)
    d_plane, mask = planar_depth(bumpy, K_inv, seg)
    seg_half = seg.clone()
    seg_half[..., 30:] = torch.arange(1200).reshape(40, 30) + 2  # right half → tiny superpixels
    loss_half = planar_loss(bumpy, K_inv, seg_half)
    expected = ((bumpy - d_plane).abs()[..., :30]).sum() / (40 * 60)
    assert torch.allclose(loss_half, expected, atol=1e-12)


def test_gradcheck_through_the_fit():
    torch.manual_seed(1)
    h, w = 6, 8
    depth = (1 + torch.rand(1, 1, h, w, dtype=torch.float64)).requires_grad_()
    K_inv = torch.linalg.inv(_K(h, w))
    seg = (torch.arange(w) >= 4).long().expand(1, h, w)

    def fn(d):
        return planar_loss(d, K_inv, seg, min_area=10)

    assert fn(depth) > 0
    assert torch.autograd.gradcheck(fn, (depth,))
