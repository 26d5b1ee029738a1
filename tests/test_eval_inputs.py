"""Tests for f2depth.eval.inputs: sample fields, input resizing and batching."""

from __future__ import annotations

from collections import namedtuple

import numpy as np
import pytest
import torch
from PIL import Image

from f2depth.eval import inputs as I


def test_field_by_attribute_key_and_position():
    NT = namedtuple("NT", "scene rgb")
    nt = NT("kitchen", 1)
    assert I.field(nt, "scene", 5) == "kitchen"
    # namedtuples and tuples have an index() method: it must not pass for an "index" field
    with pytest.raises(TypeError, match="no field 'index'"):
        I.field(nt, "index")
    assert I.field((7, "rgb"), "index", 0) == 7
    assert I.field({"name": "a.jpg"}, "image", aliases=("name",)) == "a.jpg"
    with pytest.raises(TypeError, match="no field 'points'"):
        I.field(object(), "points", 3)


def test_resize_filters():
    rng = np.random.default_rng(0)
    blocks = rng.integers(0, 256, (6, 8, 3), dtype=np.uint8)
    big = np.repeat(np.repeat(blocks, 4, 0), 4, 1)
    np.testing.assert_array_equal(I.resize_rgb(big, (6, 8), "area"), blocks)  # exact block means
    lz = I.resize_rgb(big, (10, 13), "lanczos")
    ref = np.asarray(Image.fromarray(big).resize((13, 10), Image.Resampling.LANCZOS))
    np.testing.assert_array_equal(lz, ref)
    assert I.resize_rgb(big, (24, 32)) is big
    with pytest.raises(ValueError, match="interpolation"):
        I.resize_rgb(big, (6, 8), "cubic")


def test_to_input_layout_and_range():
    rgb = np.zeros((4, 6, 3), np.uint8)
    rgb[..., 1] = 255
    x = I.to_input(rgb, (4, 6))
    assert x.shape == (3, 4, 6) and x.dtype == torch.float32
    assert x[1].min() == 1.0 and x[0].max() == 0.0


def test_check_rgb():
    with pytest.raises(ValueError, match="uint8"):
        I.check_rgb(np.zeros((2, 2, 3), np.float32), "sample 1")
    with pytest.raises(ValueError, match=r"\(H,W,3\)"):
        I.check_rgb(np.zeros((2, 2), np.uint8), "sample 1")


def test_batched_and_run_batch():
    assert [len(b) for b in I.batched(range(7), 3)] == [3, 3, 1]
    with pytest.raises(ValueError):
        list(I.batched(range(3), 0))
    out = I.run_batch(lambda x: 1.0 + x[:, :1], [torch.zeros(3, 2, 4), torch.ones(3, 2, 4)], out_hw=(4, 8))
    assert out.shape == (2, 4, 8) and out.dtype == np.float32
    assert out[0].max() == 1.0 and out[1].min() == 2.0
