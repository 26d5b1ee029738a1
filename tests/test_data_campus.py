"""Tests for f2depth.formats.campus: points.csv parsing and every bad row the issue names."""

from __future__ import annotations

import fakes
import numpy as np
import pytest

from f2depth.errors import DataError
from f2depth.formats.campus import CampusSet


@pytest.fixture
def campus(tmp_path):
    rows = fakes.write_campus(tmp_path, {"hall": 2, "lab": 1}, points_per_image=4)
    return tmp_path, rows


def test_reads_images_and_points(campus):
    root, rows = campus
    ds = CampusSet(root)
    assert len(ds) == 3 and ds.scenes == ["hall", "lab"]
    s = ds[0]
    assert s.key == ("hall", "img_000.jpg") and s.scene == ds.scene(0) == "hall" and s.depth is None
    assert s.rgb.shape == (*fakes.CAMPUS_HW, 3)
    expect = np.array([r[2:] for r in rows if r[:2] == ["hall", "img_000"]], dtype=np.float64)
    np.testing.assert_allclose(s.points, expect)


def test_image_column_with_extension(campus):
    root, rows = campus
    fakes.write_points_csv(root / "points.csv", [[r[0], r[1] + ".jpg", *r[2:]] for r in rows])
    assert len(CampusSet(root)) == 3


def _break(root, rows, k, col, value):
    rows = [list(r) for r in rows]
    rows[k][col] = value
    fakes.write_points_csv(root / "points.csv", rows)


def test_point_outside_image(campus):
    root, rows = campus
    _break(root, rows, 5, 2, fakes.CAMPUS_HW[1])  # u = W
    msg = r"points.csv: row 7: point \(u=48, v=\d+\) lies outside its 48×64 image"
    with pytest.raises(DataError, match=msg):
        CampusSet(root)
    _break(root, rows, 0, 3, -1)
    with pytest.raises(DataError, match="points.csv: row 2: point .* lies outside"):
        CampusSet(root)


@pytest.mark.parametrize("depth", [0, -1.5, "nan"])
def test_depth_not_positive(campus, depth):
    root, rows = campus
    _break(root, rows, 3, 4, depth)
    with pytest.raises(DataError, match="points.csv: row 5: (depth_m = .* is not positive|non-finite)"):
        CampusSet(root)


def test_missing_image_and_header(campus):
    root, rows = campus
    _break(root, rows, 9, 1, "img_999")
    with pytest.raises(DataError, match=r"points.csv: row 11: image .*img_999.jpg does not exist"):
        CampusSet(root)
    fakes.write_points_csv(root / "points.csv", rows, header="scene,image,x,y,depth")
    with pytest.raises(DataError, match="points.csv: header is"):
        CampusSet(root)
    (root / "points.csv").unlink()
    with pytest.raises(DataError, match="points.csv: points file not found"):
        CampusSet(root)


def test_unlabelled_and_truncated_image(campus):
    root, rows = campus
    fakes.write_rgb(root / "lab" / "extra.jpg", np.zeros((8, 8, 3), np.uint8))
    with pytest.raises(DataError, match="points.csv: image lab/extra.jpg has no points"):
        CampusSet(root)
    (root / "lab" / "extra.jpg").unlink()
    fakes.truncate(root / "hall" / "img_001.jpg", 0.5)
    with pytest.raises(DataError, match=r"img_001\.jpg: truncated JPEG"):
        CampusSet(root)


def test_bad_number(campus):
    root, rows = campus
    _break(root, rows, 1, 2, "abc")
    with pytest.raises(DataError, match="row 3: u, v, depth_m must be numbers"):
        CampusSet(root)
