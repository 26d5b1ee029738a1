"""Pyramid, gradients and block thresholds against direct transcriptions of DSO's makeImages and makeHists."""

from __future__ import annotations

import numpy as np

from f2depth.keypoints.pyramid import downsample, gradients, make_images
from f2depth.keypoints.thresholds import block_quantiles, make_hists, pixel_thresholds, smooth_thresholds


def test_gradients_flat_index_with_wrap_and_zero_border_rows():
    rng = np.random.default_rng(0)
    image = rng.integers(0, 256, (7, 9)).astype(np.float32)
    g = gradients(image)
    h, w = image.shape
    flat = image.ravel()
    for idx in range(w, w * (h - 1)):
        dx = np.float32(0.5) * (flat[idx + 1] - flat[idx - 1])  # wraps at row ends, as DSO
        dy = np.float32(0.5) * (flat[idx + w] - flat[idx - w])
        assert g.dx.ravel()[idx] == dx and g.dy.ravel()[idx] == dy
        assert g.abs_sq.ravel()[idx] == dx * dx + dy * dy
    assert not g.dx[[0, -1]].any() and not g.dy[[0, -1]].any() and not g.abs_sq[[0, -1]].any()


def test_pyramid_box_mean_drops_odd_row_and_column():
    image = np.arange(7 * 9, dtype=np.float32).reshape(7, 9)
    half = downsample(image)
    assert half.shape == (3, 4)
    assert half[1, 2] == np.float32(0.25) * (image[2, 4] + image[2, 5] + image[3, 4] + image[3, 5])
    levels = make_images(np.zeros((48, 64), np.uint8), 3)
    assert [lv.abs_sq.shape for lv in levels] == [(48, 64), (24, 32), (12, 16)]


def test_block_quantile_is_upper_median_of_counted_pixels():
    rng = np.random.default_rng(1)
    abs_sq = rng.uniform(0, 60, (64, 96)).astype(np.float32) ** 2
    quantile, count = block_quantiles(abs_sq)
    assert quantile.shape == (2, 3)
    assert count[0, 0] == 31 * 31 and count[0, 1] == 31 * 32 and count[1, 1] == 31 * 32
    g = np.minimum(np.sqrt(abs_sq).astype(np.int64), 48)
    for by in range(2):
        for bx in range(3):
            ys = slice(max(32 * by, 1), min(32 * by + 32, 63))
            xs = slice(max(32 * bx, 1), min(32 * bx + 32, 95))
            values = np.sort(g[ys, xs].ravel())
            t = int(np.float32(values.size) * np.float32(0.5) + np.float32(0.5))
            assert quantile[by, bx] == values[t]


def test_smoothing_means_over_clipped_neighbourhoods_then_squares():
    ths = np.arange(12, dtype=np.float32).reshape(3, 4) + 7
    smoothed = smooth_thresholds(ths)
    assert smoothed[0, 0] == np.float32(ths[:2, :2].sum() / np.float32(4)) ** 2
    assert smoothed[1, 1] == np.float32(ths[:3, :3].sum() / np.float32(9)) ** 2
    assert smoothed[0, 2] == np.float32(ths[:2, 1:4].sum() / np.float32(6)) ** 2
    # an invalid (empty) block is left out of its neighbours' means and takes theirs
    valid = np.ones((3, 4), bool)
    valid[:, 3] = False
    partial = smooth_thresholds(ths, valid)
    assert partial[0, 3] == np.float32(ths[:2, 2].sum() / np.float32(2)) ** 2
    assert partial[0, 2] == np.float32(ths[:2, 1:3].sum() / np.float32(4)) ** 2


def test_flat_image_thresholds_and_pixel_map():
    ths = make_hists(np.zeros((96, 128), np.float32))
    np.testing.assert_array_equal(ths, np.full((3, 4), 49, np.float32))  # (0 + 7)^2
    th0 = pixel_thresholds(np.arange(12, dtype=np.float32).reshape(3, 4), 70, 100)
    assert th0.shape == (70, 100) and th0[69, 99] == 11 and th0[31, 32] == 1 and th0[32, 31] == 4
