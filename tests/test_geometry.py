"""Tests for f2depth.geometry: projections, rotations, rigid flow, warping and masks."""

from __future__ import annotations

import math

import pytest
import torch

from f2depth import geometry as G


def _K(b: int = 1, dtype=torch.float64) -> torch.Tensor:
    K = torch.tensor([[50.0, 0.0, 15.5], [0.0, 52.0, 11.0], [0.0, 0.0, 1.0]], dtype=dtype)
    return K.expand(b, 3, 3).clone()


def _pose(aa, t, dtype=torch.float64) -> torch.Tensor:
    return G.pose_from_params(torch.tensor([aa], dtype=dtype), torch.tensor([t], dtype=dtype))


def test_pixel_grid_layout():
    g = G.pixel_grid(3, 4, torch.float64)
    assert g.shape == (1, 2, 3, 4)
    assert g[0, 0, 2, 3] == 3 and g[0, 1, 2, 3] == 2  # x = column first, y = row


def test_backproject_project_round_trip():
    torch.manual_seed(0)
    b, h, w = 2, 6, 8
    depth = 0.5 + 3 * torch.rand(b, 1, h, w, dtype=torch.float64)
    K = _K(b)
    points = G.backproject(depth, torch.linalg.inv(K))
    eye = torch.eye(4, dtype=torch.float64).expand(b, 4, 4)
    pix, z = G.project(points, K, eye)
    assert torch.allclose(pix, G.pixel_grid(h, w, torch.float64).expand(b, 2, h, w), atol=1e-6)
    assert torch.allclose(z, depth, atol=1e-12)


def test_project_hand_computed():
    # One point X = (1, -0.5, 4) in the src frame, tgt_T_src = translation (0.5, 0, 1), no rotation.
    points = torch.tensor([1.0, -0.5, 4.0], dtype=torch.float64).reshape(1, 3, 1, 1)
    T = _pose([0.0, 0.0, 0.0], [0.5, 0.0, 1.0])
    pix, z = G.project(points, _K(), T)
    # X_tgt = (1.5, -0.5, 5): u = 50·1.5/5 + 15.5 = 30.5, v = 52·(−0.5)/5 + 11 = 5.8
    assert z.item() == pytest.approx(5.0)
    assert pix[0, 0, 0, 0].item() == pytest.approx(30.5, abs=1e-6)
    assert pix[0, 1, 0, 0].item() == pytest.approx(5.8, abs=1e-6)


def test_axis_angle_known_rotation():
    aa = torch.tensor([[0.0, 0.0, math.pi / 2]], dtype=torch.float64)
    R = G.axis_angle_to_matrix(aa)[0]
    expected = torch.tensor([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]], dtype=torch.float64)
    assert torch.allclose(R, expected, atol=1e-12)
    # 90° about x maps y to z.
    Rx = G.axis_angle_to_matrix(torch.tensor([[math.pi / 2, 0.0, 0.0]], dtype=torch.float64))[0]
    assert torch.allclose(
        Rx @ torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64),
        torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64),
        atol=1e-12,
    )


def test_axis_angle_rodrigues_properties():
    torch.manual_seed(1)
    aa = torch.randn(16, 3, dtype=torch.float64)
    aa[0] = 0.0
    aa[1] = 1e-5 * torch.randn(3, dtype=torch.float64)  # Taylor branch
    R = G.axis_angle_to_matrix(aa)
    eye = torch.eye(3, dtype=torch.float64).expand_as(R)
    assert torch.allclose(R @ R.transpose(1, 2), eye, atol=1e-12)
    assert torch.allclose(torch.linalg.det(R), torch.ones(16, dtype=torch.float64), atol=1e-12)
    # The axis is fixed, the angle is the norm, and R(−a) = R(a)ᵀ.
    assert torch.allclose((R @ aa.unsqueeze(-1)).squeeze(-1), aa, atol=1e-12)
    theta = aa.norm(dim=1)
    cos = ((R.diagonal(dim1=1, dim2=2).sum(-1) - 1) / 2).clamp(-1, 1)
    wrapped = torch.remainder(theta + math.pi, 2 * math.pi) - math.pi
    assert torch.allclose(torch.cos(wrapped), cos, atol=1e-10)
    assert torch.allclose(G.axis_angle_to_matrix(-aa), R.transpose(1, 2), atol=1e-12)
    assert torch.allclose(R[0], eye[0])


def test_axis_angle_matches_exponential_map():
    torch.manual_seed(2)
    aa = 0.7 * torch.randn(5, 3, dtype=torch.float64)
    expected = torch.linalg.matrix_exp(G._skew(aa))
    assert torch.allclose(G.axis_angle_to_matrix(aa), expected, atol=1e-12)


def test_axis_angle_gradient_finite_at_zero():
    aa = torch.zeros(2, 3, dtype=torch.float64, requires_grad=True)
    G.axis_angle_to_matrix(aa).sum().backward()
    assert torch.isfinite(aa.grad).all()
    assert torch.autograd.gradcheck(G.axis_angle_to_matrix, (aa,))
    aa2 = torch.tensor([[0.3, -0.2, 0.5], [1e-4, 0.0, 2e-4]], dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(G.axis_angle_to_matrix, (aa2,))


def test_pose_from_params_convention_and_inverse():
    aa = torch.tensor([[0.1, -0.3, 0.2]], dtype=torch.float64)
    t = torch.tensor([[0.4, 0.1, -0.2]], dtype=torch.float64)
    T = G.pose_from_params(aa, t)
    R = G.axis_angle_to_matrix(aa)
    assert torch.allclose(T[0, :3, :3], R[0]) and torch.allclose(T[0, :3, 3], t[0])  # T(t)·R(aa)
    Ti = G.pose_from_params(aa, t, invert=True)
    eye = torch.eye(4, dtype=torch.float64)
    assert torch.allclose(T @ Ti, eye[None], atol=1e-12)
    assert torch.allclose(G.invert_pose(T), Ti, atol=1e-12)
    assert torch.allclose(G.invert_pose(T), torch.linalg.inv(T), atol=1e-12)


def test_relative_pose():
    world_T_a = _pose([0.1, 0.2, -0.1], [1.0, 2.0, 0.5])
    world_T_b = _pose([-0.2, 0.0, 0.3], [0.0, 1.5, 1.0])
    b_T_a = G.relative_pose(world_T_a, world_T_b)
    X_a = torch.tensor([0.3, -0.4, 2.0, 1.0], dtype=torch.float64)
    # The same world point seen from a and from b.
    X_w = world_T_a[0] @ X_a
    assert torch.allclose(b_T_a[0] @ X_a, torch.linalg.inv(world_T_b[0]) @ X_w, atol=1e-12)


def test_rigid_flow_pure_translation_closed_form():
    h, w = 7, 9
    K = _K()
    depth = torch.full((1, 1, h, w), 2.0, dtype=torch.float64)
    depth[..., 3:, :] = 4.0
    tx, ty, tz = 0.2, -0.1, 0.0
    T = _pose([0.0, 0.0, 0.0], [tx, ty, tz])
    flow = G.rigid_flow(depth, K, T)
    # Translation parallel to the image plane: flow = (fx·tx/D, fy·ty/D).
    assert torch.allclose(flow[:, 0:1], 50.0 * tx / depth, atol=1e-9)
    assert torch.allclose(flow[:, 1:2], 52.0 * ty / depth, atol=1e-9)
    # Forward motion: p_s − c = (p_t − c)·D/(D − tz).
    T2 = _pose([0.0, 0.0, 0.0], [0.0, 0.0, -0.5])
    flow2 = G.rigid_flow(depth, K, T2)
    grid = G.pixel_grid(h, w, torch.float64)
    c = torch.tensor([15.5, 11.0], dtype=torch.float64).reshape(1, 2, 1, 1)
    expected = (grid - c) * depth / (depth - 0.5) - (grid - c)
    assert torch.allclose(flow2, expected, atol=1e-6)


def test_rigid_flow_identity_is_zero_and_batch_agnostic():
    depth = 1 + torch.rand(3, 1, 5, 6, dtype=torch.float64)
    eye = torch.eye(4, dtype=torch.float64).expand(3, 4, 4)
    assert torch.allclose(
        G.rigid_flow(depth, _K(3), eye), torch.zeros(3, 2, 5, 6, dtype=torch.float64), atol=1e-6
    )
    flow32 = G.rigid_flow(depth.float(), _K(3, torch.float32), eye.float())
    assert flow32.dtype == torch.float32


def test_gradcheck_rigid_flow():
    torch.manual_seed(3)
    depth = (1 + torch.rand(1, 1, 3, 4, dtype=torch.float64)).requires_grad_()
    aa = (0.05 * torch.randn(1, 3, dtype=torch.float64)).requires_grad_()
    t = (0.1 * torch.randn(1, 3, dtype=torch.float64)).requires_grad_()
    K = _K()

    def fn(d, a, tr):
        return G.rigid_flow(d, K, G.pose_from_params(a, tr))

    assert torch.autograd.gradcheck(fn, (depth, aa, t))


def test_warp_matches_manual_bilinear_and_border():
    img = torch.arange(20, dtype=torch.float64).reshape(1, 1, 4, 5)
    flow = torch.zeros(1, 2, 4, 5, dtype=torch.float64)
    flow[0, 0] = 0.5  # half a pixel to the right
    flow[0, 1] = 0.25
    out = G.warp(img, flow)
    # img(x, y) = 5y + x is linear, so bilinear sampling is exact inside the image.
    expect = img + 0.5 + 5 * 0.25
    assert torch.allclose(out[..., :3, :4], expect[..., :3, :4], atol=1e-12)
    # Border padding: sampling beyond the right edge clamps to the last column.
    big = torch.zeros(1, 2, 4, 5, dtype=torch.float64)
    big[0, 0] = 10.0
    assert torch.allclose(G.warp(img, big), img[..., 4:5].expand(1, 1, 4, 5))
    # Zero flow is the identity.
    assert torch.allclose(G.warp(img, torch.zeros_like(flow)), img)


def test_warp_follows_rigid_flow():
    # Synthesise a source by shifting a smooth texture; warping back with the known flow recovers it.
    h, w = 12, 16
    grid = G.pixel_grid(h, w, torch.float64)
    tex = torch.sin(0.4 * grid[:, :1]) + torch.cos(0.3 * grid[:, 1:])
    shift = 2.0
    src = torch.sin(0.4 * (grid[:, :1] - shift)) + torch.cos(0.3 * grid[:, 1:])
    flow = torch.zeros(1, 2, h, w, dtype=torch.float64)
    flow[:, 0] = shift
    out = G.warp(src, flow)
    valid = G.in_view_mask(flow).bool()
    assert torch.allclose(out[valid], tex[valid], atol=1e-12)


def test_gradcheck_warp():
    torch.manual_seed(4)
    img = torch.randn(1, 2, 4, 5, dtype=torch.float64, requires_grad=True)
    flow = (0.3 + 0.4 * torch.rand(1, 2, 4, 5, dtype=torch.float64)).requires_grad_()
    assert torch.autograd.gradcheck(G.warp, (img, flow))


def test_in_view_mask():
    flow = torch.zeros(1, 2, 3, 4)
    flow[0, 0, :, 3] = 0.5  # last column pushed out to the right
    flow[0, 1, 0, 0] = -0.1  # top-left pixel pushed up
    m = G.in_view_mask(flow)
    assert m.shape == (1, 1, 3, 4)
    assert m[0, 0, :, 3].sum() == 0 and m[0, 0, 0, 0] == 0
    assert m.sum() == 12 - 3 - 1


def test_occlusion_by_depth():
    h, w = 6, 8
    K = _K()
    depth_t = torch.full((1, 1, h, w), 3.0, dtype=torch.float64)
    eye = torch.eye(4, dtype=torch.float64)[None]
    depth_s = depth_t.clone()
    depth_s[..., 2:4, 2:4] = 1.0  # an occluder appears in front in the source view
    occ = G.occlusion_by_depth(depth_t, depth_s, K, eye)
    assert occ.dtype == torch.bool
    assert occ[..., 2:4, 2:4].all() and occ.sum() == 4
    # Within tolerance: not occluded; invalid source depth: not occluded.
    depth_s2 = depth_t * 0.99
    depth_s2[..., 0, 0] = 0.0
    assert not G.occlusion_by_depth(depth_t, depth_s2, K, eye).any()


def test_rigid_flow_matches_ray_traced_flow():
    from depth_scenes import plane_scene

    s = plane_scene().torch()
    flow = G.rigid_flow(s["depth_t"], s["K"], s["T"])
    assert (flow - s["flow"]).abs().max() < 1e-4  # only the 1e-7 added to z before the division
    assert s["flow"].abs().max() > 2.0  # a real motion, not a trivial one
    # Warping the rendered source with it reproduces the rendered target where the view overlaps.
    rec = G.warp(s["img_s"], flow)
    inside = G.in_view_mask(flow).bool().expand_as(rec)
    assert (rec - s["img_t"])[inside].abs().mean() < 5e-3
    assert not G.occlusion_by_depth(s["depth_t"], s["depth_s"], s["K"], s["T"]).any()


def test_rigid_flow_via_world_poses():
    from depth_scenes import plane_scene

    s = plane_scene().torch()
    world_T_tgt = _pose([0.2, -0.1, 0.3], [1.0, 0.5, -2.0])
    world_T_src = world_T_tgt @ G.invert_pose(s["T"])
    src_T_tgt = G.relative_pose(world_T_tgt, world_T_src)
    assert torch.allclose(src_T_tgt, s["T"], atol=1e-12)
