"""Running a depth network for evaluation: its disparity at the ground truth's size, with or without
Monodepth's flip post-processing, and depth from disparity (used by the test-set protocols, timing and
``f2depth predict``)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

DISP_EPS = 1e-8
"""Disparities below this are treated as this value when inverted (avoids division by zero)."""

PredictDisp = Callable[[torch.Tensor], torch.Tensor]
"""``predict_disp(img (B,3,H,W) float in [0,1]) -> disp (B,1,H,W)`` with ``1/disp`` the depth up to scale.

For ``f2depth.depth.DepthModel`` that is the *scaled* disparity,
``lambda x: disp_to_depth(model.predict_disp(x), 0.1, 10)[0]``, not the raw sigmoid (1/sigmoid is not
proportional to depth, so median scaling would not undo it)."""


# ---- disparity → depth, resizing, post-processing ---------------------------------------------------


def depth_from_disparity(disp: np.ndarray | torch.Tensor) -> np.ndarray:
    """depth = 1 / disp (any shape) as float64 NumPy; disparities ≤ ``DISP_EPS`` are clamped to it."""
    if isinstance(disp, torch.Tensor):
        disp = disp.detach().cpu().numpy()
    return 1.0 / np.maximum(np.asarray(disp, dtype=np.float64), DISP_EPS)


def resize_disparity(disp: torch.Tensor, hw: tuple[int, int], mode: str = "nearest") -> torch.Tensor:
    """Resize disp (B,1,h,w) → (B,1,H,W). ``mode``: ``nearest`` (``F.interpolate``'s default, as in
    P²Net's evaluation) or ``bilinear`` (``align_corners=False``, as Monodepth2 / SC-Depth)."""
    if tuple(disp.shape[-2:]) == tuple(hw):
        return disp
    if mode == "nearest":
        return F.interpolate(disp, size=tuple(hw), mode="nearest")
    if mode == "bilinear":
        return F.interpolate(disp, size=tuple(hw), mode="bilinear", align_corners=False)
    raise ValueError(f"upsample mode must be 'nearest' or 'bilinear', got {mode!r}")


def pp_weights(height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """Monodepth's ramp masks, each (H,W) float64.

    ``l_mask`` is 1 on the left 5 % of the columns (x = linspace(0, 1, W) ≤ 0.05), falls linearly to 0
    at 10 % and stays 0; ``r_mask`` is its mirror image.
    """
    x = np.linspace(0.0, 1.0, width)
    l_row = 1.0 - np.clip(20.0 * (x - 0.05), 0.0, 1.0)
    l_mask = np.broadcast_to(l_row, (height, width)).copy()
    return l_mask, l_mask[:, ::-1].copy()


def flip_post_process(disp: Any, disp_flipped_back: Any) -> Any:
    """Monodepth's flip post-processing: blend a prediction with the flipped-back prediction of the
    flipped image.

    disp, disp_flipped_back: (..., H, W) disparities (NumPy or torch, same type), the second being
    ``predict(flip(img))`` flipped back. Returns
    ``r_mask·disp + l_mask·disp_flipped_back + (1 − l_mask − r_mask)·(disp + disp_flipped_back)/2``:
    the left border comes from the flipped-back prediction, the right border from the direct one, the
    rest is their mean. Work in disparity (the blend is affine, so scaled or sigmoid disparity agree).
    """
    h, w = disp.shape[-2:]
    l_mask, r_mask = pp_weights(h, w)
    if isinstance(disp, torch.Tensor):
        l_mask = torch.as_tensor(l_mask, dtype=disp.dtype, device=disp.device)
        r_mask = torch.as_tensor(r_mask, dtype=disp.dtype, device=disp.device)
    mean = 0.5 * (disp + disp_flipped_back)
    return r_mask * disp + l_mask * disp_flipped_back + (1.0 - l_mask - r_mask) * mean


def predict_disparity(predict_disp: PredictDisp, img: torch.Tensor, *, post_process: bool = False,
                      out_hw: tuple[int, int] | None = None, upsample: str = "nearest") -> torch.Tensor:
    """Run ``predict_disp`` on img (B,3,h,w) in [0,1], optionally with flip post-processing.

    With ``post_process`` the network sees the batch ``[img, flip(img)]`` (2B images,
    :func:`predict_with_and_without_pp`). When ``out_hw = (H, W)`` is given, the disparity is resized to it
    (``upsample``: nearest | bilinear), with PP *before* blending, as P²Net's evaluation does. Returns
    disp (B,1,H,W) (or (B,1,h,w)).
    """
    if post_process:
        return predict_with_and_without_pp(predict_disp, img, out_hw=out_hw, upsample=upsample)[1]
    return _resized(predict_disp, _checked(img), out_hw, upsample)


def predict_with_and_without_pp(predict_disp: PredictDisp, img: torch.Tensor, *,
                                out_hw: tuple[int, int] | None = None, upsample: str = "nearest"
                                ) -> tuple[torch.Tensor, torch.Tensor]:
    """One pass of the batch ``[img, flip(img)]`` → (disp without flip post-processing, disp with it), both
    (B,1,H,W) as :func:`predict_disparity` returns them: the first is the network's output on ``img``
    itself, so scoring both costs two images a test image instead of three."""
    b = _checked(img).shape[0]
    disp = _resized(predict_disp, torch.cat([img, img.flip(-1)], 0), out_hw, upsample)
    return disp[:b], flip_post_process(disp[:b], disp[b:].flip(-1))


def _checked(img: torch.Tensor) -> torch.Tensor:
    if img.ndim != 4 or img.shape[1] != 3:
        raise ValueError(f"img must be (B,3,H,W), got {tuple(img.shape)}")
    return img


def _resized(predict_disp: PredictDisp, x: torch.Tensor, out_hw: tuple[int, int] | None,
             upsample: str) -> torch.Tensor:
    """``predict_disp(x)``, checked to be (B,1,h,w), resized to ``out_hw`` when given."""
    disp = predict_disp(x)
    if disp.ndim != 4 or disp.shape[0] != x.shape[0] or disp.shape[1] != 1:
        raise ValueError(f"predict_disp must return disp (B,1,H,W) for an input {tuple(x.shape)}, got "
                         f"{tuple(disp.shape)}")
    return resize_disparity(disp, out_hw, upsample) if out_hw is not None else disp
