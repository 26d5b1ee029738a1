"""DSO's adaptive block thresholds (``makeHists`` in DSO's ``PixelSelector2.cpp``), in float32.

Per 32×32 block: the histogram of ``g = min((int)sqrt(|∇I|²), 48)`` over pixels with
``1 ≤ x ≤ w−2`` and ``1 ≤ y ≤ h−2``, its upper median (DSO's ``computeHistQuantil(hist, 0.5)``)
plus ``hist_add`` (7); then the square of the mean over the 3×3 neighbouring blocks.

Sizes that are not multiples of 32 (our choice, documented; DSO itself aliases blocks there):
the block grid is ``ceil(h/32) × ceil(w/32)`` and the right/bottom blocks are partial, holding the
pixels they cover. A partial block that counts no pixel (a strip one pixel wide, all in the excluded
border) takes no part in the smoothing and gets the mean of its non-empty neighbours. For sizes that are
multiples of 32 this is exactly DSO.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

BLOCK = 32
HIST_MAX = 48  # g is clipped to this value
QUANTILE_NONE = 90  # DSO's result when the scan never ends (an empty histogram)


def block_grid(height: int, width: int) -> tuple[int, int]:
    """Number of threshold blocks (rows, columns): partial edge blocks included."""
    return -(-height // BLOCK), -(-width // BLOCK)


@lru_cache(maxsize=8)
def _histogram_base(height: int, width: int) -> np.ndarray:
    """(block index)·49 for the counted pixels [1, h−2] × [1, w−2]; (h−2, w−2) intp, read-only."""
    w32 = block_grid(height, width)[1]
    by = (np.arange(1, height - 1) // BLOCK)[:, None]
    bx = (np.arange(1, width - 1) // BLOCK)[None, :]
    base = ((by * w32 + bx) * (HIST_MAX + 1)).astype(np.intp)
    base.setflags(write=False)
    return base


def block_quantiles(abs_sq0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Upper median of ``g`` per block and the number of counted pixels; abs_sq0 (h, w) float32.

    Returns ``(quantile, count)``, both (h32, w32) int64. The quantile is the smallest ``i`` with
    ``#{g ≤ i} > T``, ``T = (int)(N·0.5 + 0.5)``, which is DSO's scan; with ``N = 1`` (only possible
    in a partial block) T is clamped to ``N − 1`` instead of reading undefined bins; ``N = 0`` gives 90.
    """
    h, w = abs_sq0.shape
    h32, w32 = block_grid(h, w)
    if h < 3 or w < 3:
        return np.full((h32, w32), QUANTILE_NONE, np.int64), np.zeros((h32, w32), np.int64)
    # float32 sqrt then truncation, as (int)sqrtf; clipping before truncating gives the same value.
    g = np.minimum(np.sqrt(abs_sq0[1 : h - 1, 1 : w - 1]), np.float32(HIST_MAX)).astype(np.intp)
    g += _histogram_base(h, w)
    hist = np.bincount(g.ravel(), minlength=h32 * w32 * (HIST_MAX + 1)).reshape(h32, w32, HIST_MAX + 1)
    count = hist.sum(axis=2)
    target = np.floor(count.astype(np.float32) * np.float32(0.5) + np.float32(0.5)).astype(np.int64)
    target = np.minimum(target, np.maximum(count - 1, 0))
    cumulative = np.cumsum(hist, axis=2)
    above = cumulative > target[:, :, None]
    quantile = np.where(above.any(axis=2), above.argmax(axis=2), QUANTILE_NONE)
    return quantile, count


def smooth_thresholds(ths: np.ndarray, valid: np.ndarray | None = None) -> np.ndarray:
    """``thsSmoothed``: the squared mean of ``ths`` (h32, w32) over each 3×3 block neighbourhood.

    Neighbourhoods are clipped to the grid; blocks where ``valid`` is False are left out of every mean.
    Result (h32, w32) float32, to be compared with squared gradients.
    """
    ths = ths.astype(np.float32)
    valid = np.ones(ths.shape, bool) if valid is None else valid
    values = np.pad(np.where(valid, ths, np.float32(0)), 1)
    weights = np.pad(valid.astype(np.float32), 1)
    h32, w32 = ths.shape
    total = np.zeros(ths.shape, np.float32)
    num = np.zeros(ths.shape, np.float32)
    for oy in range(3):
        for ox in range(3):
            total += values[oy : oy + h32, ox : ox + w32]
            num += weights[oy : oy + h32, ox : ox + w32]
    mean = np.divide(total, num, out=np.zeros_like(total), where=num > 0)
    return mean * mean


def make_hists(abs_sq0: np.ndarray, hist_add: float = 7.0) -> np.ndarray:
    """DSO's smoothed squared block thresholds (h32, w32) float32 for a level-0 ``|∇I|²`` (h, w)."""
    quantile, count = block_quantiles(abs_sq0)
    ths = quantile.astype(np.float32) + np.float32(hist_add)
    return smooth_thresholds(ths, count > 0)


def pixel_thresholds(ths_smoothed: np.ndarray, height: int, width: int, block: int = BLOCK) -> np.ndarray:
    """The threshold of every pixel (height, width) float32: the value of its ``block``×``block`` block
    (32 at level 0; 16 and 8 on the level-1 and level-2 grids)."""
    full = np.repeat(np.repeat(ths_smoothed, block, axis=0), block, axis=1)
    return np.ascontiguousarray(full[:height, :width])
