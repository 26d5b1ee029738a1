"""P²Net's patch-based multi-view photometric loss L_ph (P²Net's ``trainer_geo.py``, ``layers.py``).

For every target point p (DSO keypoints filled up with uniform random points) a fronto-parallel patch of
9 samples at offsets {−2, 0, 2}² shares the centre's depth D(p): ``X_k = D(p)·K⁻¹·[u+dx, v+dy, 1]ᵀ``.
The samples are projected into each source with ``K·src_T_tgt`` and read bilinearly (border padding,
align_corners=True). Per point and source ``ρ = 0.85·SSIM_9 + 0.15·L1`` (both averaged over the three
channels; L1 also over the 9 samples); the loss is the mean over points of the minimum over sources.
No auto-mask and no out-of-view mask, as P²Net.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from f2depth.geometry import PROJ_EPS, patch_offsets
from f2depth.losses.ssim import ssim_samples

#: P²Net's patch: the 9 samples at offsets {−2, 0, 2}² (:func:`f2depth.geometry.patch_offsets`).
PATCH_SPACING = 2
SSIM_WEIGHT = 0.85


def sample_points(img: torch.Tensor, pix: torch.Tensor) -> torch.Tensor:
    """Bilinear, border-padded, align_corners=True sampling at pixel positions.

    img (B,C,H,W), pix (B,N,S,2) pixels, x first → (B,C,N,S).
    """
    h, w = img.shape[-2:]
    gx = 2.0 * pix[..., 0] / max(w - 1, 1) - 1.0
    gy = 2.0 * pix[..., 1] / max(h - 1, 1) - 1.0
    grid = torch.stack((gx, gy), dim=-1)
    return F.grid_sample(img, grid, mode="bilinear", padding_mode="border", align_corners=True)


def centre_depth(depth: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """Depth at the integer keypoints: depth (B,1,H,W), points (B,N,2) x first (rounded, clamped
    into the image) → (B,N)."""
    b, _, h, w = depth.shape
    idx = torch.round(points.detach()).long()
    x = idx[..., 0].clamp(0, w - 1)
    y = idx[..., 1].clamp(0, h - 1)
    return torch.gather(depth.reshape(b, h * w), 1, y * w + x)


def patch_samples(points: torch.Tensor) -> torch.Tensor:
    """The positions of P²Net's patch samples: integer centres plus the 9 offsets, points (B,N,2) → (B,N,9,2)
    pixels, x first."""
    centres = torch.round(points.detach())
    return centres.unsqueeze(2) + patch_offsets(PATCH_SPACING, points.dtype, points.device)


def project_patches(
    depth_c: torch.Tensor, pix_t: torch.Tensor, K: torch.Tensor, src_T_tgt: torch.Tensor
) -> torch.Tensor:
    """Project target patch samples at the centres' depth into a source.

    depth_c (B,N), pix_t (B,N,9,2) target pixels, K (B,3,3), src_T_tgt (B,4,4) → (B,N,9,2) source pixels.
    """
    b, n, s, _ = pix_t.shape
    ones = torch.ones_like(pix_t[..., :1])
    pix_h = torch.cat((pix_t, ones), dim=-1).reshape(b, n * s, 3).transpose(1, 2)  # (B,3,NS)
    rays = torch.matmul(torch.linalg.inv(K), pix_h)
    X = rays * depth_c.unsqueeze(-1).expand(b, n, s).reshape(b, 1, n * s)
    P = torch.matmul(K, torch.matmul(src_T_tgt[:, :3, :3], X) + src_T_tgt[:, :3, 3:4])
    pix_s = P[:, :2] / (P[:, 2:3] + PROJ_EPS)
    return pix_s.transpose(1, 2).reshape(b, n, s, 2)


def patch_errors(target_patch: torch.Tensor, source_patch: torch.Tensor) -> torch.Tensor:
    """ρ per point: patches (B,C,N,9) → (B,N) = 0.85·mean_c SSIM_9 + 0.15·mean_{c,9} |·|."""
    l1 = (source_patch - target_patch).abs().mean(dim=(1, 3))
    ssim = ssim_samples(source_patch, target_patch, dim=-1).mean(dim=1)
    return SSIM_WEIGHT * ssim + (1 - SSIM_WEIGHT) * l1


def patch_photometric_errors(
    target: torch.Tensor,
    sources: list[torch.Tensor],
    depth: torch.Tensor,
    K: torch.Tensor,
    src_T_tgt: list[torch.Tensor],
    points: torch.Tensor,
) -> torch.Tensor:
    """Per-point, per-source errors ρ.

    target (B,3,H,W), sources list of S (B,3,H,W) images (un-augmented, [0, 1]), depth (B,1,H,W) target
    depth in metres, K (B,3,3), src_T_tgt list of S (B,4,4), points (B,N,2) target pixels, x first
    (rounded to integers) → (B,S,N).
    """
    if len(sources) != len(src_T_tgt) or not sources:
        raise ValueError(f"need one src_T_tgt per source, got {len(sources)} sources, {len(src_T_tgt)} poses")
    pix_t = patch_samples(points.to(depth.dtype))
    target_patch = sample_points(target, pix_t)
    depth_c = centre_depth(depth, points)
    errors = []
    for src, T in zip(sources, src_T_tgt):
        pix_s = project_patches(depth_c, pix_t, K, T)
        errors.append(patch_errors(target_patch, sample_points(src, pix_s)))
    return torch.stack(errors, dim=1)


def patch_photometric_loss(
    target: torch.Tensor,
    sources: list[torch.Tensor],
    depth: torch.Tensor,
    K: torch.Tensor,
    src_T_tgt: list[torch.Tensor],
    points: torch.Tensor,
) -> torch.Tensor:
    """L_ph = mean over batch and points of min over sources of ρ (shapes as ``patch_photometric_errors``).

    Returns a scalar tensor.
    """
    errors = patch_photometric_errors(target, sources, depth, K, src_T_tgt, points)
    return errors.min(dim=1).values.mean()
