"""Colour operations on RGB tensors ``(...,3,H,W)`` in [0, 1]: grey, HSV and the four colour-jitter
adjustments, shared by the depth training's and the flow fine-tuning's augmentation; and the Middlebury
colour coding of flow fields (:func:`flow_to_color`, Baker et al., IJCV 2011) for every flow picture.

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

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

GREY_PIL = (0.299, 0.587, 0.114)
GREY_MATLAB = (0.2989, 0.5870, 0.1140)
JITTER_OPS = ("brightness", "contrast", "saturation", "hue")


@dataclass(frozen=True)
class AugmentConfig:
    """P²Net's augmentation recipe (P²Net's ``datasets/nyu_dataset.py``), the one both the depth training
    (f2depth.train.augment) and the flow fine-tuning (f2depth.flow.augment) use: a horizontal flip with
    probability ``flip_p``; with probability ``jitter_p`` a colour jitter whose factors are drawn from these
    ranges (hue in turns) and applied in a drawn order. ``params.yaml`` switches it on or off only
    (``flow_finetune.augment``, ``train_depth.augment``): the recipe is P²Net's, not a setting."""

    flip_p: float = 0.5
    jitter_p: float = 0.5
    brightness: tuple[float, float] = (0.8, 1.2)
    contrast: tuple[float, float] = (0.8, 1.2)
    saturation: tuple[float, float] = (0.8, 1.2)
    hue: tuple[float, float] = (-0.1, 0.1)

    def ranges(self) -> tuple[tuple[float, float], ...]:
        """The factor ranges in ``JITTER_OPS``'s order."""
        return self.brightness, self.contrast, self.saturation, self.hue


P2NET_AUGMENT = AugmentConfig()


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


def jitter(img: torch.Tensor, factors: Sequence[float], order: Sequence[int],
           weights: tuple[float, float, float]) -> torch.Tensor:
    """The colour jitter: ``adjust`` with ``JITTER_OPS[k]`` and ``factors[k]`` for each ``k`` of ``order``,
    on RGB ``(...,3,H,W)`` in [0, 1] (``factors`` in ``JITTER_OPS``'s order)."""
    for k in order:
        img = adjust(img, JITTER_OPS[k], factors[k], weights)
    return img


def color_wheel() -> np.ndarray:
    """The 55×3 Middlebury colour wheel, float in [0, 255]."""
    segments = [(15, (255, 0, 0), (255, 255, 0)), (6, (255, 255, 0), (0, 255, 0)),
                (4, (0, 255, 0), (0, 255, 255)), (11, (0, 255, 255), (0, 0, 255)),
                (13, (0, 0, 255), (255, 0, 255)), (6, (255, 0, 255), (255, 0, 0))]
    rows = []
    for n, start, end in segments:
        t = np.arange(n, dtype=np.float64)[:, None] / n
        rows.append(np.asarray(start, np.float64) * (1 - t) + np.asarray(end, np.float64) * t)
    return np.floor(np.concatenate(rows, 0))


def flow_to_color(flow: np.ndarray, max_flow: float | None = None) -> np.ndarray:
    """``flow (H,W,2)`` or ``(2,H,W)`` pixels → RGB uint8 ``(H,W,3)`` (Middlebury coding: hue is the
    direction on the 55-colour wheel of :func:`color_wheel`, saturation the magnitude).

    Magnitudes are divided by ``max_flow`` (default: the largest finite magnitude); vectors longer than
    that are drawn at 75 % brightness; non-finite vectors are black.
    """
    f = np.asarray(flow, dtype=np.float64)
    if f.ndim == 3 and f.shape[0] == 2 and f.shape[-1] != 2:
        f = f.transpose(1, 2, 0)
    if f.ndim != 3 or f.shape[-1] != 2:
        raise ValueError(f"flow_to_color: expected (H,W,2) or (2,H,W), got {np.shape(flow)}")
    u, v = f[..., 0], f[..., 1]
    bad = ~(np.isfinite(u) & np.isfinite(v))
    u, v = np.where(bad, 0, u), np.where(bad, 0, v)
    mag = np.hypot(u, v)
    scale = max_flow if max_flow is not None else (float(mag.max()) if mag.size else 0.0)
    scale = max(scale, 1e-9)
    u, v, mag = u / scale, v / scale, mag / scale
    wheel = color_wheel()
    n = wheel.shape[0]
    angle = np.arctan2(-v, -u) / np.pi                 # in (-1, 1]
    fk = (angle + 1) / 2 * (n - 1)                      # 0 .. n-1
    k0 = np.floor(fk).astype(int)
    k1 = (k0 + 1) % n
    frac = (fk - k0)[..., None]
    col = ((1 - frac) * wheel[k0] + frac * wheel[k1]) / 255.0
    inside = (mag <= 1)[..., None]
    col = np.where(inside, 1 - mag[..., None] * (1 - col), col * 0.75)
    img = np.floor(255 * col).astype(np.uint8)
    img[bad] = 0
    return img
