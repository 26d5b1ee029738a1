"""ARFlow's ternary census distance (f2depth.flow.census) and the warp (f2depth.geometry.warp)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from f2depth.flow.census import census_distance
from f2depth.geometry import warp

REF = Path(__file__).resolve().parent / "data" / "arflow" / "pwclite_seed0_io.npz"


@pytest.fixture(scope="module")
def ref():
    assert REF.is_file(), f"reference bundle missing: {REF}"
    return dict(np.load(REF))


def _textured(seed: int, hw=(48, 64)) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    coarse = torch.rand(1, 3, hw[0] // 4, hw[1] // 4, generator=g)
    img = torch.nn.functional.interpolate(coarse, size=hw, mode="bilinear", align_corners=False)
    return (0.2 + 0.6 * img + 0.05 * torch.rand(1, 3, *hw, generator=g)).clamp(0, 1)


def test_reproduces_the_official_warped_image_and_census_map(ref):
    x = torch.from_numpy(ref["input"])
    warped = warp(x[:, 3:], torch.from_numpy(ref["flows_fw_0"]))
    assert np.abs(warped.numpy() - ref["im2_warped_by_flows_fw_0"]).max() <= 1e-5
    census = census_distance(x[:, :3], warped)
    assert census.shape == (1, 1, 128, 192)
    assert np.abs(census.numpy() - ref["census_warped_by_flows_fw_0"]).max() <= 1e-5


def test_census_invariant_to_a_global_brightness_scale():
    a, b = _textured(0), _textured(1)  # values in [0.2, 0.85]: no clipping below for gains <= 1.15
    far = float(census_distance(a, b).mean())
    assert far > 0.4  # a different image is far
    for gain in (0.5, 0.8, 1.15):
        # a scaled copy has (almost) the same census pattern although its L1 distance is large
        assert float(census_distance(a, a * gain).mean()) < 0.15 * far
        assert float((a - a * gain).abs().mean()) > 0.05
        # and the distance between two images does not depend on their common gain
        scaled = census_distance(a * gain, b * gain)
        assert float((scaled - census_distance(a, b)).abs().mean()) < 0.05


def test_census_zero_on_identical_images_and_border():
    a, b = _textured(2), _textured(3)
    assert float(census_distance(a, a).abs().max()) == 0.0
    d = census_distance(a, b)
    assert float(d[..., 0, :].abs().max()) == 0 and float(d[..., :, -1].abs().max()) == 0
    assert torch.allclose(d, census_distance(b, a))


def test_warp_integer_shift_and_border_padding():
    img = torch.arange(20.0).view(1, 1, 4, 5)
    flow = torch.zeros(1, 2, 4, 5)
    flow[:, 0] = 1.0  # sample one pixel to the right
    out = warp(img, flow)
    assert torch.equal(out[..., :4], img[..., 1:])
    assert torch.equal(out[..., 4], img[..., 4])  # border padding repeats the last column
    half = warp(img, flow * 0.5)
    assert torch.allclose(half[..., :4], (img[..., :4] + img[..., 1:]) / 2)
    zeros = warp(img, flow, padding="zeros")
    assert float(zeros[..., 4].abs().max()) == 0.0
