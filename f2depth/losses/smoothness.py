"""P²Net's edge-aware first-order smoothness L_sm on mean-normalised disparity (P²Net's
``trainer_geo.py`` and ``layers.py``, ``get_smooth_loss``)."""

from __future__ import annotations

import torch


def edge_aware_smoothness(disp: torch.Tensor, img: torch.Tensor) -> torch.Tensor:
    """L_sm = mean(|∂x d|·exp(−mean_c|∂x I|)) + mean(|∂y d|·exp(−mean_c|∂y I|)), d = disp / mean(disp).

    disp (B,1,H,W) the raw sigmoid output (not the scaled disparity), img (B,3,H,W) the un-augmented
    target in [0, 1]; forward differences; the mean of d is taken per image → scalar.
    """
    d = disp / (disp.mean(dim=(2, 3), keepdim=True) + 1e-7)
    grad_d_x = (d[..., :, :-1] - d[..., :, 1:]).abs()
    grad_d_y = (d[..., :-1, :] - d[..., 1:, :]).abs()
    grad_i_x = (img[..., :, :-1] - img[..., :, 1:]).abs().mean(dim=1, keepdim=True)
    grad_i_y = (img[..., :-1, :] - img[..., 1:, :]).abs().mean(dim=1, keepdim=True)
    return (grad_d_x * torch.exp(-grad_i_x)).mean() + (grad_d_y * torch.exp(-grad_i_y)).mean()
