"""SSIM dissimilarity as Monodepth2 / P²Net compute it: dense 3×3 and over sparse sample sets.

Both return ``clamp((1 − SSIM) / 2, 0, 1)`` with C1 = 0.01², C2 = 0.03² and population (biased)
variances, the form the photometric losses weigh by 0.85.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

C1 = 0.01**2
C2 = 0.03**2


def _dissimilarity(mu_x, mu_y, sigma_x, sigma_y, sigma_xy) -> torch.Tensor:
    num = (2 * mu_x * mu_y + C1) * (2 * sigma_xy + C2)
    den = (mu_x**2 + mu_y**2 + C1) * (sigma_x + sigma_y + C2)
    return torch.clamp((1 - num / den) / 2, 0, 1)


def ssim_dense(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """Per-pixel SSIM dissimilarity over 3×3 windows (reflection padding, mean pooling).

    x, y (B,C,H,W) → (B,C,H,W) in [0, 1].
    """
    x = F.pad(x, (1, 1, 1, 1), mode="reflect")
    y = F.pad(y, (1, 1, 1, 1), mode="reflect")
    mu_x = F.avg_pool2d(x, 3, 1)
    mu_y = F.avg_pool2d(y, 3, 1)
    sigma_x = F.avg_pool2d(x * x, 3, 1) - mu_x**2
    sigma_y = F.avg_pool2d(y * y, 3, 1) - mu_y**2
    sigma_xy = F.avg_pool2d(x * y, 3, 1) - mu_x * mu_y
    return _dissimilarity(mu_x, mu_y, sigma_x, sigma_y, sigma_xy)


def ssim_samples(x: torch.Tensor, y: torch.Tensor, dim: int = -1) -> torch.Tensor:
    """SSIM dissimilarity over sample sets (P²Net's ``SSIM_sparse``: one window = the 9 patch samples).

    x, y (..., S, ...) with the S samples along ``dim`` → (...) with ``dim`` reduced, in [0, 1].
    """
    mu_x = x.mean(dim)
    mu_y = y.mean(dim)
    sigma_x = (x * x).mean(dim) - mu_x**2
    sigma_y = (y * y).mean(dim) - mu_y**2
    sigma_xy = (x * y).mean(dim) - mu_x * mu_y
    return _dissimilarity(mu_x, mu_y, sigma_x, sigma_y, sigma_xy)
