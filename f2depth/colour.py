"""Colour operations on RGB tensors ``(...,3,H,W)`` in [0, 1]: grey, HSV and the four colour-jitter
adjustments, shared by the depth training's and the flow fine-tuning's augmentation.

Two sets of grey weights, both kept because the code each part inherits uses its own:

* ``GREY_PIL`` = (0.299, 0.587, 0.114): PIL's ``convert("L")`` (ITU-R 601-2). P²Net jitters PIL images
  with torchvision's ``ColorJitter``, whose contrast and saturation go through PIL's grey image
  (P²Net's ``datasets/nyu_dataset.py``).
* ``GREY_MATLAB`` = (0.2989, 0.5870, 0.1140): MATLAB's ``rgb2gray``, also torchvision's grey of a tensor;
  ARFlow's census transform (ARFlow's ``losses/loss_blocks.py``) and our flow fine-tuning jitter.

The jitter operations follow torchvision's ``ColorJitter`` definitions (torchvision is not a dependency):
brightness ``x·f``; contrast ``f·x + (1−f)·mean(grey(x))``; saturation ``f·x + (1−f)·grey(x)``; hue: the
HSV hue rotated by ``f`` turns; every result clipped to [0, 1].
"""

from __future__ import annotations

import torch

GREY_PIL = (0.299, 0.587, 0.114)
GREY_MATLAB = (0.2989, 0.5870, 0.1140)
JITTER_OPS = ("brightness", "contrast", "saturation", "hue")


def grey(img: torch.Tensor, weights: tuple[float, float, float] = GREY_PIL) -> torch.Tensor:
    """RGB ``(...,3,H,W)`` → grey ``(...,1,H,W)`` = Σ weights·channel (same range as the input)."""
    r, g, b = img.unbind(dim=-3)
    return (weights[0] * r + weights[1] * g + weights[2] * b).unsqueeze(-3)


def rgb_to_hsv(img: torch.Tensor) -> torch.Tensor:
    """RGB ``(...,3,H,W)`` in [0, 1] → HSV: hue in [0, 1) turns, saturation and value in [0, 1]."""
    r, g, b = img.unbind(dim=-3)
    value = img.amax(dim=-3)
    chroma = value - img.amin(dim=-3)
    flat = chroma == 0
    safe_c = torch.where(flat, torch.ones_like(chroma), chroma)
    sat = torch.where(value > 0, chroma / torch.where(value > 0, value, torch.ones_like(value)),
                      torch.zeros_like(value))
    # hue sector by which channel is the maximum (red wins ties, then green), in units of 60°
    h_r = ((g - b) / safe_c) % 6.0
    h_g = (b - r) / safe_c + 2.0
    h_b = (r - g) / safe_c + 4.0
    hue = torch.where(value == r, h_r, torch.where(value == g, h_g, h_b))
    hue = torch.where(flat, torch.zeros_like(hue), hue) / 6.0
    return torch.stack((hue % 1.0, sat, value), dim=-3)


def hsv_to_rgb(hsv: torch.Tensor) -> torch.Tensor:
    """Inverse of :func:`rgb_to_hsv`: ``(...,3,H,W)`` → RGB in [0, 1]."""
    hue, sat, value = hsv.unbind(dim=-3)

    def channel(n: float) -> torch.Tensor:
        k = (n + hue * 6.0) % 6.0
        ramp = torch.clamp(torch.minimum(k, 4.0 - k), 0.0, 1.0)
        return value - value * sat * ramp

    return torch.stack((channel(5.0), channel(3.0), channel(1.0)), dim=-3).clamp(0.0, 1.0)


def adjust(img: torch.Tensor, op: str, factor: float,
           weights: tuple[float, float, float] = GREY_PIL) -> torch.Tensor:
    """One jitter operation (``op`` in ``JITTER_OPS``) on RGB ``(...,3,H,W)`` in [0, 1]; contrast uses each
    image's own mean grey (leading dimensions are separate images). Returns a new tensor in [0, 1]."""
    if op == "brightness":
        out = img * factor
    elif op == "contrast":
        out = factor * img + (1.0 - factor) * grey(img, weights).mean(dim=(-3, -2, -1), keepdim=True)
    elif op == "saturation":
        out = factor * img + (1.0 - factor) * grey(img, weights)
    elif op == "hue":
        if factor == 0.0:
            return img.clamp(0.0, 1.0)
        hsv = rgb_to_hsv(img.clamp(0.0, 1.0))
        out = hsv_to_rgb(torch.cat(((hsv[..., :1, :, :] + factor) % 1.0, hsv[..., 1:, :, :]), dim=-3))
    else:
        raise ValueError(f"unknown colour operation {op!r} (one of {', '.join(JITTER_OPS)})")
    return out.clamp(0.0, 1.0)
