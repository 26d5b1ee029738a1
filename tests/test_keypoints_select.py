"""Invariants of select() and makeMaps on seeded random images, odd sizes, flat images, float input."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from f2depth.keypoints import KeypointSelector, select_pixels
from f2depth.keypoints.makemaps import ideal_potential, make_maps
from f2depth.keypoints.select import DIRECTIONS, direction_zero_mask, prepare, select, valid_box


def valid_region(height: int, width: int) -> np.ndarray:
    """The valid pixels of DSO's select() (:func:`valid_box`) as a (h, w) bool mask."""
    valid = np.zeros((height, width), bool)
    valid[valid_box(height, width)] = True
    return valid


def select_raw(gray: np.ndarray, pot: int, direction: bool = True) -> np.ndarray:
    """DSO's select() alone at cell size ``pot``: no adaptation, no thinning; (N, 3) x, y, level."""
    return select(prepare(gray, direction=direction), int(pot))[0]


def random_image(seed: int, hw=(192, 256)) -> np.ndarray:
    """Blurred noise with a few flat rectangles (strong and weak texture), uint8 (H, W)."""
    rng = np.random.default_rng(seed)
    img = cv2.GaussianBlur(rng.normal(128, 50, hw).astype(np.float32), (0, 0), 1.5)
    for _ in range(4):
        y, x = rng.integers(0, max(hw[0] - 20, 1)), rng.integers(0, max(hw[1] - 20, 1))
        img[y : y + rng.integers(10, 60), x : x + rng.integers(10, 80)] = rng.uniform(0, 255)
    return np.clip(img, 0, 255).astype(np.uint8)


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("pot", [1, 2, 3, 5])
def test_select_invariants(seed, pot):
    image = random_image(seed)
    h, w = image.shape
    points = select_raw(image, pot)
    x, y, level = points.T
    valid = valid_region(h, w)
    assert valid[y, x].all(), "points outside DSO's valid region 4 <= x <= w-6, 4 <= y <= h-4"
    assert set(np.unique(level)) <= {0, 1, 2}
    assert np.all(np.diff(y * w + x) > 0), "not in raster order or a pixel twice"
    # at most one point per pot cell, per 2pot cell at level >= 1 and per 4pot cell at level 2
    for lvl, size in ((0, pot), (1, 2 * pot), (2, 4 * pot)):
        sel = points[level >= lvl] if lvl else points
        cells = (sel[:, 1] // size) * 10_000 + sel[:, 0] // size
        assert len(np.unique(cells)) == len(cells), f"two points in one {size}x{size} cell (level {lvl})"
    # a level-1 point's 2pot cell holds no level-0 point; a level-2 point's 4pot cell holds nothing else
    for lvl, size in ((1, 2 * pot), (2, 4 * pot)):
        coarse = points[level == lvl]
        finer = points[level < lvl]
        coarse_cells = set(((coarse[:, 1] // size) * 10_000 + coarse[:, 0] // size).tolist())
        finer_cells = set(((finer[:, 1] // size) * 10_000 + finer[:, 0] // size).tolist())
        assert not coarse_cells & finer_cells


def test_level0_points_beat_their_threshold_and_cells_are_exhaustive():
    image = random_image(7)
    prep = prepare(image, direction=False)
    points, counts = select(prep, 2)
    ag0 = prep.records[:-1, 0].reshape(image.shape)  # level-0 score, 0 where not a candidate
    lvl0 = points[points[:, 2] == 0]
    assert (ag0[lvl0[:, 1], lvl0[:, 0]] > 0).all()
    # every 2x2 cell with a candidate has a level-0 point, and it is the cell's maximum
    h, w = image.shape
    cells = ag0[: h // 2 * 2, : w // 2 * 2].reshape(h // 2, 2, w // 2, 2).max(axis=(1, 3))
    assert (cells > 0).sum() == counts[0] == len(lvl0)
    np.testing.assert_array_equal(cells[lvl0[:, 1] // 2, lvl0[:, 0] // 2], ag0[lvl0[:, 1], lvl0[:, 0]])


@pytest.mark.parametrize("seed", [3, 4])
@pytest.mark.parametrize("density", [300, 800])
def test_make_maps_count_near_density(seed, density):
    image = random_image(seed)
    selector = KeypointSelector("dso", density=density, recursions=3)
    points = selector(image)
    result = selector.last
    assert result.pots[0] == 3 and len(result.pots) <= 4
    # after thinning the count is ~density (binomial), or below it when the pot could not go lower
    if result.quotia < 0.95:
        assert abs(len(points) - density) < 0.12 * density + 30
    else:
        assert len(points) == sum(result.counts)
        assert len(points) <= density / 0.95 + 1 or len(result.pots) == 4
    # the pot for the next frame follows DSO's formula on the last select
    assert selector.pot == ideal_potential(sum(result.counts), result.pots[-1], density)


def test_pot_carries_over_a_sequence():
    images = [random_image(s) for s in (10, 11, 12)]
    selector = KeypointSelector("dso", density=400)
    starts, ends = [], []
    for image in images:
        starts.append(selector.pot)
        selector(image)
        assert selector.last.pots[0] == starts[-1]
        ends.append(selector.pot)
    assert starts[0] == 3 and starts[1:] == ends[:-1]
    assert ends[0] != 3  # so carrying the pot over makes a difference here
    # a fresh selector on the second frame starts at 3 again and gives a different selection
    carried = KeypointSelector("dso", density=400, pot=ends[0])(images[1])
    np.testing.assert_array_equal(carried, KeypointSelector("dso", density=400, pot=starts[1])(images[1]))
    assert not np.array_equal(carried, select_pixels(images[1], "dso", density=400))


@pytest.mark.parametrize("preset", ["dso", "p2net"])
@pytest.mark.parametrize("hw", [(480, 640), (96, 128), (30, 40)])
def test_flat_image_gives_no_points(preset, hw):
    for value in (0, 128, 255):
        points = select_pixels(np.full(hw, value, np.uint8), preset)
        assert points.shape == (0, 3) and np.issubdtype(points.dtype, np.integer)


@pytest.mark.parametrize("hw", [(100, 150), (97, 131), (33, 70), (16, 16), (8, 8)])
def test_sizes_not_multiple_of_32_run(hw):
    image = random_image(5, hw)
    for preset in ("dso", "p2net"):
        points = select_pixels(image, preset)
        assert points.ndim == 2 and points.shape[1] == 3
        if len(points):
            assert (points[:, 0] < hw[1]).all() and (points[:, 1] < hw[0]).all() and points.min() >= 0
    raw = select_raw(image, 2)
    assert valid_region(*hw)[raw[:, 1], raw[:, 0]].all()
    if min(hw) >= 32:
        assert len(raw) > 0


def test_partial_blocks_match_dso_on_full_blocks():
    # Cropping a 640x480 image to 650x490 (by padding with texture) must not change the thresholds of
    # the full blocks away from the new partial ones: thresholds of blocks two or more blocks away agree.
    image = random_image(6, (480, 640))
    bigger = random_image(8, (490, 650))
    bigger[:480, :640] = image
    ths_a = prepare(image).ths_smoothed
    ths_b = prepare(bigger).ths_smoothed
    assert ths_b.shape == (16, 21)
    np.testing.assert_array_equal(ths_a[:-2, :-2], ths_b[:13, :18])


def test_float_input_matches_uint8():
    image = random_image(9)
    for direction in (True, False):
        a = select_raw(image, 2, direction)
        b = select_raw(image.astype(np.float32), 2, direction)
        np.testing.assert_array_equal(a, b)


def test_zero_mask_table_matches_direct_products():
    rng = np.random.default_rng(0)
    dx = (rng.integers(-255, 256, 5000) / 2).astype(np.float32)
    dy = (rng.integers(-255, 256, 5000) / 2).astype(np.float32)
    dx[:50], dy[50:100], dy[100:150] = 0, 0, -dx[100:150]  # axis-aligned and diagonal gradients
    table = direction_zero_mask(dx, dy, half_integer=True)
    direct = direction_zero_mask(dx, dy, half_integer=False)
    np.testing.assert_array_equal(table, direct)
    assert (table[:50] & (1 << 14)).all() and (table[50:100] & 1).all()  # (1,0) and (0,1) directions
    assert (table[100:150] & (1 << 4)).all()  # (0.7071, 0.7071) against dx = -dy
    assert DIRECTIONS.dtype == np.float32 and DIRECTIONS.shape == (16, 2)


def test_make_maps_validates_arguments():
    prep = prepare(random_image(0, (64, 64)))
    with pytest.raises(ValueError, match="density"):
        make_maps(prep, 3, 0)
    with pytest.raises(ValueError, match="pot"):
        select(prep, 0)
    with pytest.raises(ValueError, match="grey image"):
        select_pixels(np.zeros((10, 10, 3), np.uint8))
