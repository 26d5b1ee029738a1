"""Tests for f2depth.losses.photometric (P²Net's patch loss L_ph)."""

from __future__ import annotations

import torch
from depth_scenes import plane_scene

from f2depth import geometry as G
from f2depth.losses.photometric import (
    PATCH_SPACING,
    centre_depth,
    patch_photometric_errors,
    patch_photometric_loss,
    patch_samples,
    project_patches,
)


def _points(n: int, h: int, w: int, seed: int = 0, margin: int = 3) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    x = torch.randint(margin, w - margin, (1, n, 1), generator=g)
    y = torch.randint(margin, h - margin, (1, n, 1), generator=g)
    return torch.cat((x, y), dim=-1).to(torch.float64)


def test_pattern_is_p2net_order():
    offsets = [tuple(o) for o in G.patch_offsets(PATCH_SPACING).tolist()]
    assert offsets[0] == (-2, -2) and offsets[1] == (0, -2) and offsets[4] == (0, 0)
    assert offsets[8] == (2, 2) and len(set(offsets)) == 9
    pix = patch_samples(torch.tensor([[[5.2, 7.0]]]))
    assert pix.shape == (1, 1, 9, 2)
    assert torch.equal(pix[0, 0, 0], torch.tensor([3.0, 5.0])) and torch.equal(
        pix[0, 0, 5], torch.tensor([7.0, 7.0])
    )


def test_centre_depth_gathers_integer_pixel():
    depth = torch.arange(12, dtype=torch.float32).reshape(1, 1, 3, 4)
    pts = torch.tensor([[[1.0, 2.0], [3.4, 0.0], [-5.0, 9.0]]])  # x, y; the last one is clamped
    assert centre_depth(depth, pts).tolist() == [[9.0, 3.0, 8.0]]


def test_patches_share_centre_depth_and_follow_rigid_flow_at_centre():
    s = plane_scene().torch()
    pts = _points(20, 64, 96)
    pix_t = patch_samples(pts)
    d_c = centre_depth(s["depth_t"], pts)
    pix_s = project_patches(d_c, pix_t, s["K"], s["T"])
    # The centre sample lands where the dense rigid flow sends it.
    flow = G.rigid_flow(s["depth_t"], s["K"], s["T"])
    x, y = pts[0, :, 0].long(), pts[0, :, 1].long()
    assert torch.allclose(pix_s[0, :, 4], pts[0] + flow[0, :, y, x].T, atol=1e-4)
    # All 9 samples back-project to the same z (fronto-parallel patch) in the target frame.
    assert pix_s.shape == (1, 20, 9, 2)


def test_identity_pose_and_same_image_give_zero():
    s = plane_scene().torch()
    eye = torch.eye(4, dtype=torch.float64)[None]
    loss = patch_photometric_loss(s["img_t"], [s["img_t"]], s["depth_t"], s["K"], [eye], _points(50, 64, 96))
    assert loss.item() < 1e-6


def test_true_depth_beats_wrong_depth():
    s = plane_scene().torch()
    pts = _points(300, 64, 96, margin=0)
    true = patch_photometric_loss(s["img_t"], [s["img_s"]], s["depth_t"], s["K"], [s["T"]], pts)
    for scale in (0.6, 0.8, 1.25, 1.6):
        wrong = patch_photometric_loss(s["img_t"], [s["img_s"]], scale * s["depth_t"], s["K"], [s["T"]], pts)
        assert wrong > 2 * true, (scale, wrong.item(), true.item())
    assert true.item() < 0.02


def test_minimum_over_sources():
    s = plane_scene().torch()
    pts = _points(100, 64, 96)
    bad_T = G.pose_from_params(torch.tensor([[0.0, 0.05, 0.0]], dtype=torch.float64), s["T"][:, :3, 3])
    errs = patch_photometric_errors(
        s["img_t"], [s["img_s"], s["img_s"]], s["depth_t"], s["K"], [s["T"], bad_T], pts
    )
    assert errs.shape == (1, 2, 100)
    loss = patch_photometric_loss(
        s["img_t"], [s["img_s"], s["img_s"]], s["depth_t"], s["K"], [s["T"], bad_T], pts
    )
    assert torch.allclose(loss, errs.min(dim=1).values.mean())
    assert errs[:, 1].mean() > errs[:, 0].mean()


def test_gradients_reach_depth_and_pose_gradcheck():
    s = plane_scene(16, 24).torch()
    pts = _points(6, 16, 24, seed=3)
    depth = s["depth_t"].clone().requires_grad_()
    aa = torch.tensor([[0.01, -0.03, 0.015]], dtype=torch.float64, requires_grad=True)
    t = torch.tensor([[0.2, -0.05, 0.08]], dtype=torch.float64, requires_grad=True)

    def fn(d, a, tr):
        return patch_photometric_loss(
            s["img_t"], [s["img_s"]], 1.1 * d, s["K"], [G.pose_from_params(a, tr)], pts
        )

    assert torch.autograd.gradcheck(fn, (depth, aa, t), atol=1e-5, fast_mode=True)
    fn(depth, aa, t).backward()
    assert depth.grad.abs().sum() > 0 and aa.grad.abs().sum() > 0 and t.grad.abs().sum() > 0
