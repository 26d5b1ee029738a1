"""ARFlow's unsupervised loss (f2depth.flow.loss): terms, occlusion masks, settings, no NaN."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from f2depth.flow.finetune import FinetuneConfig, batch_loss
from f2depth.flow.loss import (
    SINTEL_FT,
    SINTEL_RAW,
    FlowLossConfig,
    flow_loss,
    non_occluded_by_consistency,
    non_occluded_by_range,
    non_occluded_masks,
    range_map,
    smoothness,
    ssim_loss,
)
from f2depth.geometry import warp

REF = Path(__file__).resolve().parent / "data" / "arflow" / "arflow_loss_seed0.npz"


def _image(seed: int, hw=(64, 96)) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    coarse = torch.rand(1, 3, hw[0] // 8, hw[1] // 8, generator=g)
    return F.interpolate(coarse, size=hw, mode="bicubic", align_corners=False).clamp(0, 1)


def _pyramid(flow: torch.Tensor) -> list[torch.Tensor]:
    """Five levels finest first, each in pixels of its own resolution (like PWCLite's output)."""
    h, w = flow.shape[-2:]
    return [flow if i == 0 else F.interpolate(flow, size=(h >> i, w >> i), mode="bilinear",
                                              align_corners=True) / 2**i for i in range(5)]


def _const_flow(u: float, v: float, hw=(64, 96)) -> torch.Tensor:
    return torch.tensor([float(u), float(v)]).view(1, 2, 1, 1).expand(1, 2, *hw).clone()


def test_settings_match_arflow_configs():
    def weights(c):
        return c.w_l1, c.w_ssim, c.w_ternary, c.occ_from_back

    assert weights(SINTEL_RAW) == (0.15, 0.85, 0, True)
    assert weights(SINTEL_FT) == (0, 0, 1, False)
    for cfg in (SINTEL_RAW, SINTEL_FT):
        assert cfg.w_smooth == 50 and cfg.alpha == 10 and not cfg.smooth_2nd
        assert cfg.w_scales == (1, 1, 1, 1, 0) and cfg.w_sm_scales == (1, 0, 0, 0, 0)
    with pytest.raises(AttributeError):
        SINTEL_RAW.w_l1 = 1.0  # frozen


@pytest.mark.parametrize("cfg", [SINTEL_RAW, SINTEL_FT])
def test_true_flow_scores_lower_than_wrong_flow(cfg):
    img1 = _image(0, (64, 96))
    shift = 3
    img2 = torch.roll(img1, shifts=shift, dims=-1)  # img2(x + 3) = img1(x): flow 1→2 is +3
    good_fw, good_bw = _pyramid(_const_flow(shift, 0)), _pyramid(_const_flow(-shift, 0))
    bad_fw, bad_bw = _pyramid(_const_flow(0, 0)), _pyramid(_const_flow(0, 0))
    good, stats = flow_loss(good_fw, good_bw, img1, img2, cfg)
    bad, _ = flow_loss(bad_fw, bad_bw, img1, img2, cfg)
    assert float(good) < 0.5 * float(bad)
    assert set(stats) == {"loss", "photometric", "smooth", "flow_mean", "noc_fraction"}
    assert all(isinstance(v, float) for v in stats.values())


@pytest.mark.parametrize("cfg", [SINTEL_RAW, SINTEL_FT])
def test_finite_on_a_constant_image_pair(cfg):
    img = torch.full((2, 3, 64, 64), 0.5)
    fw = [torch.zeros(2, 2, 64 >> i, 64 >> i, requires_grad=True) for i in range(5)]
    bw = [torch.zeros(2, 2, 64 >> i, 64 >> i, requires_grad=True) for i in range(5)]
    loss, stats = flow_loss(fw, bw, img, img, cfg)
    loss.backward()
    assert math.isfinite(float(loss.detach())) and all(math.isfinite(v) for v in stats.values())
    grads = [f.grad for f in fw[:4] + bw[:4]]  # level 4 has weight 0 and gets no gradient
    assert all(g is not None and torch.isfinite(g).all() for g in grads)


def test_finite_when_every_pixel_is_occluded():
    img1, img2 = _image(1), _image(2)
    # forward and backward flows that disagree everywhere: the forward-backward check occludes all
    fw = [f.requires_grad_() for f in _pyramid(_const_flow(5, 5))]
    bw = [f.requires_grad_() for f in _pyramid(_const_flow(5, 5))]
    noc1, noc2 = non_occluded_by_consistency(fw[0].detach(), bw[0].detach())
    assert float(noc1.sum()) == 0 and float(noc2.sum()) == 0
    loss, stats = flow_loss(fw, bw, img1, img2, SINTEL_FT)
    loss.backward()
    assert math.isfinite(float(loss.detach()))
    assert stats["photometric"] == 0.0 and stats["noc_fraction"] == 0.0
    assert all(f.grad is None or torch.isfinite(f.grad).all() for f in fw + bw)
    assert torch.isfinite(fw[0].grad).all()
    # the range map too: flows pushing everything out of the image
    out_fw, out_bw = _pyramid(_const_flow(500, 0)), _pyramid(_const_flow(500, 0))
    loss, stats = flow_loss(out_fw, out_bw, img1, img2, SINTEL_RAW)
    assert math.isfinite(float(loss)) and stats["noc_fraction"] == 0.0


def test_range_map_counts_and_occlusion():
    flow = torch.zeros(1, 2, 6, 8)
    assert torch.allclose(range_map(flow), torch.ones(1, 1, 6, 8))
    flow[:, 0] = 2.0  # everything moves 2 px right: the 2 leftmost columns of the target get nothing
    count = range_map(flow)
    assert float(count[..., :2].abs().max()) == 0 and torch.allclose(count[..., 2:], torch.ones(1, 1, 6, 6))
    noc1, _ = non_occluded_by_range(torch.zeros_like(flow), flow)
    assert noc1[..., :2].sum() == 0 and noc1[..., 2:].min() == 1
    half = torch.zeros(1, 2, 6, 8)
    half[:, 0] = 0.5  # bilinear splatting: each target pixel gets half of two sources
    assert torch.allclose(range_map(half)[..., 1:], torch.ones(1, 1, 6, 7))


def test_forward_backward_check_marks_disagreement():
    fw = _const_flow(2, 0, (8, 8))
    bw = -fw.clone()
    bw[..., :4, :] = 3.0  # top half of frame 2 moves the wrong way
    noc1, noc2 = non_occluded_by_consistency(fw, bw)
    # bottom half agrees (except the 2 left columns, whose end points leave the image); top half does not
    assert noc2[..., 4:, 2:].min() == 1 and noc2[..., :4, :].max() == 0 and noc2[..., :, :2].max() == 0
    # pixels whose end point leaves the image see zero-padded flow: 4 > 0.01·4 + 0.5 → occluded
    assert noc1[..., :, -1].max() == 0


def test_ssim_and_smoothness_definitions():
    # float64: in float32 the variance terms E[x²] − E[x]² cancel to ~1e-4 differences between two
    # orderings of the same formula
    x = _image(3).double()
    y = _image(7).double()
    c1, c2 = 0.01**2, 0.03**2  # ARFlow's SSIM written with avg_pool2d, as in loss_blocks.py
    mx, my = F.avg_pool2d(x, 3, 1), F.avg_pool2d(y, 3, 1)
    sxy = F.avg_pool2d(x * y, 3, 1) - mx * my
    sx, sy = F.avg_pool2d(x * x, 3, 1) - mx * mx, F.avg_pool2d(y * y, 3, 1) - my * my
    ssim = (2 * mx * my + c1) * (2 * sxy + c2) / ((mx * mx + my * my + c1) * (sx + sy + c2))
    assert torch.allclose(ssim_loss(x, y), ((1 - ssim) / 2).clamp(0, 1), atol=1e-12)
    assert float(ssim_loss(x, x).abs().max()) < 1e-6
    assert ssim_loss(x, 1 - x).shape == (1, 3, 62, 94) and float(ssim_loss(x, 1 - x).mean()) > 0.1
    flat = torch.full((1, 3, 8, 8), 0.3)
    ramp = torch.arange(8.0).view(1, 1, 1, 8).expand(1, 2, 8, 8)
    # weights exp(0) = 1 on a flat image; |∂x F| = 1 everywhere, ∂y F = 0 → mean(1/2)/2 = 0.25
    assert smoothness(ramp, flat) == pytest.approx(0.25)
    assert smoothness(ramp, flat, second_order=True) == pytest.approx(0.0)
    edge = flat.clone()
    edge[..., 4:] = 0.9  # an image edge lowers the weight of the flow gradient across it
    assert smoothness(ramp, edge) < smoothness(ramp, flat)


def test_config_with_changes_and_level_check():
    cfg = FlowLossConfig().with_changes(w_l1=1.0, w_ssim=0.0)
    assert cfg.w_l1 == 1.0 and SINTEL_RAW.w_l1 == 0.15
    img = _image(4)
    with pytest.raises(ValueError, match="finest flow"):
        flow_loss(_pyramid(_const_flow(0, 0, (32, 48))), _pyramid(_const_flow(0, 0, (32, 48))), img, img)


def test_photometric_term_uses_warp_of_frame2():
    img1 = _image(5)
    flow = _const_flow(1.5, -0.5)
    img2 = _image(6)
    cfg = FlowLossConfig(w_l1=1.0, w_ssim=0.0, w_smooth=0.0, w_scales=(1, 0, 0, 0, 0))
    loss, _ = flow_loss(_pyramid(flow), _pyramid(-flow), img1, img2, cfg)
    noc1, noc2 = non_occluded_by_range(flow, -flow)
    l1 = ((img1 - warp(img2, flow)).abs() * noc1).mean() / noc1.mean()
    l2 = ((img2 - warp(img1, -flow)).abs() * noc2).mean() / noc2.mean()
    assert float(loss) == pytest.approx(float((l1 + l2) / 2), rel=1e-5)


def _reference(case: str):
    """ARFlow's own loss values (``arflow_loss_seed0.npz``, float64): images and the two flow pyramids."""
    ref = np.load(REF)
    x = torch.from_numpy(ref["input"]).double()
    flows = [torch.from_numpy(ref[f"flows_{case}_{i}"]).double() for i in range(5)]
    return ref, x[:, :3], x[:, 3:], [f[:, :2] for f in flows], [f[:, 2:] for f in flows]


@pytest.mark.parametrize("case", ["smooth", "model"])
def test_sintel_raw_equals_arflows_own_loss(case):
    """The pretraining setting: total, photometric sum over scales and λ·smoothness to 1e-6, same masks."""
    ref, img1, img2, fw, bw = _reference(case)
    loss, stats = flow_loss(fw, bw, img1, img2, SINTEL_RAW)
    assert float(loss) == pytest.approx(float(ref[f"sintel_raw_{case}_total"]), abs=1e-6)
    assert stats["photometric"] == pytest.approx(float(ref[f"sintel_raw_{case}_warp"]), abs=1e-6)
    assert 50 * stats["smooth"] == pytest.approx(float(ref[f"sintel_raw_{case}_smooth"]), abs=1e-6)
    for cfg, name in ((SINTEL_RAW, "sintel_raw"), (SINTEL_FT, "sintel_ft")):
        noc1, noc2 = non_occluded_masks(fw[0], bw[0], cfg)
        assert np.array_equal(noc1.numpy(), ref[f"{name}_{case}_occ_mask1_0"].reshape(noc1.shape))
        assert np.array_equal(noc2.numpy(), ref[f"{name}_{case}_occ_mask2_0"].reshape(noc2.shape))


def test_full_finetune_loss_is_arflows_sintel_ft():
    """Table 6's `full` variant, through the fine-tuning code path (``finetune.batch_loss``), is ARFlow's own
    ``sintel_ft`` loss: equal to ARFlow's values to 1e-6 where they are finite. On the random model's flows
    the forward–backward check marks every pixel occluded and ARFlow returns NaN (0/0); ours returns the
    smoothness term alone (photometric exactly 0), which equals ARFlow's finite smoothness value."""
    cfg = FinetuneConfig(loss="full", occlusion="forward_backward", smooth_weight=50.0)
    ref, img1, img2, fw, bw = _reference("smooth")
    loss, stats = batch_loss(fw, bw, img1, img2, None, None, cfg)
    assert float(loss) == pytest.approx(float(ref["sintel_ft_smooth_total"]), abs=1e-6)
    assert stats["photometric"] == pytest.approx(float(ref["sintel_ft_smooth_warp"]), abs=1e-6)
    assert 50 * stats["smooth"] == pytest.approx(float(ref["sintel_ft_smooth_smooth"]), abs=1e-6)
    assert stats["coverage"] == 1.0 and 0.9 < stats["noc_fraction"] < 1.0
    ref, img1, img2, fw, bw = _reference("model")
    assert math.isnan(float(ref["sintel_ft_model_total"])) and math.isnan(float(ref["sintel_ft_model_warp"]))
    loss, stats = batch_loss(fw, bw, img1, img2, None, None, cfg)
    assert math.isfinite(float(loss)) and stats["photometric"] == 0.0 and stats["noc_fraction"] == 0.0
    assert float(loss) == pytest.approx(float(ref["sintel_ft_model_smooth"]), abs=1e-6)
    # the CPU default's range map (ARFlow's warm-up check) keeps the photometric term of such flows alive
    loss_rm, stats_rm = batch_loss(fw, bw, img1, img2, None, None,
                                   FinetuneConfig(loss="full", occlusion="range_map", smooth_weight=50.0))
    assert stats_rm["photometric"] > 0 and stats_rm["noc_fraction"] > 0
    expect, _ = flow_loss(fw, bw, img1, img2, SINTEL_FT.with_changes(occ_from_back=True))
    assert float(loss_rm) == float(expect)


def test_range_map_of_a_non_finite_flow_lands_nowhere():
    flow = torch.zeros(1, 2, 4, 5)
    flow[0, 0, 1, 1] = float("nan")
    flow[0, 1, 2, 3] = float("inf")
    count = range_map(flow)
    assert torch.isfinite(count).all()
    assert count.sum() == pytest.approx(18.0)  # the 18 finite pixels stay where they are
    assert count[0, 0, 1, 1] == 0 and count[0, 0, 2, 3] == 0
