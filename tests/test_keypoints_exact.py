"""Exactness against the DSO reference build (tests/data/dso): every mode, every case,
point for point and level for level; also the pot DSO keeps for the next frame and the level counts."""

from __future__ import annotations

import re
from pathlib import Path

import cv2
import numpy as np
import pytest

from f2depth.keypoints import KeypointSelector, select_pixels
from f2depth.keypoints.select import prepare, select

REFERENCE = Path(__file__).resolve().parent / "data" / "dso"
CASES = ["case1_rects_640x480", "case2_edges_640x480", "case4_texture_640x480"]


def _image(case: str) -> np.ndarray:
    path = REFERENCE / f"{case}.pgm"
    assert path.is_file(), f"{path} missing: the DSO reference outputs live in tests/data/dso"
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert image is not None and image.dtype == np.uint8 and image.shape == (480, 640)
    return image


def _reference(case: str, mode: str) -> tuple[np.ndarray, dict[str, int]]:
    path = REFERENCE / f"{case}.{mode}.txt"
    header = path.read_text().splitlines()[0]
    info = {k: int(v) for k, v in re.findall(r"(\w+)=(-?\d+)\b", header) if k != "input"}
    return np.loadtxt(path, dtype=np.int64).reshape(-1, 3), info


def test_reference_cases_present():
    assert len(list(REFERENCE.glob("case*.pgm"))) == len(CASES), f"unexpected reference set in {REFERENCE}"


@pytest.mark.parametrize("case", CASES)
@pytest.mark.parametrize(("mode", "pot", "direction"),
                         [("raw_pot1", 1, True), ("raw_pot3", 3, True), ("raw_pot3_nodir", 3, False)])
def test_select_raw_equals_reference(case, mode, pot, direction):
    reference, info = _reference(case, mode)
    points = select(prepare(_image(case), direction=direction), pot)[0]
    assert points.shape == reference.shape
    np.testing.assert_array_equal(points, reference)
    counts = np.bincount(points[:, 2], minlength=3)
    assert counts.tolist() == [info["n_level0"], info["n_level1"], info["n_level2"]]


@pytest.mark.parametrize("case", CASES)
@pytest.mark.parametrize(("mode", "preset"), [("dso_default", "dso"), ("p2net", "p2net")])
def test_make_maps_equals_reference(case, mode, preset):
    reference, info = _reference(case, mode)
    selector = KeypointSelector(preset)
    points = selector(_image(case))
    np.testing.assert_array_equal(points, reference)
    assert len(points) == info["returned"]
    assert selector.pot == info["pot_out"]  # the pot a persistent selector would start the next frame with
    assert sum(selector.last.counts) >= len(points)
    # the fresh-selector function gives the same
    np.testing.assert_array_equal(select_pixels(_image(case), preset), reference)
