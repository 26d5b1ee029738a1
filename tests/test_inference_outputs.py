"""Tests for f2depth.inference.outputs: units of the depth files, colour map, intrinsics, PLY geometry."""

from __future__ import annotations

import cv2
import fakes
import inference_data
import numpy as np
import pytest

from f2depth.camera import default_intrinsics, intrinsics
from f2depth.inference.outputs import (
    MM_MAX,
    SUFFIXES,
    colorize_depth,
    depth_to_mm,
    mm_clipped,
    write_frame,
)


def _depth(hw=(30, 40), seed=0):
    rng = np.random.default_rng(seed)
    return rng.uniform(0.3, 9.0, hw).astype(np.float32)


def test_mm_png_and_npy_agree(tmp_path):
    depth, rgb = _depth(), fakes.smooth_image((30, 40), 0)
    paths = write_frame(tmp_path, "f", depth, rgb)
    assert [p.name for p in paths] == ["f_depth_mm.png", "f_depth.npy", "f_depth_color.png"]
    mm = cv2.imread(str(paths[0]), cv2.IMREAD_UNCHANGED)
    metres = np.load(paths[1])
    assert mm.dtype == np.uint16 and metres.dtype == np.float32 and mm.shape == metres.shape == (30, 40)
    np.testing.assert_array_equal(metres, depth)
    assert np.abs(mm / 1000.0 - metres).max() <= 0.0005 + 1e-7  # rounded to the millimetre
    colour = cv2.imread(str(paths[2]))
    assert colour.shape == (30, 40, 3)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(p.name for p in paths)  # no temp files


def test_depth_to_mm_never_writes_a_no_depth_code_for_a_depth():
    """Issue 53 item 5. Before: 70 m → 65535 (and 0.4 mm → 0), the codes that 7-Scenes-style readers (ours
    too: f2depth.inference.scaling, f2depth.formats.sevenscenes) take for "no depth". Now a depth is clipped
    to [1, 65534] mm and reads back as a depth; 0, negative and NaN stay 0."""
    depth = np.array([0.0, 0.0004, 0.0006, 1.2345, 65.534, 70.0, np.inf, -1.0, np.nan])
    mm = depth_to_mm(depth)
    np.testing.assert_array_equal(mm, [0, 1, 1, 1234, 65534, 65534, 65534, 0, 0])
    assert MM_MAX == 65534 and mm_clipped(depth) == 3  # 0.0004 m, 70 m and inf


def test_a_far_depth_reads_back_as_a_depth(tmp_path):
    """Issue 53 item 5 through the files: a 70 m pixel in a predicted _depth_mm.png was 65535 and read back
    by --scale-from as missing; now it is 65534 mm."""
    from f2depth.inference.scaling import read_reference_depth

    depth = np.full((4, 5), 2.0, np.float32)
    depth[0, 0] = 70.0
    (mm_path, *_rest) = write_frame(tmp_path, "f", depth, np.zeros((4, 5, 3), np.uint8))
    mm = cv2.imread(str(mm_path), cv2.IMREAD_UNCHANGED)
    assert mm[0, 0] == 65534 and (mm[1:] == 2000).all()
    back = read_reference_depth(mm_path)
    assert back[0, 0] == pytest.approx(65.534) and (back > 0).all()  # nothing reads as "no depth"


def test_colour_map_near_is_bright_and_invalid_black():
    depth = np.array([[1.0, 2.0, 4.0, 8.0, 0.0]], np.float32)
    colour = colorize_depth(depth)
    grey = cv2.cvtColor(colour, cv2.COLOR_BGR2GRAY)[0].astype(int)
    assert grey[0] > grey[1] > grey[2] > grey[3] and grey[3] < 10
    assert (colour[0, 4] == 0).all()


def test_intrinsics_defaults_and_partial():
    K = default_intrinsics(480, 640)
    assert K[0, 0] == K[1, 1] == pytest.approx(518.8579, abs=1e-3)  # NYU's horizontal field of view
    assert (K[0, 2], K[1, 2]) == (319.5, 239.5)
    np.testing.assert_allclose(intrinsics(100, 200, fx=150.0), [[150, 0, 99.5], [0, 150, 49.5], [0, 0, 1]])
    np.testing.assert_allclose(intrinsics(100, 200, fx=150.0, fy=160.0, cx=90.0, cy=40.0),
                               [[150, 0, 90], [0, 160, 40], [0, 0, 1]])
    assert intrinsics(100, 200, cx=10.0)[0, 2] == 10.0
    with pytest.raises(ValueError, match="positive"):
        intrinsics(10, 10, fx=-1.0)


def test_ply_points_back_project_to_the_input_pixels(tmp_path):
    h, w = 30, 40
    depth, rgb = _depth((h, w), 1), fakes.smooth_image((h, w), 1)
    depth[3, 5] = 0.0  # no depth → no point
    K = np.array([[50.0, 0.0, 18.3], [0.0, 55.0, 16.1], [0.0, 0.0, 1.0]])
    paths = write_frame(tmp_path, "f", depth, rgb, K)
    assert paths[-1].name == "f" + SUFFIXES["ply"]
    points, colours = inference_data.read_ply_points(paths[-1])
    assert points.shape == (h * w - 1, 3) and colours.shape == (h * w - 1, 3)
    uv = (K @ points.T.astype(np.float64)).T
    uv = uv[:, :2] / uv[:, 2:]
    v, u = np.nonzero(depth > 0)  # row-major order of the valid pixels
    np.testing.assert_allclose(uv[:, 0], u, atol=1e-3)
    np.testing.assert_allclose(uv[:, 1], v, atol=1e-3)
    np.testing.assert_allclose(points[:, 2], depth[v, u], rtol=1e-6)
    np.testing.assert_array_equal(colours, rgb[v, u])
    header = paths[-1].read_bytes()[:300].decode("ascii", errors="replace")
    assert "format binary_little_endian 1.0" in header and f"element vertex {h * w - 1}" in header
