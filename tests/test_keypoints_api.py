"""Presets, overrides and P²Net's rescaling to the training size."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from f2depth.keypoints import PRESETS, KeypointSelector, get_preset, rescale_points, select_pixels


def textured(hw, seed=0):
    rng = np.random.default_rng(seed)
    img = cv2.GaussianBlur(rng.normal(128, 60, hw).astype(np.float32), (0, 0), 1.0)
    return np.clip(img, 0, 255).astype(np.uint8)


def test_presets():
    dso, p2net = PRESETS["dso"], PRESETS["p2net"]
    assert (dso.density, dso.recursions, dso.direction, dso.th_factor, dso.pot) == (1500, 1, True, 1.0, 3)
    assert dso.work_size is None
    assert (p2net.density, p2net.recursions, p2net.direction, p2net.work_size) == (2000, 3, False, (480, 640))
    assert p2net.max_points == 2500
    assert get_preset("dso", density=600).density == 600
    with pytest.raises(ValueError, match="unknown keypoint preset"):
        get_preset("harris")
    with pytest.raises(TypeError, match="unknown selector option"):
        get_preset("dso", densty=3)
    with pytest.raises(ValueError, match="pot >= 1"):
        get_preset("dso", pot=0)


def test_overrides_change_the_selection():
    image = textured((96, 128))
    base = select_pixels(image, "dso", density=300)
    assert len(select_pixels(image, "dso", density=1000)) > len(base)
    assert not np.array_equal(select_pixels(image, "dso", density=300, direction=False), base)
    assert len(select_pixels(image, "dso", density=300, th_factor=4.0)) <= len(base) + 40
    assert len(select_pixels(image, "dso", density=10**6, recursions=0, pot=1)) > len(base)


def test_rescale_is_p2net_integer_arithmetic_and_keeps_duplicates():
    points = np.array([[639, 479, 0], [1, 0, 1], [0, 1, 0], [2, 0, 2], [637, 478, 0]])
    out = rescale_points(points, (480, 640), (288, 384))
    # y*288//480, x*384//640; raster order at 288x384, stable among equal pixels
    expected = np.array([[0, 0, 1], [1, 0, 2], [0, 0, 0], [383, 287, 0], [382, 286, 0]])
    expected = expected[np.argsort(expected[:, 1] * 384 + expected[:, 0], kind="stable")]
    np.testing.assert_array_equal(out, expected)
    assert len(out) == len(points)  # the two points that land on (0, 0) are both kept


def test_p2net_preset_at_training_size():
    image = textured((96, 128), seed=3)
    points = select_pixels(image, "p2net")
    assert len(points) > 0
    assert points[:, 0].max() < 128 and points[:, 1].max() < 96
    key = points[:, 1] * 128 + points[:, 0]
    assert np.all(np.diff(key) >= 0)  # raster order, duplicates adjacent
    # equals selecting on the bilinear 640x480 upscale and rescaling
    work = cv2.resize(image, (640, 480), interpolation=cv2.INTER_LINEAR)
    at_work = select_pixels(work, "p2net")
    np.testing.assert_array_equal(points, rescale_points(at_work, (480, 640), (96, 128)))
    assert len(points) == len(at_work) <= 2500


def test_selector_reports_last_result():
    selector = KeypointSelector("p2net")
    points = selector(textured((480, 640), seed=4))
    assert selector.last is not None and selector.last.pots[0] == 3
    assert len(points) == len(selector.last.points)
