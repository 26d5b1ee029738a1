"""f2depth.colour: grey, HSV and the jitter operations (torchvision's ColorJitter definitions)."""

from __future__ import annotations

import colorsys

import numpy as np
import pytest
import torch

from f2depth import colour as C


def test_hue_and_hsv_match_colorsys():
    rng = np.random.default_rng(0)
    rgb = rng.uniform(0, 1, (3, 4, 5)).astype(np.float32)
    rgb[:, 0, 0] = 0.5  # grey pixel: hue undefined, must stay grey
    t = torch.from_numpy(rgb)
    hsv = C.rgb_to_hsv(t)
    for y in range(4):
        for x in range(5):
            h, s, v = colorsys.rgb_to_hsv(*rgb[:, y, x])
            assert hsv[:, y, x].tolist() == pytest.approx([h, s, v], abs=1e-5)
    assert torch.allclose(C.hsv_to_rgb(hsv), t, atol=1e-5)
    shifted = C.adjust(t, "hue", 0.07)
    for y in range(4):
        for x in range(5):
            h, s, v = colorsys.rgb_to_hsv(*rgb[:, y, x])
            ref = colorsys.hsv_to_rgb((h + 0.07) % 1.0, s, v)
            assert shifted[:, y, x].tolist() == pytest.approx(list(ref), abs=1e-5)


def test_brightness_contrast_saturation_definitions():
    rng = np.random.default_rng(1)
    img = torch.from_numpy(rng.uniform(0.1, 0.9, (2, 3, 4, 4)).astype(np.float32))
    for op in ("brightness", "contrast", "saturation", "hue"):
        assert torch.allclose(C.adjust(img, op, 1.0 if op != "hue" else 0.0), img)
    gray = 0.299 * img[:, 0] + 0.587 * img[:, 1] + 0.114 * img[:, 2]
    sat0 = C.adjust(img, "saturation", 0.0)
    assert torch.allclose(sat0, gray.unsqueeze(1).expand_as(img), atol=1e-6)
    con0 = C.adjust(img, "contrast", 0.0)  # every pixel becomes the image's own mean luma
    assert torch.allclose(con0[0], gray[0].mean().expand(3, 4, 4), atol=1e-6)
    assert torch.allclose(con0[1], gray[1].mean().expand(3, 4, 4), atol=1e-6)
    assert float(C.adjust(img, "brightness", 1.2).max()) <= 1.0
    matlab = 0.2989 * img[:, 0] + 0.5870 * img[:, 1] + 0.1140 * img[:, 2]
    assert torch.allclose(C.adjust(img, "saturation", 0.0, C.GREY_MATLAB), matlab.unsqueeze(1).expand_as(img),
                          atol=1e-6)
    assert not torch.allclose(matlab, gray, atol=1e-6)  # the two weight sets differ
    with pytest.raises(ValueError, match="unknown colour operation 'gamma'"):
        C.adjust(img, "gamma", 1.0)


def test_hsv_round_trip_and_hue_rotation():
    img = torch.rand(2, 3, 12, 16, generator=torch.Generator().manual_seed(0))
    assert torch.allclose(C.hsv_to_rgb(C.rgb_to_hsv(img)), img, atol=1e-5)
    red = torch.zeros(3, 2, 2)
    red[0] = 1
    green = C.adjust(red, "hue", 1 / 3)
    assert torch.allclose(green[1], torch.ones(2, 2), atol=1e-5) and green[0].abs().max() < 1e-5
    assert torch.allclose(C.adjust(img, "hue", 0.0), img, atol=1e-5)
    grey = C.adjust(img, "saturation", 0.0)
    assert torch.allclose(grey[:, 0], grey[:, 1]) and torch.allclose(grey[:, 1], grey[:, 2])
    assert torch.allclose(C.adjust(img, "brightness", 0.5), img * 0.5)
