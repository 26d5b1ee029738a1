"""ARFlow's ternary census distance (ARFlow's code, ``losses/loss_blocks.py``; UnFlow's transform, 3×3 patch).

For a grey image ``I = 255·(0.2989 R + 0.5870 G + 0.1140 B)`` and the 9 offsets ``o`` of a 3×3 patch
(centre included, zero padding outside the image)::

    t_o(p) = (I(p+o) − I(p)) / sqrt(0.81 + (I(p+o) − I(p))²)
    d_o(p) = (t1_o(p) − t2_o(p))²,   D(p) = mean_o d_o(p) / (0.1 + d_o(p))

and D is zeroed on a one-pixel border. The soft sign ``t`` makes D nearly insensitive to a global gain
of the images (only the sign pattern of local differences larger than ~1 grey level matters).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from f2depth.colour import GREY_MATLAB, grey


def grey255(img: torch.Tensor) -> torch.Tensor:
    """``img (B,3,H,W)`` RGB in [0,1] → ``(B,1,H,W)`` grey in [0,255] (ARFlow's weights)."""
    return grey(img, GREY_MATLAB) * 255.0


def ternary_transform(img: torch.Tensor) -> torch.Tensor:
    """Soft ternary census ``(B,9,H,W)`` of ``img (B,3,H,W)`` in [0,1]; channel k = offset (k//3−1, k%3−1)."""
    grey = grey255(img)
    h, w = grey.shape[-2:]
    padded = F.pad(grey, (1, 1, 1, 1))
    shifted = [padded[:, :, dy : dy + h, dx : dx + w] for dy in range(3) for dx in range(3)]
    diffs = torch.cat(shifted, 1) - grey
    return diffs * torch.rsqrt(0.81 + diffs * diffs)


def border_mask(x: torch.Tensor, width: int = 1) -> torch.Tensor:
    """``(1,1,H,W)`` ones inside, zeros on a ``width``-pixel border, on ``x``'s device and dtype."""
    h, w = x.shape[-2:]
    mask = x.new_zeros(1, 1, h, w)
    mask[:, :, width : h - width, width : w - width] = 1.0
    return mask


def census_distance(img1: torch.Tensor, img2_warped: torch.Tensor) -> torch.Tensor:
    """ARFlow's census distance map: ``img1, img2_warped (B,3,H,W)`` in [0,1] → ``(B,1,H,W)`` in [0, 1).

    Symmetric in its arguments; zero on the one-pixel border. No robust penalty is applied (ARFlow
    averages this map directly).
    """
    if img1.shape != img2_warped.shape or img1.dim() != 4 or img1.shape[1] != 3:
        raise ValueError(f"census_distance: expected two (B,3,H,W) images, got {tuple(img1.shape)} and "
                         f"{tuple(img2_warped.shape)}")
    d = (ternary_transform(img1) - ternary_transform(img2_warped)).square()
    dist = (d / (0.1 + d)).mean(1, keepdim=True)
    return dist * border_mask(dist)
