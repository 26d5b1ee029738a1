"""F²Depth's patch-based photometric loss for flow fine-tuning (the paper §3.1), computed the way ARFlow
computes its own loss (ARFlow's code, `losses/flow_loss.py`: the paper takes λ = 50 from ARFlow, whose
photometric term is summed over output scales and both flow directions).

For PWC-Lite's flows of a pair (frame 1 = target t, frame 2 = source s), five levels each, finest first,
level i in pixels of its own grid, and with ``backward`` (ARFlow's ``with_bk``)::

    L_flow = Σ_i w_i · (P_i(f_t→s; t, s, S_t) + P_i(f_s→t; s, t, S_s)) / 2
             + λ · (L_sm(f_t→s, I_t) + L_sm(f_s→t, I_s)) / 2

without ``backward``: ``L_flow = Σ_i w_i · P_i(f_t→s; t, s, S_t) + λ · L_sm(f_t→s, I_t)`` — with
``w_scales = (1,)`` exactly the paper's equation ``L_patch(f_t→s) + λ·L_sm(f_t→s)`` on the finest flow.
ARFlow's values (params.yaml, ``paper`` profile): ``w_scales (1, 1, 1, 1, 0)``, ``backward`` true.

``P_i(f; a, b, S_a)`` = mean over the usable pixels ``S'_i`` of ARFlow's ternary census distance between
frame a's 3×3 window at p and frame b's at ``p + f(p)``, on the level-i images (area-resized from the
input, as ARFlow does). ``S_a`` = the patch pixels ``{(x + i, y + j) : i, j ∈ {−N, 0, N}}`` around the
DSO keypoints **of frame a** (the target's keypoints for the forward term, the source's for the backward
term); ``S'_i`` = those pixels mapped to level i, minus occluded pixels and the level's one-pixel border.
``L_sm`` = ARFlow's first-order edge-aware smoothness of ``f / min(H, W)`` weighted by
``exp(−10·|∂I|)``, on the finest level only (ARFlow's ``w_sm_scales (1, 0, 0, 0, 0)``).

Decisions (documented because the paper leaves them open):

* **Patches at coarser levels.** Every patch pixel (x, y) inside the input image is mapped to level i
  (size h_i × w_i) as ``(⌊x·w_i/W⌋, ⌊y·h_i/H⌋)`` = ``(⌊x/2^i⌋, ⌊y/2^i⌋)`` for PWC-Lite's sizes: the
  level-i pixels whose area-averaged colour contains the patch pixels. The loss thus covers the same image
  region around the keypoints at every level (no low-texture surroundings are added at coarse levels).
  Pixels that coincide after the mapping count once, as below.
* **Each pixel counts once.** ``S`` is a *set* per level: a pixel covered by several (overlapping or
  duplicate) patches enters the average once, exactly as multiplying ARFlow's occlusion mask by a binary
  patch mask would. Duplicate keypoints therefore do not weigh double.
* **Occlusion** is decided on the finest level only (no gradient) and nearest-resized to the coarser
  levels, as ARFlow does: the forward–backward check (``|f + f_bw(p + f)|² > 0.01·(|f|² + |f_bw(p + f)|²)
  + 0.5``; frame 1's mask for the forward term, frame 2's for the backward term) or, with
  ``occlusion="range_map"``, ARFlow's UnOS range map, which ARFlow uses to warm up because the
  forward–backward check marks every pixel occluded while the flow is still degenerate (e.g. a constant
  flow, where forward = backward).
* **The average runs over the whole batch**, per level and direction (ARFlow divides the masked sum by
  the mask's mean over the batch): images with more usable patch pixels weigh more; an image without
  keypoints, or whose patch pixels are all occluded, adds nothing. A level and direction without any
  usable pixel contributes exactly 0 (ARFlow would return 0/0 = NaN).
* **Census window moves with the pixel's own flow.** The source grey image is sampled bilinearly (border
  padding, align_corners=True) at ``p + o + f(p)`` for the 9 offsets ``o``. ARFlow instead warps the whole
  source first, so its window uses the neighbours' flows ``f(p + o)``; both agree wherever the flow is
  constant over the 3×3 window, and this form makes the loss depend on the flow **only at the pixels of
  S** (the paper's "only patch pixels are used"). It is computed only at the gathered pixels (no dense
  map): ``9·|S|`` bilinear samples of one grey channel per level and direction.
* The one-pixel border of each level (where ARFlow's census is defined as 0) is left out of ``S`` and of
  the denominator. Images are not multiplied by the occlusion mask before the census (ARFlow does that);
  the mask is applied to the distances.

The `full` variant of Table 6 is not computed here: it is ARFlow's own loss,
:func:`f2depth.flow.loss.flow_loss` with ``SINTEL_FT`` (see :mod:`f2depth.flow.finetune`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import torch
import torch.nn.functional as F

from f2depth.flow.census import grey255
from f2depth.flow.loss import non_occluded_masks, smoothness
from f2depth.geometry import patch_offsets

OCCLUSION_CHECKS = ("forward_backward", "range_map")
CENSUS_BORDER = 1


@dataclass(frozen=True)
class FinetuneLossConfig:
    """Settings of the patch loss. The first five come from params.yaml (``flow_finetune.patch_spacing``,
    ``w_scales``, ``backward``, ``occlusion``, ``lambda_flow_smooth``; ``FinetuneConfig.patch_loss_config``).
    The paper's equation as written is ``w_scales=(1.0,), backward=False`` (the finest forward flow only),
    ARFlow's way of computing it ``w_scales=(1, 1, 1, 1, 0), backward=True``. The rest: ARFlow's constants."""

    spacing: int                      # N
    w_scales: tuple[float, ...]       # photometric weight per flow level, finest first; missing = 0
    backward: bool                    # also the backward term (ARFlow's with_bk), averaged with the forward
    smooth_weight: float              # λ = params.yaml lambda_flow_smooth
    occlusion: str                    # forward_backward (the paper's, ARFlow's) | range_map (warm-up)
    alpha: float = 10.0               # edge-awareness of the smoothness weights (ARFlow)
    fb_scale: float = 0.01            # forward–backward occlusion check (ARFlow)
    fb_bias: float = 0.5
    range_threshold: float = 0.2      # range map: occluded where the splatted count is below this

    @property
    def occ_from_back(self) -> bool:
        """The range map rather than the forward–backward check
        (:func:`f2depth.flow.loss.non_occluded_masks`)."""
        return self.occlusion == "range_map"

    def __post_init__(self) -> None:
        if self.occlusion not in OCCLUSION_CHECKS:
            raise ValueError(f"FinetuneLossConfig.occlusion must be one of {OCCLUSION_CHECKS}, "
                             f"got {self.occlusion!r}")
        if self.spacing < 1:
            raise ValueError(f"FinetuneLossConfig.spacing must be >= 1, got {self.spacing}")
        if not self.w_scales or any(w < 0 for w in self.w_scales) or not any(w > 0 for w in self.w_scales):
            raise ValueError(f"FinetuneLossConfig.w_scales must be non-negative with one positive weight, "
                             f"got {self.w_scales}")


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


def patch_indices(keypoints: torch.Tensor, mask: torch.Tensor, height: int, width: int, spacing: int = 2,
                  border: int = CENSUS_BORDER, level_hw: tuple[int, int] | None = None
                  ) -> tuple[torch.Tensor, torch.Tensor]:
    """The patch pixel set of every image, as flat indices of the level grid.

    ``keypoints (B,K,2)`` integer pixels of the ``height × width`` input image, x first, ``mask (B,K)``
    bool; ``level_hw`` = ``(h, w)`` of the level (default: the input) → ``idx (B,M)`` int64 ``y·w + x``
    and ``valid (B,M)`` bool. Patch pixels inside the input image are mapped to ``(⌊x·w/W⌋, ⌊y·h/H⌋)``;
    each mapped pixel lying at least ``border`` pixels inside the level is valid exactly once. Each row
    holds its valid pixels first, in ascending order, then padding (invalid, ``idx`` clamped into the
    level, to be ignored); ``M`` = the largest set of the batch (at least 1, at most 9K), so overlapping
    patches and coarse levels cost only their distinct pixels.
    """
    h, w = level_hw if level_hw is not None else (height, width)
    b = keypoints.shape[0]
    off = patch_offsets(spacing, device=keypoints.device)
    pix = keypoints[:, :, None, :].to(torch.int64) + off                      # (B,K,9,2)
    x, y = pix[..., 0], pix[..., 1]
    inside = mask[:, :, None] & (x >= 0) & (x <= width - 1) & (y >= 0) & (y <= height - 1)
    if (h, w) != (height, width):
        x, y = torch.div(x * w, width, rounding_mode="floor"), torch.div(y * h, height, rounding_mode="floor")
    inside = inside & (x >= border) & (x <= w - 1 - border) & (y >= border) & (y <= h - 1 - border)
    sentinel = h * w
    flat = torch.where(inside, y * w + x, torch.full_like(x, sentinel)).reshape(b, -1)
    flat, _ = flat.sort(dim=1)
    first = torch.ones_like(flat, dtype=torch.bool)
    first[:, 1:] = flat[:, 1:] != flat[:, :-1]
    valid = first & (flat < sentinel)
    order = torch.argsort((~valid).to(torch.int8), dim=1, stable=True)   # valid first, order kept
    m = max(int(valid.sum(1).max()), 1) if b else 1
    return flat.gather(1, order)[:, :m].clamp(max=sentinel - 1), valid.gather(1, order)[:, :m]


def _soft_sign(d: torch.Tensor) -> torch.Tensor:
    """ARFlow's ternary value of a grey difference (census.py): ``d / sqrt(0.81 + d²)``."""
    return d * torch.rsqrt(0.81 + d * d)


def census_at(img1: torch.Tensor, img2: torch.Tensor, flow: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
    """Census distance at chosen pixels of frame 1, frame 2's window moved by each pixel's flow.

    ``img1, img2 (B,3,H,W)`` in [0,1], ``flow (B,2,H,W)`` pixels x first (frame 1 → frame 2), ``idx (B,M)``
    flat indices ``y·W + x`` of pixels at least one pixel inside the image → ``(B,M)`` distances in [0, 1).
    Differentiable in ``flow`` (at ``idx`` only) and in ``img2``.
    """
    b, _, h, w = img1.shape
    m = idx.shape[1]
    off = patch_offsets(1, device=idx.device)                                  # (9,2) dx, dy
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


@dataclass
class _Term:
    value: torch.Tensor   # mean census distance over the usable pixels (0 without any)
    pixels: float         # |S| of the level (all images)
    used: float           # |S'| (not occluded)


def _patch_term(img_a: torch.Tensor, img_b: torch.Tensor, flow: torch.Tensor, noc: torch.Tensor,
                keypoints: torch.Tensor, mask: torch.Tensor, input_hw: tuple[int, int], spacing: int
                ) -> _Term:
    """One level and direction: frame a's patches, flow a → b, non-occluded mask ``noc (B,1,h,w)`` of a."""
    b = flow.shape[0]
    h, w = flow.shape[-2:]
    idx, valid = patch_indices(keypoints, mask, *input_hw, spacing, level_hw=(h, w))
    weight = (valid & (noc.reshape(b, h * w).gather(1, idx) > 0)).to(img_a.dtype)
    dist = census_at(img_a, img_b, flow, idx)
    used = weight.sum()
    return _Term((dist * weight).sum() / used.clamp_min(1.0), float(valid.sum()), float(used))


def _levels(flows: torch.Tensor | Sequence[torch.Tensor]) -> list[torch.Tensor]:
    return [flows] if isinstance(flows, torch.Tensor) else list(flows)


def finetune_loss(flows_fw: torch.Tensor | Sequence[torch.Tensor],
                  flows_bw: torch.Tensor | Sequence[torch.Tensor], img1: torch.Tensor, img2: torch.Tensor,
                  keypoints: torch.Tensor, keypoint_mask: torch.Tensor,
                  cfg: FinetuneLossConfig) -> tuple[torch.Tensor, dict[str, float]]:
    """L_flow with the patch loss (see the module docstring).

    ``flows_fw`` frame 1 → 2 and ``flows_bw`` frame 2 → 1: lists of ``(B,2,h_i,w_i)`` flows, finest first,
    in pixels of their level (finest at the image size), or one ``(B,2,H,W)`` tensor = the finest level
    alone; ``img1, img2 (B,3,H,W)`` in [0,1] (target, source); ``keypoints`` integer pixels x first and
    ``keypoint_mask`` bool (see :func:`pad_keypoints`): ``(B,2,K,2)`` / ``(B,2,K)`` for frames 1 and 2, or
    ``(B,K,2)`` / ``(B,K)`` of frame 1 alone (without ``cfg.backward``). Returns ``(loss, {"loss",
    "photometric", "smooth", "pixels", "used_pixels", "coverage", "noc_fraction"})``: ``pixels`` /
    ``used_pixels`` per image in S / in S' of the finest forward term, ``coverage`` = its share of the
    image, ``noc_fraction`` = frame 1's non-occluded share.
    """
    fw, bw = _levels(flows_fw), _levels(flows_bw)
    if (len(fw) != len(bw) or any(f.shape != g.shape for f, g in zip(fw, bw))
            or fw[0].shape[-2:] != img1.shape[-2:] or img1.shape != img2.shape):
        raise ValueError(f"finetune_loss: flows {[tuple(f.shape) for f in fw]}/"
                         f"{[tuple(f.shape) for f in bw]} and images {tuple(img1.shape)}/{tuple(img2.shape)} "
                         "must share B and the finest H, W")
    if any(w > 0 for w in cfg.w_scales[len(fw):]):
        raise ValueError(f"finetune_loss: w_scales {cfg.w_scales} weighs {len(cfg.w_scales)} levels but only "
                         f"{len(fw)} flow level(s) were given")
    device = img1.device
    keypoints, keypoint_mask = keypoints.to(device), keypoint_mask.to(device)
    if keypoints.dim() == 3:
        if cfg.backward:
            raise ValueError("finetune_loss: the backward term needs the keypoints of frame 2 too: pass "
                             "keypoints (B,2,K,2) and keypoint_mask (B,2,K)")
        keypoints, keypoint_mask = keypoints[:, None], keypoint_mask[:, None]
    b, _, h, w = img1.shape
    noc1, noc2 = non_occluded_masks(fw[0].detach(), bw[0].detach(), cfg)
    photometric = img1.new_zeros(())
    finest: _Term | None = None
    for i, weight in enumerate(cfg.w_scales[:len(fw)]):
        if weight == 0 and i > 0:
            continue
        size = fw[i].shape[-2:]
        im1 = img1 if i == 0 else F.interpolate(img1, size=size, mode="area")
        im2 = img2 if i == 0 else F.interpolate(img2, size=size, mode="area")
        m1 = noc1 if i == 0 else F.interpolate(noc1, size=size, mode="nearest")
        term = _patch_term(im1, im2, fw[i], m1, keypoints[:, 0], keypoint_mask[:, 0], (h, w), cfg.spacing)
        finest = term if i == 0 else finest
        value = term.value
        if cfg.backward:
            m2 = noc2 if i == 0 else F.interpolate(noc2, size=size, mode="nearest")
            back = _patch_term(im2, im1, bw[i], m2, keypoints[:, 1], keypoint_mask[:, 1], (h, w), cfg.spacing)
            value = (value + back.value) / 2
        photometric = photometric + weight * value
    s = float(min(h, w))
    smooth = smoothness(fw[0] / s, img1, cfg.alpha)
    if cfg.backward:
        smooth = (smooth + smoothness(bw[0] / s, img2, cfg.alpha)) / 2
    loss = photometric + cfg.smooth_weight * smooth
    stats = {"loss": float(loss.detach()), "photometric": float(photometric.detach()),
             "smooth": float(smooth.detach()), "pixels": finest.pixels / b, "used_pixels": finest.used / b,
             "coverage": finest.pixels / (b * h * w), "noc_fraction": float(noc1.mean())}
    return loss, stats
