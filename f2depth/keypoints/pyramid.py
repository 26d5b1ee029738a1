"""DSO's image pyramid and gradients (DSO's ``FrameHessian::makeImages``, ``HessianBlocks.cpp``), in float32.

Level ``l`` is ``(w >> l) × (h >> l)``, a 2×2 box average of level ``l−1`` (odd last row/column
dropped). Gradients are central differences halved, over the flat index range ``[w, w·(h−1))``:
rows 1..h−2, every column, with DSO's wrap-around at row ends. Rows 0 and h−1 are never written by
DSO (uninitialised memory there); here they are 0, what the DSO reference build the tests use reads.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

_HALF = np.float32(0.5)
_QUARTER = np.float32(0.25)


@dataclass(frozen=True)
class LevelGradients:
    """One pyramid level: ``image``, ``dx``, ``dy``, ``abs_sq`` = dx²+dy², each (h_l, w_l) float32."""

    image: np.ndarray
    dx: np.ndarray
    dy: np.ndarray
    abs_sq: np.ndarray


def downsample(image: np.ndarray) -> np.ndarray:
    """2×2 box mean ``0.25·(((a + b) + c) + d)`` in float32; image (h, w) → (h//2, w//2)."""
    h2, w2 = image.shape[0] // 2, image.shape[1] // 2
    top = image[0 : 2 * h2 : 2, : 2 * w2]
    bottom = image[1 : 2 * h2 : 2, : 2 * w2]
    total = top[:, 0::2] + top[:, 1::2]
    total += bottom[:, 0::2]
    total += bottom[:, 1::2]
    total *= _QUARTER
    return total


def gradients(image: np.ndarray, sanitize: bool = True) -> LevelGradients:
    """DSO's gradients of a float32 image (h, w); border rows are zero, row ends wrap as in DSO.

    ``sanitize`` sets non-finite gradients to 0 as DSO does (skippable when the image is finite).
    """
    h, w = image.shape
    dx = np.zeros((h, w), np.float32)
    dy = np.zeros((h, w), np.float32)
    if h >= 3 and w >= 2:
        flat = image.reshape(-1)
        lo, hi = w, w * (h - 1)
        fdx = dx.reshape(-1)
        fdy = dy.reshape(-1)
        np.subtract(flat[lo + 1 : hi + 1], flat[lo - 1 : hi - 1], out=fdx[lo:hi])
        fdx[lo:hi] *= _HALF
        np.subtract(flat[lo + w : hi + w], flat[lo - w : hi - w], out=fdy[lo:hi])
        fdy[lo:hi] *= _HALF
        if sanitize:
            np.nan_to_num(dx, copy=False, nan=0.0, posinf=0.0, neginf=0.0)
            np.nan_to_num(dy, copy=False, nan=0.0, posinf=0.0, neginf=0.0)
    abs_sq = dx * dx
    abs_sq += dy * dy
    return LevelGradients(image, dx, dy, abs_sq)


def make_images(gray: np.ndarray, levels: int = 3) -> list[LevelGradients]:
    """Pyramid levels 0..levels−1 of ``gray`` (h, w) with gradients; the input is converted to float32."""
    image = np.ascontiguousarray(gray, dtype=np.float32)
    sanitize = not np.issubdtype(np.asarray(gray).dtype, np.integer) and not np.isfinite(image).all()
    out = [gradients(image, sanitize)]
    for _ in range(1, levels):
        image = downsample(image)
        out.append(gradients(image, sanitize))
    return out
