"""F²Depth's flow fine-tuning loss (paper §3.1, SPEC §4.3): census distance at the pixels of 3×3 patches
around the target's DSO keypoints (``patch``) or at every pixel (``full``, for Table 6), plus ARFlow's
first-order edge-aware smoothness.

For the forward flow ``f = f(t→s)`` of a target/source pair and a set of target pixels ``S``::

    L_flow = Σ_{p∈S'} D(p) / |S'| + λ · L_sm(f),     S' = {p ∈ S : p not occluded, 1 ≤ x ≤ W−2, 1 ≤ y ≤ H−2}

``patch``: ``S = ∪_k {(x_k + i, y_k + j) : i, j ∈ {−N, 0, N}}`` over the keypoints of the target (N =
``spacing``, 2 in the paper). ``full``: every pixel. Occlusion is ARFlow's forward–backward check on the
detached flows (``|f + f_bw(p + f)|² > 0.01·(|f|² + |f_bw(p + f)|²) + 0.5``). ``λ·L_sm`` is ARFlow's
``smooth_grad_1st`` of ``f / min(H, W)`` weighted by ``exp(−10·|∂I_t|)``, as in ARFlow's loss.

Decisions (documented because the paper leaves them open):

* **Each pixel counts once.** ``S`` is a *set*: a pixel covered by several (overlapping or duplicate)
  patches enters the average once, exactly as multiplying ARFlow's occlusion mask by a binary patch mask
  would. Duplicate keypoints (frequent at small sizes, docs/keypoints.md) therefore do not weigh double.
* **The average runs over the whole batch** (ARFlow divides the masked sum by the mask's mean over the
  batch): images with more usable patch pixels weigh more; an image without keypoints, or whose patch
  pixels are all occluded, adds nothing. With no usable pixel at all the photometric term is exactly 0.
* **Census window moves with the pixel's own flow.** ``D(p)`` is ARFlow's ternary census distance
  (research/arflow.md §4: grey ``255·(0.2989, 0.587, 0.114)``, 3×3 window incl. the centre,
  ``t = Δ/√(0.81 + Δ²)``, ``d = (t_t − t_s)²``, ``mean d/(0.1 + d)``) between the target's window at ``p``
  and the source's window at ``p + f(p)``: the source grey image is sampled bilinearly (border padding,
  align_corners=True) at ``p + o + f(p)`` for the 9 offsets ``o``. ARFlow instead warps the whole source
  first, so its window uses the neighbours' flows ``f(p + o)``; both agree wherever the flow is constant
  over the 3×3 window, and this form makes the loss depend on the flow **only at the pixels of S**
  (the paper's "only patch pixels are used"). It is computed only at the gathered pixels (no dense map):
  ``9·|S|`` bilinear samples of one grey channel.
* The one-pixel image border (where ARFlow's census is defined as 0) is left out of ``S`` and of the
  denominator. Images are not multiplied by the occlusion mask before the census (ARFlow does that); the
  mask is applied to the distances. ``full`` uses the same code, so the two variants differ only in ``S``.
* Single scale: the finest (input-resolution) flow only, target → source only (the keypoints belong to
  the target); the backward flow serves the occlusion check alone.
* ``occlusion="range_map"`` swaps the forward–backward check for ARFlow's range map (UnOS; research/arflow.md
  §3.2), which ARFlow uses to warm up because the forward–backward check marks every pixel occluded while
  the flow is still degenerate (e.g. a constant flow, where forward = backward). Default: the paper's check.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import torch
import torch.nn.functional as F

from f2depth.flow.census import grey255
from f2depth.flow.loss import non_occluded_by_consistency, non_occluded_by_range, smoothness

PIXEL_SETS = ("patch", "full")
OCCLUSION_CHECKS = ("forward_backward", "range_map")
CENSUS_BORDER = 1


@dataclass(frozen=True)
class FinetuneLossConfig:
    """``pixels``: ``"patch"`` (F²Depth) or ``"full"`` (ARFlow's all-pixel census); ``spacing`` = N."""

    pixels: str = "patch"
    spacing: int = 2
    smooth_weight: float = 50.0       # λ = lambda_flow_smooth
    alpha: float = 10.0               # edge-awareness of the smoothness weights (ARFlow)
    occlusion: str = "forward_backward"  # or "range_map" (ARFlow's warm-up check)
    fb_scale: float = 0.01            # forward–backward occlusion check (ARFlow)
    fb_bias: float = 0.5
    range_threshold: float = 0.2      # range map: occluded where the splatted count is below this

    def __post_init__(self) -> None:
        if self.pixels not in PIXEL_SETS:
            raise ValueError(f"FinetuneLossConfig.pixels must be one of {PIXEL_SETS}, got {self.pixels!r}")
        if self.occlusion not in OCCLUSION_CHECKS:
            raise ValueError(f"FinetuneLossConfig.occlusion must be one of {OCCLUSION_CHECKS}, "
                             f"got {self.occlusion!r}")
        if self.spacing < 1:
            raise ValueError(f"FinetuneLossConfig.spacing must be >= 1, got {self.spacing}")


def patch_offsets(spacing: int = 2) -> torch.Tensor:
    """``(9, 2)`` int64 offsets ``(dx, dy)`` of ``{−N, 0, N}²``, row-major (dy outer), centre at index 4."""
    r = (-spacing, 0, spacing)
    return torch.tensor([(dx, dy) for dy in r for dx in r], dtype=torch.int64)


def pad_keypoints(points: Sequence[torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-image keypoints ``(n_i, ≥2)`` (x, y first) → ``(B,K,2)`` int64 padded with zeros and a ``(B,K)``
    bool mask of the real ones; ``K = max(1, max n_i)``."""
    k = max([1, *(len(p) for p in points)])
    kp = torch.zeros(len(points), k, 2, dtype=torch.int64)
    mask = torch.zeros(len(points), k, dtype=torch.bool)
    for i, p in enumerate(points):
        n = len(p)
        if n:
            kp[i, :n] = torch.as_tensor(p)[:, :2].to(torch.int64)
            mask[i, :n] = True
    return kp, mask


def patch_pixels(keypoints: torch.Tensor, mask: torch.Tensor, height: int, width: int, spacing: int = 2,
                 border: int = CENSUS_BORDER) -> tuple[torch.Tensor, torch.Tensor]:
    """The patch pixel set of every image, as flat indices.

    ``keypoints (B,K,2)`` integer pixels x first, ``mask (B,K)`` bool → ``idx (B,9K)`` int64 ``y·W + x`` and
    ``valid (B,9K)`` bool. Each pixel of the union of the patches that lies at least ``border`` pixels
    inside the image is valid exactly once (duplicates and pixels outside are invalid; their ``idx`` is
    clamped into the image and must be ignored).
    """
    b = keypoints.shape[0]
    off = patch_offsets(spacing).to(keypoints.device)
    pix = keypoints[:, :, None, :].to(torch.int64) + off                      # (B,K,9,2)
    x, y = pix[..., 0], pix[..., 1]
    inside = (mask[:, :, None] & (x >= border) & (x <= width - 1 - border)
              & (y >= border) & (y <= height - 1 - border))
    sentinel = height * width
    flat = torch.where(inside, y * width + x, torch.full_like(x, sentinel)).reshape(b, -1)
    flat, _ = flat.sort(dim=1)
    first = torch.ones_like(flat, dtype=torch.bool)
    first[:, 1:] = flat[:, 1:] != flat[:, :-1]
    valid = first & (flat < sentinel)
    return flat.clamp(max=sentinel - 1), valid


def interior_pixels(batch: int, height: int, width: int, border: int = CENSUS_BORDER, device=None
                    ) -> tuple[torch.Tensor, torch.Tensor]:
    """Every pixel: ``idx (B,H·W)`` int64 and ``valid (B,H·W)`` bool (False on the ``border``)."""
    idx = torch.arange(height * width, device=device)
    x, y = idx % width, idx // width
    valid = (x >= border) & (x <= width - 1 - border) & (y >= border) & (y <= height - 1 - border)
    return idx.expand(batch, -1), valid.expand(batch, -1)


def _soft_sign(d: torch.Tensor) -> torch.Tensor:
    """ARFlow's ternary value of a grey difference (census.py): ``d / sqrt(0.81 + d²)``."""
    return d * torch.rsqrt(0.81 + d * d)


def census_at(img1: torch.Tensor, img2: torch.Tensor, flow: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
    """Census distance at chosen target pixels, the source window moved by each pixel's flow.

    ``img1, img2 (B,3,H,W)`` in [0,1] (target, source), ``flow (B,2,H,W)`` pixels x first (target →
    source), ``idx (B,M)`` flat indices ``y·W + x`` of pixels at least one pixel inside the image →
    ``(B,M)`` distances in [0, 1). Differentiable in ``flow`` (at ``idx`` only) and in ``img2``.
    """
    b, _, h, w = img1.shape
    m = idx.shape[1]
    off = patch_offsets(1).to(idx.device)                                       # (9,2) dx, dy
    nb = (idx[:, :, None] + off[:, 1] * w + off[:, 0]).clamp(0, h * w - 1)     # (B,M,9)
    g1 = grey255(img1).reshape(b, h * w)
    win1 = g1.gather(1, nb.reshape(b, -1)).reshape(b, m, 9)
    t1 = _soft_sign(win1 - win1[:, :, 4:5])
    f = flow.reshape(b, 2, h * w).gather(2, idx[:, None, :].expand(b, 2, m))   # (B,2,M)
    x = (idx % w).to(flow.dtype)[:, :, None] + off[:, 0].to(flow.dtype) + f[:, 0, :, None]
    y = (idx // w).to(flow.dtype)[:, :, None] + off[:, 1].to(flow.dtype) + f[:, 1, :, None]
    grid = torch.stack([2.0 * x / max(w - 1, 1) - 1.0, 2.0 * y / max(h - 1, 1) - 1.0], dim=-1)  # (B,M,9,2)
    win2 = F.grid_sample(grey255(img2), grid, mode="bilinear", padding_mode="border",
                         align_corners=True)[:, 0]                               # (B,M,9)
    t2 = _soft_sign(win2 - win2[:, :, 4:5])
    d = (t1 - t2).square()
    return (d / (0.1 + d)).mean(-1)


def finetune_loss(flow_fw: torch.Tensor, flow_bw: torch.Tensor, img1: torch.Tensor, img2: torch.Tensor,
                  keypoints: torch.Tensor | None = None, keypoint_mask: torch.Tensor | None = None,
                  cfg: FinetuneLossConfig = FinetuneLossConfig()) -> tuple[torch.Tensor, dict[str, float]]:
    """L_flow of the finest flows (see the module docstring).

    ``flow_fw (B,2,H,W)`` target → source and ``flow_bw (B,2,H,W)`` source → target, pixels x first;
    ``img1, img2 (B,3,H,W)`` target and source in [0,1]; for ``cfg.pixels == "patch"``: ``keypoints
    (B,K,2)`` integer pixels of the target (x first) and ``keypoint_mask (B,K)`` bool (see
    :func:`pad_keypoints`). Returns ``(loss, {"loss", "photometric", "smooth", "pixels", "used_pixels",
    "coverage", "noc_fraction"})``: ``pixels`` / ``used_pixels`` per image in S / in S' (not occluded),
    ``coverage`` = share of the image in S.
    """
    if flow_fw.shape != flow_bw.shape or flow_fw.shape[-2:] != img1.shape[-2:] or img1.shape != img2.shape:
        raise ValueError(f"finetune_loss: flows {tuple(flow_fw.shape)}/{tuple(flow_bw.shape)} and images "
                         f"{tuple(img1.shape)}/{tuple(img2.shape)} must share B, H, W")
    b, _, h, w = img1.shape
    if cfg.pixels == "patch":
        if keypoints is None or keypoint_mask is None:
            raise ValueError("finetune_loss: the patch loss needs keypoints and keypoint_mask")
        idx, valid = patch_pixels(keypoints.to(img1.device), keypoint_mask.to(img1.device), h, w, cfg.spacing)
    else:
        idx, valid = interior_pixels(b, h, w, device=img1.device)
    if cfg.occlusion == "range_map":
        noc, _ = non_occluded_by_range(flow_fw.detach(), flow_bw.detach(), cfg.range_threshold)
    else:
        noc, _ = non_occluded_by_consistency(flow_fw.detach(), flow_bw.detach(), cfg.fb_scale, cfg.fb_bias)
    weight = (valid & (noc.reshape(b, h * w).gather(1, idx) > 0)).to(img1.dtype)
    dist = census_at(img1, img2, flow_fw, idx)
    used = weight.sum()
    photometric = (dist * weight).sum() / used.clamp_min(1.0)
    smooth = smoothness(flow_fw / float(min(h, w)), img1, cfg.alpha)
    loss = photometric + cfg.smooth_weight * smooth
    n_valid = float(valid.sum())
    stats = {
        "loss": float(loss.detach()),
        "photometric": float(photometric.detach()),
        "smooth": float(smooth.detach()),
        "pixels": n_valid / b,
        "used_pixels": float(used) / b,
        "coverage": n_valid / (b * h * w),
        "noc_fraction": float(noc.mean()),
    }
    return loss, stats
