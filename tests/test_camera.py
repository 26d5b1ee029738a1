"""Tests for f2depth.camera: lens (un)distortion round trips and intrinsics under crop and resize."""

from __future__ import annotations

import cv2
import fakes
import numpy as np
import pytest

from f2depth.camera import (
    NYU_RGB_DIST,
    NYU_RGB_K,
    NYU_SIZE_HW,
    crop_resize_intrinsics,
    distortion_maps,
    undistort_image,
    undistort_normalized,
)
from f2depth.data.prepare import crop_and_resize
from f2depth.formats.prepared import prepare_image


def distort_normalized(xy: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """Brown–Conrady forward model (OpenCV's): ideal normalised (..., 2) → distorted normalised (..., 2)."""
    k1, k2, p1, p2, k3 = (float(d) for d in dist[:5])
    x, y = xy[..., 0], xy[..., 1]
    r2 = x * x + y * y
    radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    return np.stack([x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x),
                     y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y], axis=-1)


def distort_image(image: np.ndarray, K: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """Ideal pinhole image → the image the distorted lens records, as f2depth.synth renders NYU raw frames."""
    map_x, map_y = distortion_maps(K, dist, image.shape[:2])
    return cv2.remap(image, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def _project(K: np.ndarray, X: np.ndarray) -> np.ndarray:
    p = K @ X
    return p[:2] / p[2]


def _blob(hw: tuple[int, int], uv: np.ndarray, sigma: float) -> np.ndarray:
    v, u = np.mgrid[0:hw[0], 0:hw[1]].astype(np.float64)
    return np.exp(-((u - uv[0]) ** 2 + (v - uv[1]) ** 2) / (2 * sigma**2)).astype(np.float32)


def _centroid(img: np.ndarray) -> np.ndarray:
    w = np.clip(img.astype(np.float64) - 0.01 * img.max(), 0, None)
    v, u = np.mgrid[0:img.shape[0], 0:img.shape[1]]
    return np.array([(w * u).sum(), (w * v).sum()]) / w.sum()


def test_undistort_normalized_inverts_distort_normalized():
    rng = np.random.default_rng(0)
    xy = rng.uniform([-0.62, -0.47], [0.62, 0.47], size=(2000, 2))  # the whole NYU field of view
    xd = distort_normalized(xy, NYU_RGB_DIST)
    uv = xd * NYU_RGB_K[[0, 1], [0, 1]] + NYU_RGB_K[:2, 2]
    back = undistort_normalized(uv, NYU_RGB_K, NYU_RGB_DIST)
    assert np.abs(back - xy).max() < 1e-9


def test_distort_then_undistort_image_round_trip():
    img = fakes.smooth_image(NYU_SIZE_HW, seed=4, cells=10).astype(np.float32)
    distorted = distort_image(img, NYU_RGB_K, NYU_RGB_DIST)
    assert np.abs(distorted - img).mean() > 5  # the NYU lens really moves pixels
    back = undistort_image(distorted, NYU_RGB_K, NYU_RGB_DIST)
    err = np.abs(back - img)[40:-40, 40:-40]
    assert err.mean() < 0.3 and err.max() < 3.0


def test_p2net_cxcy_bug_numbers():
    K = crop_resize_intrinsics(NYU_RGB_K, NYU_SIZE_HW, 16, (288, 384), p2net_cxcy_bug=True)
    got = [K[0, 0], K[1, 1], K[0, 2], K[1, 2]]
    np.testing.assert_allclose(got, [327.70, 333.94, 205.63, 163.12], atol=0.006)
    fixed = crop_resize_intrinsics(NYU_RGB_K, NYU_SIZE_HW, 16, (288, 384))
    assert fixed[0, 0] == K[0, 0] and fixed[1, 1] == K[1, 1]
    assert fixed[0, 2] == pytest.approx(195.53, abs=0.2) and fixed[1, 2] == pytest.approx(152.83, abs=0.2)


@pytest.mark.parametrize("hw", [(288, 384), (96, 128)])
def test_crop_resize_intrinsics_reproject_a_3d_point(hw):
    K_new = crop_resize_intrinsics(NYU_RGB_K, NYU_SIZE_HW, 16, hw)
    sigma = 3.0 * NYU_SIZE_HW[0] / hw[0]  # a few pixels wide at the new size
    for X in ([0.3, -0.2, 2.0], [-0.9, 0.5, 3.0], [0.05, 0.1, 1.0]):
        X = np.array(X)
        blob = _blob(NYU_SIZE_HW, _project(NYU_RGB_K, X), sigma)
        got = _centroid(crop_and_resize(blob, 16, hw))
        np.testing.assert_allclose(got, _project(K_new, X), atol=0.02)  # measured < 0.001 px


def test_prepare_image_pipeline_keeps_the_projection():
    """Ideal blob → NYU lens distortion → prepare (undistort, crop, resize): lands where K' projects it."""
    hw = (288, 384)
    K_new = crop_resize_intrinsics(NYU_RGB_K, NYU_SIZE_HW, 16, hw)
    X = np.array([-0.7, 0.45, 2.5])
    blob = _blob(NYU_SIZE_HW, _project(NYU_RGB_K, X), 8.0)
    distorted = distort_image(blob, NYU_RGB_K, NYU_RGB_DIST)
    assert np.abs(_centroid(distorted) - _project(NYU_RGB_K, X)).max() > 2  # distortion moved it
    got = _centroid(prepare_image(distorted, 16, hw))
    np.testing.assert_allclose(got, _project(K_new, X), atol=0.02)  # measured 0.005 px


def test_nearest_depth_resize_keeps_alignment():
    """Depth uses exact nearest sampling: a step edge stays where the image's edge lands."""
    hw = (96, 128)
    depth = np.ones(NYU_SIZE_HW, np.float32)
    depth[:, 336:] = 2.0  # edge between columns 335 and 336 → at x = 335.5 in the full image
    out = crop_and_resize(depth, 16, hw, nearest=True)
    K_new = crop_resize_intrinsics(NYU_RGB_K, NYU_SIZE_HW, 16, hw)
    s = K_new[0, 0] / NYU_RGB_K[0, 0]
    edge_new = (335.5 - 16 + 0.5) * s - 0.5
    cols = np.flatnonzero(out[0] == 2.0)
    assert set(np.unique(out)) == {1.0, 2.0}
    assert abs(cols[0] - 0.5 - edge_new) <= 0.5

