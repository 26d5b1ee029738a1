"""Tests for f2depth.formats.images: decoding with checks for missing, unreadable, truncated, wrong size."""

from __future__ import annotations

import cv2
import fakes
import numpy as np
import pytest

from f2depth.errors import DataError
from f2depth.formats.images import read_image, read_png16
from f2depth.io import write_rgb


@pytest.mark.parametrize("ext", ["ppm", "png", "jpg"])
def test_reads_rgb_in_rgb_order(tmp_path, ext):
    img = np.zeros((20, 30, 3), np.uint8)
    img[..., 0] = 200  # red
    path = tmp_path / f"a.{ext}"
    if ext == "ppm":
        fakes.write_ppm(path, img)
    else:
        fakes.write_rgb(path, img)
    out = read_image(path, expect_hw=(20, 30))
    assert out.shape == (20, 30, 3) and out.dtype == np.uint8
    assert abs(int(out[..., 0].mean()) - 200) <= 2 and out[..., 2].max() <= 3


def test_write_rgb_round_trip(tmp_path):
    img = fakes.smooth_image((16, 24), seed=1)
    write_rgb(tmp_path / "x.png", img)
    np.testing.assert_array_equal(read_image(tmp_path / "x.png"), img)
    assert [p.name for p in tmp_path.iterdir()] == ["x.png"]


def test_missing_file(tmp_path):
    with pytest.raises(DataError, match=r"nope\.png: image not found"):
        read_image(tmp_path / "nope.png")


def test_folder_instead_of_file(tmp_path):
    with pytest.raises(DataError, match="found a folder"):
        read_image(tmp_path)


@pytest.mark.parametrize("ext", ["ppm", "png", "jpg"])
def test_truncated(tmp_path, ext):
    path = tmp_path / f"t.{ext}"
    img = fakes.smooth_image((48, 64), seed=2)
    if ext == "ppm":
        fakes.write_ppm(path, img)
    else:
        fakes.write_rgb(path, img)
    fakes.truncate(path, 0.7)
    with pytest.raises(DataError, match=rf"t\.{ext}: .*truncated"):
        read_image(path)


def test_ppm_with_comment_and_16_bit_pgm_sizes(tmp_path):
    p = tmp_path / "c.ppm"
    p.write_bytes(b"P6\n# a comment\n2 1\n255\n" + bytes(6))
    assert read_image(p).shape == (1, 2, 3)
    p.write_bytes(b"P6\n# a comment\n2 1\n255\n" + bytes(5))
    with pytest.raises(DataError, match="truncated"):
        read_image(p)
    g = tmp_path / "d.pgm"
    g.write_bytes(b"P5\n2 2\n65535\n" + bytes(7))  # needs 8 bytes
    with pytest.raises(DataError, match="truncated"):
        read_image(g)


def test_unreadable(tmp_path):
    p = tmp_path / "garbage.png"
    p.write_bytes(b"this is not an image at all")
    with pytest.raises(DataError, match="garbage.png: unreadable"):
        read_image(p)
    e = tmp_path / "empty.jpg"
    e.write_bytes(b"")
    with pytest.raises(DataError, match="empty.jpg: empty file"):
        read_image(e)


def test_wrong_size(tmp_path):
    p = tmp_path / "small.png"
    fakes.write_rgb(p, np.zeros((10, 12, 3), np.uint8))
    with pytest.raises(DataError, match=r"small.png: image is 10×12 \(H×W\), expected 480×640"):
        read_image(p, expect_hw=(480, 640))


def test_png16(tmp_path):
    d = (np.arange(12, dtype=np.uint16) * 5000).reshape(3, 4)
    p = tmp_path / "d.png"
    cv2.imwrite(str(p), d)
    np.testing.assert_array_equal(read_png16(p, (3, 4)), d)
    q = tmp_path / "rgb.png"
    fakes.write_rgb(q, np.zeros((3, 4, 3), np.uint8))
    with pytest.raises(DataError, match="single-channel 16-bit"):
        read_png16(q)
