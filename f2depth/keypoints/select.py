"""DSO's hierarchical grid selection (``PixelSelector::select``, DSO's ``PixelSelector2.cpp``), vectorised.

Cells of size d = pot, 2d and 4d start at (0, 0) and are visited 4d-cell by 4d-cell in raster order,
then 2d sub-cells, then d sub-cells, then pixels, each in raster order. We permute the pixels into that
*visiting order* (padding the image to a multiple of 4d with non-candidates), so every cell of every
level is a contiguous segment and the per-cell maxima with first-in-visiting-order tie-break are plain
``argmax`` reductions.

The only sequential dependency is the direction of each cell, ``directions[pattern[n2] & 15]`` with
n2 the number of level-0 points selected before it. Whether a d-cell gets a level-0 point depends on
its direction only through exact zeros of the score ``|dx·a + dy·b|`` (e.g. a purely horizontal
gradient against the direction (0, 1)); per cell we keep a 16-bit mask of the directions under which
every candidate scores exactly 0. Cells whose mask is empty are selected whatever their direction,
cells where every candidate fails are never selected, so n2 is a cumulative sum, except at the few
"partial" cells, which a short loop resolves in order. Levels 1 and 2 never change n2.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from f2depth.keypoints.pyramid import make_images
from f2depth.keypoints.random_pattern import random_pattern
from f2depth.keypoints.thresholds import BLOCK, make_hists, pixel_thresholds

# DSO's 16 directions, as its float literals (PixelSelector2.cpp).
DIRECTIONS = np.array(
    [(0.0, 1.0000), (0.3827, 0.9239), (0.1951, 0.9808), (0.9239, 0.3827), (0.7071, 0.7071), (0.3827, -0.9239),
     (0.8315, 0.5556), (0.8315, -0.5556), (0.5556, -0.8315), (0.9808, 0.1951), (0.9239, -0.3827),
     (0.7071, -0.7071), (0.5556, 0.8315), (0.9808, -0.1951), (1.0000, 0.0000), (0.1951, -0.9808)],
    dtype=np.float32,
)  # fmt: skip
DOWNWEIGHT = np.float32(0.75)  # setting_gradDownweightPerLevel; TH1 = TH0·0.75, TH2 = TH1·0.75²
ALL_DIRECTIONS = 0xFFFF
_FLAG1, _FLAG2 = np.uint32(1 << 16), np.uint32(1 << 17)


@dataclass(frozen=True)
class Prepared:
    """What ``select`` needs from one image at one threshold factor, packed for a single gather.

    ``records`` (h·w + 1, 4) float32, one row per pixel in raster order plus a padding row:
    with ``direction``: dx, dy (level 0), then a uint32 (bit pattern) = zero-mask | flags << 16, where
    zero-mask bit k is set when the pixel is *not* a level-0 candidate under direction k (0xFFFF when
    it fails the level-0 threshold), flag 1 = level-1 candidate, flag 2 = level-2 candidate;
    without ``direction``: the level-0/1/2 scores (the squared gradient at (y>>l, x>>l)) where the
    pixel is a candidate of that level, else 0. The last column is unused (alignment).
    """

    height: int
    width: int
    direction: bool
    records: np.ndarray
    ths_smoothed: np.ndarray


def valid_box(height: int, width: int) -> tuple[slice, slice]:
    """Rows and columns DSO's select() looks at: 4 ≤ y ≤ h−4 and 4 ≤ x ≤ w−6."""
    return slice(4, max(height - 3, 4)), slice(4, max(width - 5, 4))


def _outside(array: np.ndarray, box: tuple[slice, slice], value) -> None:
    """Set everything of a (h, w, ...) array outside ``box`` to ``value``, in place."""
    rows, cols = box
    array[: rows.start] = value
    array[rows.stop :] = value
    array[:, : cols.start] = value
    array[:, cols.stop :] = value


def _spread(target: np.ndarray, coarse: np.ndarray, factor: int, combine=None) -> None:
    """``target[y, x] (op)= coarse[y // factor, x // factor]`` over the part of target (h, w) it covers."""
    hc, wc = coarse.shape
    view = target[: hc * factor, : wc * factor].reshape(hc, factor, wc, factor)
    if combine is None:
        view[...] = coarse[:, None, :, None]
    else:
        combine(view, coarse[:, None, :, None], out=view)


@lru_cache(maxsize=1)
def _zero_table() -> np.ndarray:
    """Direction-zero bits for every half-integer gradient pair of 8-bit images: (511, 511) uint16.

    Entry [2dx+255, 2dy+255] has bit k set when fl(dx·a_k) + fl(dy·b_k) == 0 in float32, i.e. when
    fl(dx·a_k) == −fl(dy·b_k).
    """
    values = (np.arange(511, dtype=np.float32) - np.float32(255)) * np.float32(0.5)
    table = np.zeros((511, 511), np.uint16)
    for k, (a, b) in enumerate(DIRECTIONS):
        px = values * a
        py = values * b
        table |= (px[:, None] == -py[None, :]).astype(np.uint16) << np.uint16(k)
    table.setflags(write=False)
    return table


def direction_zero_mask(dx: np.ndarray, dy: np.ndarray, half_integer: bool) -> np.ndarray:
    """Bit k set where the float32 score |dx·a_k + dy·b_k| is exactly 0; same shape as dx, uint16.

    ``half_integer``: the gradients come from an 8-bit image (|2dx| ≤ 255, integer), so a table lookup
    replaces the 16 products.
    """
    if half_integer:
        ix = (dx * np.float32(2)).astype(np.int32) + 255
        iy = (dy * np.float32(2)).astype(np.int32) + 255
        return _zero_table()[ix, iy]
    mask = np.zeros(dx.shape, np.uint16)
    for k, (a, b) in enumerate(DIRECTIONS):
        mask |= ((dx * a + dy * b) == 0).astype(np.uint16) << np.uint16(k)
    return mask


def prepare(gray: np.ndarray, th_factor: float = 1.0, direction: bool = True,
            hist_add: float = 7.0) -> Prepared:
    """Pyramid, gradients, thresholds and candidates of a grey image (h, w), uint8 or float32.

    Level-L tests ``ag_L > TH_L·th_factor`` are done on level L's own grid (TH_L is constant over the
    2^L × 2^L pixels that share ``ag_L``) and spread to level 0.
    """
    gray = np.asarray(gray)
    if gray.ndim != 2:
        raise ValueError(f"expected a grey image of shape (H, W), got shape {gray.shape}")
    height, width = gray.shape
    levels = make_images(gray, 3)
    ths = make_hists(levels[0].abs_sq, hist_add)
    factor = np.float32(th_factor)
    ths1 = ths * DOWNWEIGHT
    ths2 = ths1 * (DOWNWEIGHT * DOWNWEIGHT)
    box = valid_box(height, width)
    ag0 = levels[0].abs_sq
    cand0 = np.zeros((height, width), bool)
    cand0[box] = ag0[box] > pixel_thresholds(ths * factor, height, width)[box]
    ag1, ag2 = levels[1].abs_sq, levels[2].abs_sq
    pass1 = ag1 > pixel_thresholds(ths1 * factor, *ag1.shape, block=BLOCK // 2)
    pass2 = ag2 > pixel_thresholds(ths2 * factor, *ag2.shape, block=BLOCK // 4)
    records = np.zeros((height * width + 1, 4), np.float32)
    grid = records[:-1].reshape(height, width, 4)
    if direction:
        dx, dy = levels[0].dx, levels[0].dy
        grid[..., 0] = dx
        grid[..., 1] = dy
        word = np.full((height, width), ALL_DIRECTIONS, np.uint32)
        _spread(word, pass1.astype(np.uint32) << np.uint32(16), 2, np.bitwise_or)
        _spread(word, pass2.astype(np.uint32) << np.uint32(17), 4, np.bitwise_or)
        flat = word.reshape(-1)
        idx = np.flatnonzero(cand0)
        zero = direction_zero_mask(dx.reshape(-1)[idx], dy.reshape(-1)[idx], gray.dtype == np.uint8)
        flat[idx] &= zero.astype(np.uint32) | np.uint32(0xFFFF0000)
        _outside(word, box, ALL_DIRECTIONS)
        packed = records.view(np.uint32)[:, 2]
        packed[:-1] = flat
        packed[-1] = ALL_DIRECTIONS
    else:
        np.multiply(ag0, cand0, out=grid[..., 0])
        _spread(grid[..., 1], ag1 * pass1, 2)
        _spread(grid[..., 2], ag2 * pass2, 4)
        _outside(grid, box, 0)
    return Prepared(height, width, direction, records, ths)


@lru_cache(maxsize=16)
def _visiting_order(height: int, width: int, pot: int) -> np.ndarray:
    """Flat raster indices of the padded image in visiting order; out-of-image entries = h·w (a sentinel).

    Shape (H4·W4·16·pot²,) intp with H4 = ceil(h / 4pot), W4 = ceil(w / 4pot).
    """
    d = pot
    h4, w4 = -(-height // (4 * d)), -(-width // (4 * d))
    ys = np.arange(h4 * 4 * d).reshape(h4, 2, 2, d)
    xs = np.arange(w4 * 4 * d).reshape(w4, 2, 2, d)
    y = ys[:, None, :, None, :, None, :, None]
    x = xs[None, :, None, :, None, :, None, :]
    flat = np.where((y < height) & (x < width), y * width + x, height * width)
    order = np.ascontiguousarray(flat, dtype=np.intp).reshape(-1)
    order.setflags(write=False)
    return order


def _gather(records: np.ndarray, order: np.ndarray) -> np.ndarray:
    """Rows of ``records`` (h·w + 1, 4) float32 in visiting order (one 16-byte gather)."""
    rows = records.view(np.complex128).reshape(-1).take(order, mode="clip")
    return rows.view(np.float32).reshape(-1, 4)


def _decode(visit_index: np.ndarray, pot: int, w4: int) -> tuple[np.ndarray, np.ndarray]:
    """Visiting-order positions → (x, y) image coordinates."""
    v = visit_index.astype(np.int64)
    ox, v = v % pot, v // pot
    oy, v = v % pot, v // pot
    sx2, v = v % 2, v // 2
    sy2, v = v % 2, v // 2
    sx3, v = v % 2, v // 2
    sy3, v = v % 2, v // 2
    cx4, cy4 = v % w4, v // w4
    x = cx4 * 4 * pot + sx3 * 2 * pot + sx2 * pot + ox
    y = cy4 * 4 * pot + sy3 * 2 * pot + sy2 * pot + oy
    return x, y


def _level0_cells(cell_zero: np.ndarray, pattern_dir: np.ndarray) -> np.ndarray:
    """Which d-cells (visiting order) get a level-0 point, resolving the running count n2 in order."""
    full = cell_zero == 0
    partial = np.flatnonzero((cell_zero != ALL_DIRECTIONS) & ~full)
    selected = full.copy()
    if partial.size:
        before = np.cumsum(full) - full  # level-0 points of always-selected cells before each cell
        base = before[partial].tolist()
        masks = cell_zero[partial].tolist()
        extra = 0
        hits = []
        for i, n_before in enumerate(base):
            if not (masks[i] >> int(pattern_dir[n_before + extra])) & 1:
                extra += 1
                hits.append(partial[i])
        selected[hits] = True
    return selected


def _best(score: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per row: first argmax and max of a (cells, pixels) score array."""
    arg = score.argmax(axis=1)
    return arg, np.take_along_axis(score, arg[:, None], axis=1)[:, 0]


def _scores(dx: np.ndarray, dy: np.ndarray, cell: int, rows: np.ndarray, candidate: np.ndarray,
            dirs: np.ndarray) -> np.ndarray:
    """|dx·a + dy·b| in the cells ``rows`` of size ``cell`` (visiting order), one direction index per
    cell, 0 where not a candidate; (len(rows), cell) float32."""
    a = DIRECTIONS[dirs, 0][:, None]
    b = DIRECTIONS[dirs, 1][:, None]
    score = dx.reshape(-1, cell)[rows] * a
    score += dy.reshape(-1, cell)[rows] * b
    np.abs(score, out=score)
    score *= candidate
    return score


def select(prep: Prepared, pot: int) -> tuple[np.ndarray, tuple[int, int, int]]:
    """DSO's select() at cell size ``pot``: points (N, 3) int64 = x, y, level in raster order, and counts.

    Level 0/1/2 corresponds to DSO's selection-map value 1/2/4; counts are (n_level0, n_level1, n_level2).
    The score is the random-direction projection when ``prep.direction``, else the squared gradient.
    """
    if pot < 1:
        raise ValueError(f"pot must be >= 1, got {pot}")
    h, w, d = prep.height, prep.width, int(pot)
    c1, c2, c4 = d * d, 4 * d * d, 16 * d * d
    rec = _gather(prep.records, _visiting_order(h, w, d))
    if prep.direction:
        dx, dy = rec[:, 0], rec[:, 1]
        packed = rec.view(np.uint32)[:, 2]
        # n2 never exceeds the number of cells with a candidate, so h·w + 1 pattern bytes suffice.
        pattern_dir = random_pattern(h * w + 1) & np.uint8(15)
        cell_zero = np.bitwise_and.reduce(packed.reshape(-1, c1), axis=1) & np.uint32(ALL_DIRECTIONS)
        sel0 = _level0_cells(cell_zero, pattern_dir)
        dir_cell = pattern_dir[np.cumsum(sel0) - sel0]
        rows0 = np.flatnonzero(sel0)
        cand = (packed.reshape(-1, c1)[rows0] & np.uint32(ALL_DIRECTIONS)) != ALL_DIRECTIONS
        arg0, _ = _best(_scores(dx, dy, c1, rows0, cand, dir_cell[rows0]))
        flags2 = np.bitwise_or.reduce(packed.reshape(-1, c2), axis=1)
        taken2 = sel0.reshape(-1, 4).any(axis=1)
        rows1 = np.flatnonzero(~taken2 & ((flags2 & _FLAG1) > 0))
        cand = (packed.reshape(-1, c2)[rows1] & _FLAG1) > 0
        arg1, val1 = _best(_scores(dx, dy, c2, rows1, cand, dir_cell[rows1 * 4]))
        taken2[rows1[val1 > 0]] = True
        flags4 = np.bitwise_or.reduce(flags2.reshape(-1, 4), axis=1)
        rows2 = np.flatnonzero(~taken2.reshape(-1, 4).any(axis=1) & ((flags4 & _FLAG2) > 0))
        cand = (packed.reshape(-1, c4)[rows2] & _FLAG2) > 0
        arg2, val2 = _best(_scores(dx, dy, c4, rows2, cand, dir_cell[rows2 * 16]))
    else:
        arg0, val0 = _best(rec[:, 0].reshape(-1, c1))
        rows0 = np.flatnonzero(val0 > 0)
        arg0 = arg0[rows0]
        taken2 = np.zeros(val0.size // 4, bool)
        taken2[rows0 // 4] = True
        rows1 = np.flatnonzero(~taken2)
        arg1, val1 = _best(rec[:, 1].reshape(-1, c2)[rows1])
        taken2[rows1[val1 > 0]] = True
        rows2 = np.flatnonzero(~taken2.reshape(-1, 4).any(axis=1))
        arg2, val2 = _best(rec[:, 2].reshape(-1, c4)[rows2])
    keep1, keep2 = val1 > 0, val2 > 0
    visit = np.concatenate([rows0 * c1 + arg0, rows1[keep1] * c2 + arg1[keep1],
                            rows2[keep2] * c4 + arg2[keep2]])
    counts = (int(rows0.size), int(keep1.sum()), int(keep2.sum()))
    level = np.repeat(np.arange(3), counts)
    x, y = _decode(visit, d, -(-w // (4 * d)))
    points = np.stack([x, y, level], axis=1)
    return points[np.argsort(y * w + x, kind="stable")], counts
