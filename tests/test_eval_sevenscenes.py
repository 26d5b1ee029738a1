"""Tests for f2depth.eval.sevenscenes on fake frames with a known perfect prediction.

Frames are 480×640 made of 10×10 blocks, the network size is 48×64 (INTER_AREA and nearest upsampling
are exact), and the predictor maps red to disparity pixel by pixel.
"""

from __future__ import annotations

from collections import namedtuple

import numpy as np
import pytest
import torch

from f2depth.eval import sevenscenes as S

Frame = namedtuple("Frame", "rgb depth scene seq frame")


def predictor(x: torch.Tensor) -> torch.Tensor:
    return 0.2 + x[:, :1]


def make_frame(scene: str, frame: int, scale: float = 1.0) -> Frame:
    rng = np.random.default_rng([*map(ord, scene), frame])
    blocks = rng.integers(0, 256, (48, 64, 3), dtype=np.uint8)
    rgb = np.repeat(np.repeat(blocks, 10, 0), 10, 1)
    depth = (scale / (0.2 + rgb[..., 0] / 255.0)).astype(np.float32)  # 0.83 .. 5 m
    return Frame(rgb, depth, scene, 1, frame)


def run(frames, **kw):
    return S.evaluate_sevenscenes(frames, predictor, height=48, width=64, interpolation="area", **kw)


@pytest.mark.parametrize("post_process", [False, True])
def test_perfect_prediction(post_process):
    frames = [make_frame("chess", i, 1.0 + i) for i in range(2)] + [make_frame("fire", 0, 0.7)]
    res = run(frames, post_process=post_process, batch_size=2, keep=[("fire", 1, 0)])
    assert res.frame_weighted.count == 3
    assert res.frame_weighted.mean["abs_rel"] == pytest.approx(0.0, abs=1e-6)
    assert res.frame_weighted.mean["a1"] == 1.0
    assert res.average["a1"] == 1.0
    assert list(res.scenes) == ["chess", "fire"]
    assert res.predictions[("fire", 1, 0)].shape == (480, 640)


def test_invalid_depths_are_excluded():
    f = make_frame("heads", 0)
    depth = f.depth.copy()
    depth[:40] = 0.0  # holes
    depth[40:80] = 65535 / 1000.0  # the 65535 mm code read as metres
    depth[80:120] = 12.0  # beyond 10 m
    depth[120:130] = np.nan
    res = run([f._replace(depth=depth)])
    assert res.frame_weighted.mean["abs_rel"] == pytest.approx(0.0, abs=1e-6)
    assert res.frame_weighted.mean["a1"] == 1.0
    # the 10 m bound is inclusive by default and the range is a parameter
    kept = run([f._replace(depth=depth)], max_gt_depth=70.0)
    assert kept.frame_weighted.mean["abs_rel"] > 0.1


def test_raw_millimetre_png_values():
    f = make_frame("office", 0)
    mm = np.round(f.depth * 1000).astype(np.uint16)
    mm[:50] = 65535
    mm[50:60] = 0
    m = S.depth_metres(mm)
    assert m.dtype == np.float32
    assert np.all(m[:60] == 0.0)
    np.testing.assert_allclose(m[60:], f.depth[60:], atol=6e-4)
    res = run([f._replace(depth=mm)])
    assert res.frame_weighted.mean["a1"] == 1.0
    assert res.frame_weighted.mean["abs_rel"] < 1e-3  # only the mm rounding


def test_valid_mask_bounds():
    gt = np.array([0.0, 0.05, 5.0, 10.0, 10.01, 65.535])
    assert S.valid_mask(gt).tolist() == [False, True, True, True, False, False]
    assert S.valid_mask(gt, min_gt_depth=0.1).tolist() == [False, False, True, True, False, False]


def test_scene_rows_average_and_frame_weighted():
    frames = []
    for i in range(3):  # chess: 3 frames, each wrong on a different share of the image
        f = make_frame("chess", i)
        d = f.depth.copy()
        d[: 100 * (i + 1)] *= 2.0
        frames.append(f._replace(depth=d))
    f = make_frame("stairs", 0)
    frames.append(f)  # stairs: 1 perfect frame
    res = run(frames)
    chess = res.per_image["abs_rel"][:3]
    assert res.scenes["chess"].count == 3 and res.scenes["stairs"].count == 1
    assert res.scenes["chess"].mean["abs_rel"] == pytest.approx(chess.mean())
    assert res.scenes["stairs"].mean["abs_rel"] == pytest.approx(0.0, abs=1e-6)
    # average = mean of scene rows; frame-weighted = mean of all frames
    assert res.average["abs_rel"] == pytest.approx(chess.mean() / 2, rel=1e-5)
    assert res.frame_weighted.mean["abs_rel"] == pytest.approx(chess.sum() / 4, rel=1e-5)
    rows = res.rows()
    assert [r["scene"] for r in rows] == ["chess", "stairs", S.AVERAGE_ROW, S.ALL_FRAMES_ROW]
    assert rows[0]["frames"] == 3 and rows[-1]["frames"] == 4
    js = res.to_json()
    assert js["scenes"]["chess"]["count"] == 3 and "average" in js


def test_frame_without_valid_pixel_is_skipped():
    f = make_frame("pumpkin", 0)
    res = run([f._replace(depth=np.zeros_like(f.depth), frame=9), f])
    assert res.skipped == [("pumpkin", 1, 9)]
    assert res.frame_weighted.count == 1


def test_official_frame_counts():
    assert sum(S.TEST_FRAMES.values()) == 17000
