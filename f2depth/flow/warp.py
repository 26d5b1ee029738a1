"""Backward warping by a dense flow field, with ARFlow's conventions.

``warp(img, flow)[..., y, x] = img[..., y + v(y, x), x + u(y, x)]`` sampled bilinearly, pixel centres at
integer coordinates, ``align_corners=True`` normalisation ``2 * g / (size - 1) - 1`` and ``border``
padding (ARFlow ``flow_warp``, research/arflow.md §1.7). ``padding="zeros"`` is what ARFlow's
forward–backward occlusion check uses when it warps a flow.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

_GRIDS: dict[tuple, torch.Tensor] = {}


def base_grid(height: int, width: int, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    """Pixel coordinates ``(1, 2, H, W)``: channel 0 = x (column), channel 1 = y (row); cached."""
    key = (height, width, dtype, str(device))
    grid = _GRIDS.get(key)
    if grid is None:
        ys, xs = torch.meshgrid(
            torch.arange(height, dtype=dtype, device=device),
            torch.arange(width, dtype=dtype, device=device),
            indexing="ij",
        )
        grid = torch.stack([xs, ys]).unsqueeze(0)
        if len(_GRIDS) > 64:
            _GRIDS.clear()
        _GRIDS[key] = grid
    return grid


def sample_grid(flow: torch.Tensor) -> torch.Tensor:
    """``flow (B,2,H,W)`` pixels, x first → ``grid_sample`` grid ``(B,H,W,2)``, align_corners=True."""
    _, _, h, w = flow.shape
    pos = base_grid(h, w, flow.dtype, flow.device) + flow
    gx = 2.0 * pos[:, 0] / max(w - 1, 1) - 1.0
    gy = 2.0 * pos[:, 1] / max(h - 1, 1) - 1.0
    return torch.stack([gx, gy], dim=-1)


def warp(img: torch.Tensor, flow: torch.Tensor, padding: str = "border") -> torch.Tensor:
    """Backward-warp ``img (B,C,H,W)`` by ``flow (B,2,H,W)`` pixels (x first) → ``(B,C,H,W)``.

    Bilinear, ``align_corners=True``, ``padding`` ``"border"`` (ARFlow's images and features) or
    ``"zeros"`` (ARFlow's flow warp in the occlusion check). Differentiable in both arguments.
    """
    if img.shape[-2:] != flow.shape[-2:] or flow.shape[1] != 2:
        raise ValueError(f"warp: img {tuple(img.shape)} and flow {tuple(flow.shape)} must share (H, W); "
                         "flow needs 2 channels")
    return F.grid_sample(img, sample_grid(flow), mode="bilinear", padding_mode=padding, align_corners=True)
