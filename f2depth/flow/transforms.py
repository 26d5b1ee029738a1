"""ARFlow's AR self-supervision (ARFlow's code, ``trainer/sintel_trainer_ar.py``,
``transforms/ar_transforms/``): appearance and spatial transforms of an image pair, the matching
transform of a teacher flow and its non-occluded mask, and the AR loss.

The first pass of the network on the original pair gives ``flow_ori`` and ``noc_ori`` (detached); the pair
is then transformed, the network runs again on it, and its finest forward flow is pulled towards the
transformed teacher flow on the transformed non-occluded mask::

    l_ar = ((|flow_t_pred − flow_t| + eps)^q · noc_t).mean() / (noc_t.mean() + 1e-7)

Appearance transform (same random parameters for both frames, per sample): colour jitter
(brightness, contrast, saturation factors in [1 − s, 1 + s], applied in a random order; contrast blends
with the mean grey level, saturation with the grey image), Gaussian blur with probability ``blur_p``
and sigma U(0, ``blur_radius``), gamma U(``gamma``), clipped to [0, 1].

Spatial transform (IRR's RandomAffineFlow as ARFlow describes it; the exact parametrisation of zoom and
squeeze is ours): in normalised coordinates (align_corners=True) an output point q samples frame 1 at
``T1(q) = R(θ)·diag(1/(z·s), 1/z)·q + t`` and frame 2 at ``T2 = T1 ∘ T_rel`` with a small relative affine
of the same form; parameters are redrawn until the four image corners map inside both frames;
horizontal / vertical mirroring is a sign flip of q shared by both frames. The teacher flow becomes
``T2⁻¹(T1(q) + flow(T1(q))) − q`` (in pixels), the mask is resampled bilinearly (soft), and Gaussian
noise with std U(0, ``noise``) is added to both images before clipping.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F

from f2depth.flow.census import GREY_WEIGHTS


@dataclass(frozen=True)
class AppearanceConfig:
    brightness: float = 0.5
    contrast: float = 0.5
    saturation: float = 0.5
    blur_p: float = 0.5
    blur_radius: float = 3.0
    gamma: tuple[float, float] | None = (0.7, 1.5)


@dataclass(frozen=True)
class SpatialConfig:
    """Ranges (low, high) of uniform draws; ``rel_*`` for frame 2's affine relative to frame 1's."""

    zoom: tuple[float, float] = (1.0, 1.5)
    squeeze: tuple[float, float] = (0.86, 1.16)
    rotate: tuple[float, float] = (-0.2, 0.2)          # radians
    translate: tuple[float, float] = (-0.1, 0.1)       # in [-1, 1] image coordinates
    rel_zoom: tuple[float, float] = (0.985, 1.015)
    rel_squeeze: tuple[float, float] = (1.0, 1.0)
    rel_rotate: tuple[float, float] = (-0.015, -0.015)  # ARFlow quirk: always rotate[2] (sp_transfroms.py)
    rel_translate: tuple[float, float] = (-0.0075, 0.0075)
    hflip: bool = True
    vflip: bool = True
    noise: float = 0.04
    max_tries: int = 50


@dataclass(frozen=True)
class ARConfig:
    appearance: AppearanceConfig = AppearanceConfig()
    spatial: SpatialConfig = SpatialConfig()
    eps: float = 0.0
    q: float = 1.0
    weight: float = 0.01


SINTEL_AR = ARConfig()
"""``sintel_ft_ar.json``: Sintel colour jitter, blur, gamma and affine ranges; L1 AR loss, weight 0.01."""

KITTI_AR = ARConfig(
    appearance=AppearanceConfig(contrast=0.0, saturation=0.0, gamma=None),
    spatial=SpatialConfig(zoom=(1.0, 1.4), squeeze=(1.0, 1.0), rotate=(-0.01, 0.01), translate=(-0.02, 0.02),
                          rel_zoom=(0.99, 1.01), rel_rotate=(-0.01, -0.01), rel_translate=(-0.0025, 0.0025),
                          vflip=False),
    weight=0.02,
)
"""``kitti15_ft_ar.json``: brightness jitter only, no gamma; smaller affine ranges, no vertical flip; 0.02."""


def _uniform(lo_hi: tuple[float, float], n: int, gen: torch.Generator | None) -> torch.Tensor:
    lo, hi = lo_hi
    return lo + (hi - lo) * torch.rand(n, generator=gen, dtype=torch.float64)


def _grey(img: torch.Tensor) -> torch.Tensor:
    w = img.new_tensor(GREY_WEIGHTS).view(1, 3, 1, 1)
    return (img * w).sum(1, keepdim=True)


def _gaussian_blur(img: torch.Tensor, sigma: float) -> torch.Tensor:
    radius = max(1, math.ceil(3 * sigma))
    x = torch.arange(-radius, radius + 1, dtype=img.dtype, device=img.device)
    k = torch.exp(-0.5 * (x / sigma) ** 2)
    k = k / k.sum()
    c = img.shape[1]
    pad = F.pad(img, (radius, radius, radius, radius), mode="replicate")
    out = F.conv2d(pad, k.view(1, 1, 1, -1).expand(c, 1, 1, -1), groups=c)
    return F.conv2d(out, k.view(1, 1, -1, 1).expand(c, 1, -1, 1), groups=c)


def appearance_transform(imgs: list[torch.Tensor], cfg: AppearanceConfig = AppearanceConfig(),
                         generator: torch.Generator | None = None) -> list[torch.Tensor]:
    """Photometric jitter of frames ``(B,3,H,W)`` in [0,1], the same per-sample parameters for all frames."""
    b = imgs[0].shape[0]
    out = [x.clone() for x in imgs]
    for i in range(b):
        ops = []
        for name, strength in (("brightness", cfg.brightness), ("contrast", cfg.contrast),
                               ("saturation", cfg.saturation)):
            if strength > 0:
                ops.append((name, float(_uniform((max(0.0, 1 - strength), 1 + strength), 1, generator))))
        order = torch.randperm(len(ops), generator=generator).tolist()
        blur = float(torch.rand(1, generator=generator)) < cfg.blur_p
        sigma = float(_uniform((0.0, cfg.blur_radius), 1, generator))
        gamma = float(_uniform(cfg.gamma, 1, generator)) if cfg.gamma else None
        for frame in out:
            x = frame[i : i + 1]
            for k in order:
                name, f = ops[k]
                if name == "brightness":
                    x = (x * f).clamp(0, 1)
                elif name == "contrast":
                    x = (f * x + (1 - f) * _grey(x).mean()).clamp(0, 1)
                else:
                    x = (f * x + (1 - f) * _grey(x)).clamp(0, 1)
            if blur and sigma > 0.05:
                x = _gaussian_blur(x, sigma)
            if gamma is not None:
                x = x.clamp(0, 1) ** gamma
            frame[i : i + 1] = x.clamp(0, 1)
    return out


def _affine(zoom: torch.Tensor, squeeze: torch.Tensor, angle: torch.Tensor, tx: torch.Tensor,
            ty: torch.Tensor) -> torch.Tensor:
    """(n,3,3) homogeneous maps q → R(angle)·diag(1/(zoom·squeeze), 1/zoom)·q + t."""
    n = zoom.shape[0]
    cos, sin = torch.cos(angle), torch.sin(angle)
    sx, sy = 1 / (zoom * squeeze), 1 / zoom
    m = torch.zeros(n, 3, 3, dtype=torch.float64)
    m[:, 0, 0], m[:, 0, 1], m[:, 0, 2] = cos * sx, -sin * sy, tx
    m[:, 1, 0], m[:, 1, 1], m[:, 1, 2] = sin * sx, cos * sy, ty
    m[:, 2, 2] = 1
    return m


def _corners_inside(m: torch.Tensor) -> torch.Tensor:
    corners = torch.tensor([[-1, -1, 1], [1, -1, 1], [-1, 1, 1], [1, 1, 1]], dtype=torch.float64).T
    mapped = m @ corners
    return (mapped[:, :2].abs() <= 1 + 1e-9).all(-1).all(-1)


def sample_affines(n: int, cfg: SpatialConfig, generator: torch.Generator | None = None
                   ) -> tuple[torch.Tensor, torch.Tensor]:
    """Draw ``n`` pairs (T1, T2) of (3,3) float64 maps (output → input normalised coordinates) with all
    four corners inside both frames; identity after ``cfg.max_tries`` failed draws."""
    t1 = torch.eye(3, dtype=torch.float64).repeat(n, 1, 1)
    t2 = t1.clone()
    todo = torch.ones(n, dtype=torch.bool)
    for _ in range(cfg.max_tries):
        k = int(todo.sum())
        if k == 0:
            break
        g = _affine(_uniform(cfg.zoom, k, generator), _uniform(cfg.squeeze, k, generator),
                    _uniform(cfg.rotate, k, generator), _uniform(cfg.translate, k, generator),
                    _uniform(cfg.translate, k, generator))
        r = _affine(_uniform(cfg.rel_zoom, k, generator), _uniform(cfg.rel_squeeze, k, generator),
                    _uniform(cfg.rel_rotate, k, generator), _uniform(cfg.rel_translate, k, generator),
                    _uniform(cfg.rel_translate, k, generator))
        g2 = g @ r
        ok = _corners_inside(g) & _corners_inside(g2)
        idx = todo.nonzero().squeeze(1)[ok]
        t1[idx], t2[idx] = g[ok], g2[ok]
        todo[idx] = False
    flips = torch.ones(n, 2, dtype=torch.float64)
    if cfg.hflip:
        flips[:, 0] = torch.where(torch.rand(n, generator=generator) < 0.5, -1.0, 1.0)
    if cfg.vflip:
        flips[:, 1] = torch.where(torch.rand(n, generator=generator) < 0.5, -1.0, 1.0)
    flip = torch.diag_embed(torch.cat([flips, torch.ones(n, 1, dtype=torch.float64)], 1))
    return t1 @ flip, t2 @ flip


def _apply(m: torch.Tensor, pts: torch.Tensor) -> torch.Tensor:
    """(B,3,3) maps applied to points (B,N,2) → (B,N,2)."""
    return pts @ m[:, :2, :2].transpose(1, 2) + m[:, :2, 2].unsqueeze(1)


def spatial_transform(img1: torch.Tensor, img2: torch.Tensor, flow: torch.Tensor, mask: torch.Tensor,
                      cfg: SpatialConfig = SpatialConfig(), generator: torch.Generator | None = None
                      ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Random affine of a pair: ``img1, img2 (B,3,H,W)``, teacher ``flow (B,2,H,W)`` pixels 1→2 and its
    non-occluded ``mask (B,1,H,W)`` → the four transformed consistently (see module docstring)."""
    b, _, h, w = img1.shape
    dev, dt = img1.device, img1.dtype
    t1, t2 = (t.to(dev) for t in sample_affines(b, cfg, generator))
    ys, xs = torch.meshgrid(torch.linspace(-1, 1, h, dtype=torch.float64, device=dev),
                            torch.linspace(-1, 1, w, dtype=torch.float64, device=dev), indexing="ij")
    q = torch.stack([xs, ys], -1).view(1, -1, 2).expand(b, -1, -1)
    p1 = _apply(t1, q)
    grid1 = p1.view(b, h, w, 2).to(dt)
    grid2 = _apply(t2, q).view(b, h, w, 2).to(dt)
    new1 = F.grid_sample(img1, grid1, mode="bilinear", padding_mode="border", align_corners=True)
    new2 = F.grid_sample(img2, grid2, mode="bilinear", padding_mode="border", align_corners=True)
    new_mask = F.grid_sample(mask, grid1, mode="bilinear", padding_mode="zeros", align_corners=True)
    # teacher flow at T1(q) in normalised units, its end point mapped back through T2⁻¹
    to_norm = torch.tensor([2.0 / max(w - 1, 1), 2.0 / max(h - 1, 1)], dtype=torch.float64, device=dev)
    f = F.grid_sample(flow, grid1, mode="bilinear", padding_mode="border", align_corners=True)
    f = f.permute(0, 2, 3, 1).reshape(b, -1, 2).to(torch.float64) * to_norm
    q2 = _apply(torch.linalg.inv(t2), p1 + f)
    new_flow = ((q2 - q) / to_norm).view(b, h, w, 2).permute(0, 3, 1, 2).to(dt).contiguous()
    if cfg.noise > 0:
        std = (torch.rand(b, 1, 1, 1, generator=generator) * cfg.noise).to(device=dev, dtype=dt)
        noise1 = torch.randn(new1.shape, generator=generator).to(device=dev, dtype=dt)
        noise2 = torch.randn(new2.shape, generator=generator).to(device=dev, dtype=dt)
        new1 = (new1 + std * noise1).clamp(0, 1)
        new2 = (new2 + std * noise2).clamp(0, 1)
    return new1, new2, new_flow, new_mask


def ar_loss(model: torch.nn.Module, img1: torch.Tensor, img2: torch.Tensor, flow_ori: torch.Tensor,
            noc_ori: torch.Tensor, cfg: ARConfig = SINTEL_AR, generator: torch.Generator | None = None
            ) -> tuple[torch.Tensor, dict[str, float]]:
    """Weighted AR loss ``cfg.weight · l_ar`` of ``model`` (a FlowNetwork) on a transformed copy of the pair.

    ``flow_ori (B,2,H,W)`` and ``noc_ori (B,1,H,W)`` are the first pass's finest forward flow and
    non-occluded mask; both are detached here.
    """
    a1, a2 = appearance_transform([img1, img2], cfg.appearance, generator)
    t1, t2, flow_t, noc_t = spatial_transform(a1, a2, flow_ori.detach(), noc_ori.detach(), cfg.spatial,
                                              generator)
    pred = model(t1, t2, with_backward=False)[0][0]
    err = ((pred - flow_t).abs() + cfg.eps) ** cfg.q
    l_ar = (err * noc_t).mean() / (noc_t.mean() + 1e-7)
    loss = cfg.weight * l_ar
    return loss, {"ar": float(l_ar.detach()), "ar_weighted": float(loss.detach())}
