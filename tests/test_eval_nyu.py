"""Tests of the NYU protocol (f2depth.protocols.nyu) on fake NYU samples whose perfect prediction is known.

The rgb inside the Eigen crop is made of 7×3 blocks, so an INTER_AREA resize of the 427×561 crop to
61×187 is exact and a nearest upsample of the 61×187 prediction gives the blocks back. The predictor
maps the red channel to a disparity pixel by pixel; the ground truth is that disparity's inverse times a
per-image scale, so a correct protocol scores it perfectly, and a misplaced crop does not.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from f2depth.formats.samples import EvalSample
from f2depth.protocols import nyu
from f2depth.protocols.scoring import resolve_crop

NET_HW = (61, 187)  # 427 / 7, 561 / 3


def disp_of(red: np.ndarray) -> np.ndarray:
    return 0.2 + red / 255.0


def predictor(x: torch.Tensor) -> torch.Tensor:
    return 0.2 + x[:, :1]


def make_sample(seed: int, scale: float) -> EvalSample:
    rng = np.random.default_rng(seed)
    rgb = rng.integers(0, 256, (480, 640, 3), dtype=np.uint8)  # garbage outside the crop
    depth = rng.uniform(0.5, 9.0, (480, 640)).astype(np.float32)
    blocks = rng.integers(0, 256, (*NET_HW, 3), dtype=np.uint8)
    crop_rgb = np.repeat(np.repeat(blocks, 7, 0), 3, 1)
    rgb[44:471, 40:601] = crop_rgb
    gt = (scale / disp_of(crop_rgb[..., 0].astype(np.float64))).astype(np.float32)
    gt[:20, :30] = 0.0  # holes
    depth[44:471, 40:601] = gt
    return EvalSample(rgb, f"scene_{seed % 2}", (seed,), depth=depth)


def run(samples, **kw):
    kw = {"height": NET_HW[0], "width": NET_HW[1], "interpolation": "area", **kw}
    return nyu.PROTOCOL.evaluate(samples, predictor, **kw)


def test_eigen_crop_size():
    t, b, l, r = resolve_crop("eigen")
    assert (b - t, r - l) == (427, 561)
    t, b, l, r = resolve_crop("eigen_sc")
    assert (b - t, r - l) == (426, 560)
    assert resolve_crop("none") is None and resolve_crop(None) is None
    with pytest.raises(ValueError, match="unknown NYU crop"):
        resolve_crop("garg")


@pytest.mark.parametrize("post_process", [False, True])
def test_perfect_prediction_scores_perfectly(post_process):
    samples = [make_sample(i, scale) for i, scale in enumerate([0.5, 2.0, 1.2])]  # gt within [0.1, 10] m
    res = run(samples, post_process=post_process, batch_size=2, keep=[1])
    assert res.summary.count == 3
    assert res.metrics["abs_rel"] == pytest.approx(0.0, abs=1e-6)
    assert res.metrics["rmse"] == pytest.approx(0.0, abs=1e-5)
    assert res.metrics["a1"] == 1.0
    np.testing.assert_allclose(res.per_image["ratio"], [0.5, 2.0, 1.2], rtol=1e-5)
    assert res.keys == [(0,), (1,), (2,)]
    assert res.scene == ["scene_0", "scene_1", "scene_0"]
    assert res.per_image["abs_rel"].shape == (3,)
    [kept] = res.kept  # the scored, cropped maps of sample 1
    assert kept.key == (1,) and kept.pred.shape == kept.gt.shape == (427, 561)
    assert kept.rgb.shape == (427, 561, 3)
    np.testing.assert_allclose(kept.pred[30:], kept.gt[30:], rtol=1e-5)  # scaled onto the gt (holes at top)
    js = nyu.PROTOCOL.details(res)
    assert js["count"] == 3 and js["settings"]["crop"] == [44, 471, 40, 601]
    assert js["ratio_median"] == pytest.approx(1.2, rel=1e-5) and js["skipped"] == []
    rows = nyu.PROTOCOL.image_rows(res, post_process)
    assert list(rows[0])[:4] == ["post_process", "index", "scene", "abs_rel"] and rows[2]["index"] == 2


def test_misplaced_crop_is_detected():
    res = run([make_sample(0, 1.0)], crop="eigen_sc")
    assert res.metrics["abs_rel"] > 0.05


def test_samples_are_typed_and_checked():
    s = make_sample(3, 1.5)
    with pytest.raises(ValueError, match=r"sample 3: depth must be float metres of the rgb's size \(480"):
        replace(s, depth=s.depth[:, :600])
    with pytest.raises(ValueError, match="millimetres: convert first"):
        replace(s, depth=(s.depth * 1000).astype(np.uint16))
    with pytest.raises(ValueError, match="exactly one of depth"):
        EvalSample(s.rgb, "x", (1,))
    points = EvalSample(s.rgb, "x", (1,), points=np.array([[3.0, 4.0, 2.0]]))
    with pytest.raises(ValueError, match="NYU sample 1: the NYU protocol scores depth ground truth"):
        run([points])
    with pytest.raises(TypeError, match=r"the NYU protocol has no setting \['keep_orientation'\]"):
        run([s], keep_orientation=True)


def test_max_gt_depth_excludes_far_pixels():
    s = make_sample(4, 1.0)
    depth = s.depth.copy()
    depth[100:200, 100:300] = 20.0  # far beyond the prediction there
    far = replace(s, depth=depth)
    uncapped = run([far])  # P²Net's default: every gt > 0 counts
    assert uncapped.metrics["abs_rel"] > 0.05 and uncapped.metrics["a1"] < 1.0
    capped = run([far], max_gt_depth=10.0)
    assert capped.metrics["abs_rel"] == pytest.approx(0.0, abs=1e-6)
    assert capped.settings["max_gt_depth"] == 10.0


def test_no_crop_and_skipped_images():
    s = make_sample(5, 1.0)
    rgb, depth = np.ascontiguousarray(s.rgb[44:471, 40:601]), s.depth[44:471, 40:601]
    cropped = EvalSample(rgb, "x", (5,), depth=depth)
    res = run([cropped], crop=None)
    assert res.metrics["abs_rel"] == pytest.approx(0.0, abs=1e-6)
    empty = EvalSample(s.rgb, "x", (6,), depth=np.zeros_like(s.depth))
    res = run([empty, s])
    assert res.skipped == [(6,)] and res.summary.count == 1
    assert nyu.PROTOCOL.details(res)["skipped"] == [6]


def test_scale_of_prediction_does_not_matter():
    samples = [make_sample(i, 1.0) for i in range(2)]
    for s in samples:
        s.depth[200:260, 300:400] *= 1.7  # make the metrics non-trivial
    base = nyu.evaluate_nyu(samples, predictor, height=NET_HW[0], width=NET_HW[1], interpolation="area")
    scaled = nyu.evaluate_nyu(
        samples, lambda x: 0.01 * predictor(x), height=NET_HW[0], width=NET_HW[1], interpolation="area"
    )  # evaluate_nyu: the name the training stage's validation uses
    for k, v in base.metrics.items():
        assert scaled.metrics[k] == pytest.approx(v, rel=1e-5, abs=1e-7)
    assert base.metrics["abs_rel"] > 0.0


def test_bilinear_upsampling_and_lanczos_run():
    s = make_sample(7, 1.0)
    res = nyu.evaluate_nyu([s], predictor, height=32, width=48, upsample="bilinear", interpolation="lanczos")
    assert res.summary.count == 1
    assert 0.0 < res.metrics["abs_rel"] < 0.5  # smooth resampling of blocks: close, not exact
