"""ARFlow's unsupervised flow loss (ARFlow's code, ``losses/flow_loss.py``), both directions, multi-scale.

Per output level i (finest first) with weight ``w_scales[i] > 0``: images area-resized to the level,
frame 2 warped to frame 1 by the forward flow (and frame 1 to frame 2 by the backward flow), a
photometric loss (``w_l1``·L1 + ``w_ssim``·SSIM + ``w_ternary``·census) over non-occluded pixels, and
edge-aware smoothness of the flow divided by ``min(H, W)`` of the finest level; forward and backward
terms are averaged. Occlusion comes from the finest level only (range map or forward–backward check,
no gradient) and is nearest-resized to the coarser levels.

Total = Σ_i w_scales[i]·L_ph,i + w_smooth·Σ_i w_sm_scales[i]·L_sm,i.

Departure from ARFlow, on purpose: ARFlow divides by the mean of the non-occluded mask, which is 0/0 =
NaN when every pixel is marked occluded (issue #21). Here the denominator is clamped to ``MASK_EPS``; the
numerator is exactly 0 in that case, so the photometric term becomes 0 and the loss stays finite.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Protocol

import torch
import torch.nn.functional as F

from f2depth.flow.census import census_distance
from f2depth.geometry import pixel_grid, warp

MASK_EPS = 1e-7


@dataclass(frozen=True)
class FlowLossConfig:
    """Weights of ARFlow's loss; defaults = ``sintel_raw`` (see :data:`SINTEL_RAW`, :data:`SINTEL_FT`)."""

    w_l1: float = 0.15
    w_ssim: float = 0.85
    w_ternary: float = 0.0
    occ_from_back: bool = True        # True: range map (UnOS); False: forward–backward consistency
    w_smooth: float = 50.0
    smooth_2nd: bool = False
    alpha: float = 10.0               # edge-awareness of the smoothness weights
    w_scales: tuple[float, ...] = (1.0, 1.0, 1.0, 1.0, 0.0)
    w_sm_scales: tuple[float, ...] = (1.0, 0.0, 0.0, 0.0, 0.0)
    warp_pad: str = "border"
    range_threshold: float = 0.2      # range map: occluded where the splatted count < this
    fb_scale: float = 0.01            # fw–bw check: |f12 + f21w|² > scale·(|f12|² + |f21w|²) + bias
    fb_bias: float = 0.5

    def with_changes(self, **changes) -> FlowLossConfig:
        return replace(self, **changes)


SINTEL_RAW = FlowLossConfig()
"""``configs/sintel_raw.json``: 0.15·L1 + 0.85·SSIM, range-map occlusion, 1st-order smoothness 50."""

SINTEL_FT = FlowLossConfig(w_l1=0.0, w_ssim=0.0, w_ternary=1.0, occ_from_back=False)
"""``configs/sintel_ft.json`` (and sintel_raw's ``stage1`` switch): census, forward–backward occlusion."""

def mean3x3(x: torch.Tensor) -> torch.Tensor:
    """3×3 box mean without padding, ``(B,C,H,W)`` → ``(B,C,H−2,W−2)``: ``avg_pool2d(x, 3, 1)`` computed
    with shifted sums (several times faster on CPU than PyTorch's NCHW pooling kernel)."""
    s = x[..., :, :-2] + x[..., :, 1:-1] + x[..., :, 2:]
    return (s[..., :-2, :] + s[..., 1:-1, :] + s[..., 2:, :]) / 9.0


def ssim_loss(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """ARFlow's SSIM loss: ``(B,C,H,W)`` ×2 → ``(B,C,H−2,W−2)`` clamp((1 − SSIM)/2, 0, 1), 3×3 windows."""
    c1, c2 = 0.01**2, 0.03**2
    mu_x, mu_y, m_xx, m_yy, m_xy = mean3x3(torch.cat([x, y, x * x, y * y, x * y], 1)).chunk(5, 1)
    sigma_x = m_xx - mu_x * mu_x
    sigma_y = m_yy - mu_y * mu_y
    sigma_xy = m_xy - mu_x * mu_y
    num = (2 * mu_x * mu_y + c1) * (2 * sigma_xy + c2)
    den = (mu_x * mu_x + mu_y * mu_y + c1) * (sigma_x + sigma_y + c2)
    return torch.clamp((1 - num / den) / 2, 0, 1)


def _dx(x: torch.Tensor) -> torch.Tensor:
    return x[..., :, 1:] - x[..., :, :-1]


def _dy(x: torch.Tensor) -> torch.Tensor:
    return x[..., 1:, :] - x[..., :-1, :]


def smoothness(flow: torch.Tensor, img: torch.Tensor, alpha: float = 10.0, second_order: bool = False
               ) -> torch.Tensor:
    """Edge-aware smoothness (scalar) of ``flow (B,2,H,W)`` given ``img (B,3,H,W)`` in [0,1].

    Weights ``exp(−alpha·mean_c|∂I|)``; 1st order: ``mean(w_x|∂x F|/2)/2 + mean(w_y|∂y F|/2)/2``;
    2nd order: ``mean(w_x|∂x² F|)/2 + mean(w_y|∂y² F|)/2`` (ARFlow smooth_grad_1st / _2nd).
    """
    wx = torch.exp(-alpha * _dx(img).abs().mean(1, keepdim=True))
    wy = torch.exp(-alpha * _dy(img).abs().mean(1, keepdim=True))
    if second_order:
        lx = (wx[..., :, 1:] * _dx(_dx(flow)).abs()).mean()
        ly = (wy[..., 1:, :] * _dy(_dy(flow)).abs()).mean()
        return lx / 2 + ly / 2
    return (wx * _dx(flow).abs() / 2).mean() / 2 + (wy * _dy(flow).abs() / 2).mean() / 2


@torch.no_grad()
def range_map(flow: torch.Tensor) -> torch.Tensor:
    """How much of frame A lands on each pixel of frame B: ``flow (B,2,H,W)`` A → B → count ``(B,1,H,W)``
    on B's grid, by forward-splatting every pixel of A to ``p + flow(p)`` with bilinear weights
    (neighbours outside the image get no weight; a non-finite flow lands nowhere, so the loss it makes is
    non-finite and the step is skipped, not an index error)."""
    b, _, h, w = flow.shape
    pos = pixel_grid(h, w, flow.dtype, flow.device) + flow
    pos = torch.nan_to_num(pos, nan=-2.0, posinf=-2.0, neginf=-2.0)
    x, y = pos[:, 0].reshape(b, -1), pos[:, 1].reshape(b, -1)
    x0, y0 = torch.floor(x), torch.floor(y)
    count = flow.new_zeros(b, h * w)
    for xn in (x0, x0 + 1):
        for yn in (y0, y0 + 1):
            xc, yc = xn.clamp(0, w - 1), yn.clamp(0, h - 1)
            inside = (xc == xn) & (yc == yn)
            weight = (1 - (x - xn).abs()) * (1 - (y - yn).abs()) * inside
            idx = (yc * w + xc).long()
            count.scatter_add_(1, idx, weight)
    return count.view(b, 1, h, w)


@torch.no_grad()
def non_occluded_by_range(flow_fw: torch.Tensor, flow_bw: torch.Tensor, threshold: float = 0.2
                          ) -> tuple[torch.Tensor, torch.Tensor]:
    """Range-map occlusion (UnOS): non-occluded masks ``(B,1,H,W)`` float of frame 1 (from the backward
    flow) and frame 2 (from the forward flow); 1 = visible in the other frame."""
    noc1 = (range_map(flow_bw).clamp(0, 1) >= threshold).to(flow_fw.dtype)
    noc2 = (range_map(flow_fw).clamp(0, 1) >= threshold).to(flow_fw.dtype)
    return noc1, noc2


@torch.no_grad()
def non_occluded_by_consistency(flow_fw: torch.Tensor, flow_bw: torch.Tensor, scale: float = 0.01,
                                bias: float = 0.5) -> tuple[torch.Tensor, torch.Tensor]:
    """Forward–backward check: frame 1 pixel is occluded where ``|f12 + f21(p + f12)|² > scale·(|f12|² +
    |f21(p + f12)|²) + bias`` (f21 warped with zero padding); symmetric for frame 2. → two ``(B,1,H,W)``."""

    def visible(f: torch.Tensor, g: torch.Tensor) -> torch.Tensor:
        g_w = warp(g, f, padding="zeros")
        mag = (f * f).sum(1, keepdim=True) + (g_w * g_w).sum(1, keepdim=True)
        diff = ((f + g_w) ** 2).sum(1, keepdim=True)
        return (diff <= scale * mag + bias).to(f.dtype)

    return visible(flow_fw, flow_bw), visible(flow_bw, flow_fw)


class OcclusionSettings(Protocol):
    """What decides occlusion, shared by ARFlow's loss (:class:`FlowLossConfig`) and the patch loss
    (:class:`f2depth.flow.patch_loss.FinetuneLossConfig`)."""

    occ_from_back: bool       # True: the range map (UnOS); False: the forward–backward check
    range_threshold: float
    fb_scale: float
    fb_bias: float


def non_occluded_masks(flow_fw: torch.Tensor, flow_bw: torch.Tensor, cfg: OcclusionSettings
                       ) -> tuple[torch.Tensor, torch.Tensor]:
    """The non-occluded masks of frames 1 and 2 ``(B,1,H,W)`` for the finest flows ``(B,2,H,W)`` pixels, x
    first, per ``cfg`` — the one occlusion decision of both flow losses."""
    if cfg.occ_from_back:
        return non_occluded_by_range(flow_fw, flow_bw, cfg.range_threshold)
    return non_occluded_by_consistency(flow_fw, flow_bw, cfg.fb_scale, cfg.fb_bias)


def photometric(img: torch.Tensor, img_rec: torch.Tensor, mask: torch.Tensor, cfg: FlowLossConfig
                ) -> torch.Tensor:
    """ARFlow loss_photomatric: Σ of the weighted term means divided by mean(mask) (clamped, see module)."""
    terms = []
    if cfg.w_l1 > 0:
        terms.append(cfg.w_l1 * ((img - img_rec).abs() * mask).mean())
    if cfg.w_ssim > 0:
        terms.append(cfg.w_ssim * ssim_loss(img_rec * mask, img * mask).mean())
    if cfg.w_ternary > 0:
        terms.append(cfg.w_ternary * census_distance(img_rec * mask, img * mask).mean())
    if not terms:
        return img.new_zeros(())
    return sum(terms) / mask.mean().clamp_min(MASK_EPS)


def flow_loss(flows_fw: list[torch.Tensor], flows_bw: list[torch.Tensor], img1: torch.Tensor,
              img2: torch.Tensor, cfg: FlowLossConfig = SINTEL_RAW) -> tuple[torch.Tensor, dict[str, float]]:
    """ARFlow's unsupervised loss of a PWC-Lite output.

    ``flows_fw, flows_bw``: five ``(B,2,h_i,w_i)`` flows each, finest first (finest at the image size), in
    pixels of their level; ``img1, img2 (B,3,H,W)`` in [0,1]. Returns ``(loss, {"loss", "photometric",
    "smooth", "flow_mean", "noc_fraction"})``.
    """
    if len(cfg.w_scales) < len(flows_fw) or len(cfg.w_sm_scales) < len(flows_fw):
        raise ValueError(f"flow_loss: {len(flows_fw)} flow levels but w_scales has {len(cfg.w_scales)}")
    if flows_fw[0].shape[-2:] != img1.shape[-2:]:
        raise ValueError(f"flow_loss: finest flow {tuple(flows_fw[0].shape)} must match the images "
                         f"{tuple(img1.shape)}")
    noc1, noc2 = non_occluded_masks(flows_fw[0].detach(), flows_bw[0].detach(), cfg)
    s = float(min(img1.shape[-2:]))
    total_ph = img1.new_zeros(())
    total_sm = img1.new_zeros(())
    for i, (f12, f21) in enumerate(zip(flows_fw, flows_bw)):
        w_ph, w_sm = cfg.w_scales[i], cfg.w_sm_scales[i]
        if w_ph == 0 and w_sm == 0:
            continue
        size = f12.shape[-2:]
        im1 = img1 if i == 0 else F.interpolate(img1, size=size, mode="area")
        im2 = img2 if i == 0 else F.interpolate(img2, size=size, mode="area")
        if w_ph > 0:
            m1 = noc1 if i == 0 else F.interpolate(noc1, size=size, mode="nearest")
            m2 = noc2 if i == 0 else F.interpolate(noc2, size=size, mode="nearest")
            l_ph = photometric(im1, warp(im2, f12, cfg.warp_pad), m1, cfg)
            l_ph = l_ph + photometric(im2, warp(im1, f21, cfg.warp_pad), m2, cfg)
            total_ph = total_ph + w_ph * l_ph / 2
        if w_sm > 0:
            l_sm = smoothness(f12 / s, im1, cfg.alpha, cfg.smooth_2nd)
            l_sm = l_sm + smoothness(f21 / s, im2, cfg.alpha, cfg.smooth_2nd)
            total_sm = total_sm + w_sm * l_sm / 2
    loss = total_ph + cfg.w_smooth * total_sm
    stats = {"loss": float(loss.detach()), "photometric": float(total_ph.detach()),
             "smooth": float(total_sm.detach()), "flow_mean": float(flows_fw[0].detach().abs().mean()),
             "noc_fraction": float(noc1.mean())}
    return loss, stats
