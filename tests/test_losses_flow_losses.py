"""Tests for f2depth.losses.flow_losses: L_rigid and the multi-scale feature-map synthesis L_feature."""

from __future__ import annotations

import pytest
import torch
from depth_scenes import plane_scene
from torch import nn

from f2depth import geometry as G
from f2depth.losses.flow_losses import feature_synthesis_loss, resize_flow, rigid_flow_loss

AA = (0.01, -0.03, 0.015)
T = (0.2, -0.05, 0.08)


def _pose(aa=AA, t=T, requires_grad=False):
    a = torch.tensor([aa], dtype=torch.float64, requires_grad=requires_grad)
    tr = torch.tensor([t], dtype=torch.float64, requires_grad=requires_grad)
    return a, tr


class Pyramid(nn.Module):
    """A stand-in for the flow network's feature pyramid: six stride-2 conv levels."""

    def __init__(self, channels=(8, 8, 12, 12, 16, 16)) -> None:
        super().__init__()
        torch.manual_seed(0)
        chans = (3, *channels)
        self.convs = nn.ModuleList(nn.Conv2d(chans[i], chans[i + 1], 3, 2, 1) for i in range(len(channels)))
        self.double()

    def forward(self, x):
        feats = []
        for conv in self.convs:
            x = torch.tanh(conv(x))
            feats.append(x)
        return feats


def test_rigid_loss_zero_at_gt_and_grows_with_depth_error():
    s = plane_scene().torch()
    gt_flow = s["flow"]  # ray-traced ground truth standing in for the network's flow
    assert rigid_flow_loss(G.rigid_flow(s["depth_t"], s["K"], s["T"]), gt_flow).item() < 1e-4
    losses = [
        rigid_flow_loss(G.rigid_flow(scale * s["depth_t"], s["K"], s["T"]), gt_flow).item()
        for scale in (1.0, 1.05, 1.1, 1.2, 1.4)
    ]
    assert all(b > a for a, b in zip(losses, losses[1:])), losses
    assert losses[-1] > 0.3


def test_rigid_loss_hand_value_mask_and_shape_check():
    f1 = torch.zeros(1, 2, 2, 2)
    f2 = torch.zeros(1, 2, 2, 2)
    f2[0, 0, 0, 0] = 4.0
    assert rigid_flow_loss(f1, f2).item() == pytest.approx(4.0 / 8)
    valid = torch.ones(1, 1, 2, 2)
    valid[0, 0, 0, 0] = 0
    assert rigid_flow_loss(f1, f2, valid).item() == 0.0
    with pytest.raises(ValueError, match="differ in shape"):
        rigid_flow_loss(f1, torch.zeros(1, 2, 4, 4))


def test_rigid_loss_does_not_backprop_into_flow_net():
    f_rigid = torch.randn(1, 2, 3, 3, requires_grad=True)
    f_net = torch.randn(1, 2, 3, 3, requires_grad=True)
    rigid_flow_loss(f_rigid, f_net).backward()
    assert f_rigid.grad is not None and f_net.grad is None


def test_resize_flow_scales_by_stride():
    flow = torch.ones(1, 2, 64, 96) * torch.tensor([4.0, -2.0]).reshape(1, 2, 1, 1)
    small = resize_flow(flow, (16, 24))
    assert small.shape == (1, 2, 16, 24)
    assert torch.allclose(small[:, 0], torch.full((1, 16, 24), 1.0))
    assert torch.allclose(small[:, 1], torch.full((1, 16, 24), -0.5))
    assert resize_flow(flow, (64, 96)) is flow


def _feature_loss(s, net, depth, aa, t):
    with torch.no_grad():
        ft, fs = net(s["img_t"]), net(s["img_s"])
    flow = G.rigid_flow(depth, s["K"], G.pose_from_params(aa, t))
    return feature_synthesis_loss(ft, fs, flow)


def test_feature_loss_lowest_at_true_depth_and_pose():
    s = plane_scene().torch()
    net = Pyramid()
    feats = net(s["img_t"])
    assert [f.shape[-2:] for f in feats][-1] == (1, 2)  # six levels down to 1/64
    true = _feature_loss(s, net, s["depth_t"], *_pose())
    perturbed = {
        "depth x0.8": _feature_loss(s, net, 0.8 * s["depth_t"], *_pose()),
        "depth x1.25": _feature_loss(s, net, 1.25 * s["depth_t"], *_pose()),
        "translation": _feature_loss(s, net, s["depth_t"], *_pose(t=(0.26, -0.05, 0.08))),
        "rotation": _feature_loss(s, net, s["depth_t"], *_pose(aa=(0.01, -0.015, 0.015))),
    }
    for name, value in perturbed.items():
        assert value > 1.2 * true, (name, value.item(), true.item())
    scales = (0.9, 0.95, 1.0, 1.05, 1.1)
    sweep = [_feature_loss(s, net, k * s["depth_t"], *_pose()).item() for k in scales]
    assert scales[sweep.index(min(sweep))] == 1.0, sweep


def test_feature_loss_gradients_reach_depth_and_pose_only():
    s = plane_scene(32, 48).torch()
    net = Pyramid()
    ft, fs = net(s["img_t"]), net(s["img_s"])  # built with autograd on, as if the network were trainable
    depth = (1.1 * s["depth_t"]).requires_grad_()
    aa, t = _pose(requires_grad=True)
    loss = feature_synthesis_loss(ft, fs, G.rigid_flow(depth, s["K"], G.pose_from_params(aa, t)))
    loss.backward()
    assert depth.grad.abs().sum() > 0 and aa.grad.abs().sum() > 0 and t.grad.abs().sum() > 0
    assert all(p.grad is None for p in net.parameters())


def test_feature_loss_ignores_out_of_view_pixels():
    # Source features equal to the target's shifted by 3 px: the true flow gives exactly zero, even
    # though the last 3 columns map outside the image (border padding would otherwise add error).
    torch.manual_seed(2)
    ft = [torch.rand(1, 4, 8, 12, dtype=torch.float64)]
    fs = [torch.roll(ft[0], shifts=3, dims=-1)]
    fs[0][..., :3] = 5.0  # content that the true flow never samples from inside the image
    flow = torch.zeros(1, 2, 8, 12, dtype=torch.float64)
    flow[:, 0] = 3.0
    assert feature_synthesis_loss(ft, fs, flow).item() < 1e-12
    assert feature_synthesis_loss(ft, fs, torch.zeros_like(flow)).item() > 0.1


def test_feature_loss_gradcheck():
    torch.manual_seed(3)
    ft = [torch.rand(1, 3, 6, 8, dtype=torch.float64), torch.rand(1, 3, 3, 4, dtype=torch.float64)]
    fs = [torch.rand(1, 3, 6, 8, dtype=torch.float64), torch.rand(1, 3, 3, 4, dtype=torch.float64)]
    flow = (0.3 + 0.4 * torch.rand(1, 2, 6, 8, dtype=torch.float64)).requires_grad_()
    assert torch.autograd.gradcheck(lambda f: feature_synthesis_loss(ft, fs, f), (flow,))
