"""Tests for f2depth.formats.samples (the typed sample, subsets) and f2depth.protocols.inputs (input resizing,
batching)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from PIL import Image

from f2depth.formats import samples as S
from f2depth.formats.samples import EvalSample
from f2depth.protocols import inputs as I


def test_sample_name_and_checks():
    rgb = np.zeros((4, 6, 3), np.uint8)
    s = EvalSample(rgb, "chess", ("chess", "seq-03", 5), depth=np.ones((4, 6), np.float32))
    assert s.name == "chess/seq-03/5"
    with pytest.raises(ValueError, match="sample 1: rgb must be uint8"):
        EvalSample(rgb.astype(np.float32), "a", (1,), depth=np.ones((4, 6), np.float32))
    with pytest.raises(ValueError, match=r"sample 1: rgb must be \(H,W,3\)"):
        EvalSample(rgb[..., 0], "a", (1,), depth=np.ones((4, 6), np.float32))
    with pytest.raises(ValueError, match="exactly one of depth"):
        EvalSample(rgb, "a", (1,), depth=np.ones((4, 6), np.float32), points=np.ones((1, 3)))
    # points on the border of the image are inside (pixel centres at integer coordinates)
    EvalSample(rgb, "a", (1,), points=np.array([[-0.5, -0.5, 1.0], [5.5, 3.5, 2.0]]))
    with pytest.raises(ValueError, match="1 point"):
        EvalSample(rgb, "a", (1,), points=np.array([[5.6, 3.0, 1.0]]))


class Scenes:
    """A SampleSet of named scenes whose samples are never read."""

    def __init__(self, scenes):
        self.scenes = scenes

    def __len__(self):
        return len(self.scenes)

    def __getitem__(self, i):
        return self.scenes[i]

    def scene(self, i):
        return self.scenes[i]


def test_spread_limit_and_middle_frames():
    assert S.spread(10, None) == list(range(10))
    assert S.spread(10, 3) in ([0, 4, 9], [0, 5, 9])
    assert S.spread(3, 5) == [0, 1, 2]
    with pytest.raises(ValueError):
        S.spread(10, 0)
    data = Scenes([f"s{k}" for k in range(100, 110)])
    sub = S.limit(data, 2)
    assert len(sub) == 2 and list(sub) == ["s100", "s109"] and sub[1] == "s109" and sub.scene(1) == "s109"
    assert S.limit(data, None) is data
    frames = Scenes(["chess"] * 3 + ["fire"] * 4 + ["chess"])
    assert S.middle_frames(frames) == [2, 5]  # chess: 0, 1, 2, 7 → 2; fire: 3..6 → 5
    assert S.middle_frames(S.limit(frames, 4)) == [1, 2]  # positions 0, 2, 5, 7 of frames


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


def test_batched_and_run_batch():
    assert [len(b) for b in I.batched(range(7), 3)] == [3, 3, 1]
    with pytest.raises(ValueError):
        list(I.batched(range(3), 0))
    out = I.run_batch(lambda x: 1.0 + x[:, :1], [torch.zeros(3, 2, 4), torch.ones(3, 2, 4)], out_hw=(4, 8))
    assert out.shape == (2, 4, 8) and out.dtype == np.float32
    assert out[0].max() == 1.0 and out[1].min() == 2.0
