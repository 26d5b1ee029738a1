"""The camera between scene radiance and 8-bit pixels: exposure, vignetting, tone curve and noise."""

from __future__ import annotations

import numpy as np


def vignette_map(K: np.ndarray, hw: tuple[int, int], strength: float) -> np.ndarray:
    """(H, W) float32 gain ``(1 - strength · r²)²`` with r the distance to the principal point divided
    by the distance of the farthest image corner (a smooth cos⁴-like fall-off)."""
    h, w = hw
    u = (np.arange(w) - K[0, 2]) / K[0, 0]
    v = (np.arange(h) - K[1, 2]) / K[1, 1]
    r2 = u[None, :] ** 2 + v[:, None] ** 2
    r2 = r2 / r2.max()
    return ((1.0 - strength * r2) ** 2).astype(np.float32)


def exposure_series(n: int, rng: np.random.Generator, jitter: float) -> np.ndarray:
    """(n,) gains around 1 drifting by ~``jitter`` relative per second-ish: a smoothed random walk, so that
    consecutive frames differ by well under a percent and a sequence by a few percent."""
    steps = rng.standard_normal(n) * jitter * 0.35
    walk = np.cumsum(steps)
    kernel = np.hanning(9)
    walk = np.convolve(np.pad(walk, 4, mode="edge"), kernel / kernel.sum(), mode="valid")
    return np.exp(walk - walk.mean()).astype(np.float64)


def tone(x: np.ndarray) -> np.ndarray:
    """Linear exposure → display value in [0, 1]: a soft highlight shoulder, then the sRGB curve."""
    x = np.maximum(x, 0.0)
    x = np.where(x < 0.8, x, 0.8 + 0.2 * np.tanh((x - 0.8) / 0.2))
    x = np.minimum(x, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


_LUT_MAX = 4.0  # linear values above saturate anyway
_LUT_N = 8192
#: tone() in 8-bit levels, tabulated over sqrt(x) (fine steps where the curve is steep)
_TONE_LUT = (tone((np.linspace(0.0, 1.0, _LUT_N) ** 2) * _LUT_MAX) * 255.0).astype(np.float32)


def expose(radiance: np.ndarray, gain: float, vignette: np.ndarray | None, noise_std: float,
           rng: np.random.Generator | None) -> np.ndarray:
    """Linear radiance (H, W, 3) → RGB uint8 (H, W, 3).

    ``gain`` scales the radiance (scene exposure × per-frame change), ``vignette`` (H, W) multiplies it,
    ``noise_std`` is the noise in 8-bit levels at mid-grey (signal-dependent: read + shot noise).
    """
    x = radiance * np.float32(gain)
    if vignette is not None:
        x = x * vignette[..., None]
    idx = np.sqrt(np.minimum(x, _LUT_MAX) * np.float32(1.0 / _LUT_MAX)) * np.float32(_LUT_N - 1)
    idx = idx + np.float32(0.5)
    y = _TONE_LUT[np.maximum(idx, 0).astype(np.intp)]
    if noise_std > 0 and rng is not None:
        std = noise_std * np.sqrt(0.3 + 0.7 * y / 128.0)
        y = y + std * rng.standard_normal(y.shape, dtype=np.float32)
    return np.clip(np.rint(y), 0, 255).astype(np.uint8)
