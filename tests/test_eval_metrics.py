"""Tests for f2depth.protocols.metrics: hand-computed metrics, median scaling, aggregation, flip PP."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from f2depth.depth import predict as P
from f2depth.protocols import metrics as M


def test_metrics_hand_computed_2x2():
    # gt 0 is invalid; the prediction there (7.0) must not count.
    gt = np.array([[1.0, 2.0], [4.0, 0.0]])
    pred = np.array([[1.2, 2.0], [2.1, 7.0]])
    m, ratio = M.image_metrics(gt, pred, median_scaling=False, min_depth=0.1, max_depth=10.0)
    assert ratio == 1.0
    # valid pairs (gt, pred): (1, 1.2), (2, 2), (4, 2.1)
    assert m["abs_rel"] == pytest.approx((0.2 / 1 + 0.0 + 1.9 / 4) / 3)  # 0.225
    assert m["sq_rel"] == pytest.approx((0.04 / 1 + 0.0 + 3.61 / 4) / 3)
    assert m["rmse"] == pytest.approx(math.sqrt((0.04 + 0.0 + 3.61) / 3))
    assert m["rmse_log"] == pytest.approx(math.sqrt((math.log(1.2) ** 2 + math.log(4 / 2.1) ** 2) / 3))
    assert m["log10"] == pytest.approx((math.log10(1.2) + math.log10(4 / 2.1)) / 3)
    # max ratios: 1.2, 1.0, 1.905 → < 1.25: 2 of 3; < 1.5625: 2 of 3; < 1.953125: 3 of 3
    assert m["a1"] == pytest.approx(2 / 3)
    assert m["a2"] == pytest.approx(2 / 3)
    assert m["a3"] == pytest.approx(1.0)
    assert list(m) == list(M.METRIC_NAMES)


def test_median_scale_ratio_and_values():
    scaled, ratio = M.median_scale(np.array([3.0, 4.0, 10.0]), np.array([1.0, 2.0, 4.0]))
    assert ratio == pytest.approx(0.5)
    np.testing.assert_allclose(scaled, [1.5, 2.0, 5.0])


def test_mask_then_scale_then_clip():
    # The invalid pixel (gt 0, pred 1000) must not enter the median; 300 is clipped to 10 after scaling.
    gt = np.array([0.0, 1.0, 2.0, 3.0])
    pred = np.array([1000.0, 1.0, 2.0, 300.0])
    m, ratio = M.image_metrics(gt, pred, min_depth=0.1, max_depth=10.0)
    assert ratio == pytest.approx(1.0)
    assert m["abs_rel"] == pytest.approx((0 + 0 + 7 / 3) / 3)
    # an explicit mask is combined with gt > 0
    m2, _ = M.image_metrics(gt, pred, np.array([True, True, True, False]))
    assert m2["abs_rel"] == pytest.approx(0.0)


def test_clip_lower_bound():
    np.testing.assert_allclose(M.clip_depth(np.array([0.01, 5.0, 11.0]), 0.1, 10.0), [0.1, 5.0, 10.0])


def test_median_scaling_makes_metrics_scale_invariant():
    rng = np.random.default_rng(0)
    gt = rng.uniform(0.5, 6.0, (12, 16))
    gt[0, :4] = 0.0
    pred = gt * rng.uniform(0.7, 1.4, gt.shape)
    base, r1 = M.image_metrics(gt, pred)
    for k in (0.01, 3.7, 250.0):
        scaled, rk = M.image_metrics(gt, pred * k)
        for name in M.METRIC_NAMES:
            assert scaled[name] == pytest.approx(base[name], rel=1e-9, abs=1e-12)
        assert rk == pytest.approx(r1 / k)
    unscaled, _ = M.image_metrics(gt, pred * 3.7, median_scaling=False)
    assert unscaled["abs_rel"] > base["abs_rel"] + 0.1


def test_perfect_prediction():
    gt = np.linspace(0.5, 8.0, 20)
    m, _ = M.image_metrics(gt, gt * 2.5)
    assert m["abs_rel"] == pytest.approx(0.0, abs=1e-12)
    assert m["rmse"] == pytest.approx(0.0, abs=1e-12)
    assert m["a1"] == 1.0 and m["a3"] == 1.0


def test_empty_mask_and_bad_inputs():
    with pytest.raises(M.EmptyMaskError):
        M.image_metrics(np.zeros((2, 2)), np.ones((2, 2)))
    with pytest.raises(ValueError, match="same shape"):
        M.image_metrics(np.ones((2, 2)), np.ones((2, 3)))
    with pytest.raises(ValueError, match="> 0"):
        M.compute_errors(np.array([1.0]), np.array([0.0]))


def test_aggregate_mean_std_and_stable_names():
    per_image = [
        {"abs_rel": 0.1, "sq_rel": 0.0, "rmse": 1.0, "rmse_log": 0.0, "log10": 0.0, "a1": 1.0, "a2": 1.0,
         "a3": 1.0, "ratio": 2.0},
        {"abs_rel": 0.3, "sq_rel": 0.0, "rmse": 3.0, "rmse_log": 0.0, "log10": 0.0, "a1": 0.5, "a2": 1.0,
         "a3": 1.0, "ratio": 4.0},
    ]  # fmt: skip
    s = M.aggregate(per_image)
    assert s.count == 2
    assert list(s.mean) == list(M.METRIC_NAMES)  # "ratio" is not a metric
    assert s.mean["abs_rel"] == pytest.approx(0.2)
    assert s.mean["rmse"] == pytest.approx(2.0)  # mean of per-image RMS, not pooled
    assert s.std["rmse"] == pytest.approx(1.0)  # population std
    assert s.mean["a1"] == pytest.approx(0.75)
    arrays = M.stack_per_image(per_image)
    np.testing.assert_allclose(arrays["ratio"], [2.0, 4.0])
    assert M.aggregate(arrays) == s
    empty = M.aggregate([])
    assert empty.count == 0 and math.isnan(empty.mean["abs_rel"])
    assert M.mean_of_rows([{"abs_rel": 0.1}, {"abs_rel": 0.3}]) == {"abs_rel": pytest.approx(0.2)}


def test_pp_weights_ramp():
    l_mask, r_mask = P.pp_weights(3, 101)  # x = 0.00, 0.01, ..., 1.00
    assert l_mask.shape == (3, 101)
    assert l_mask[0, 0] == 1.0 and l_mask[0, 5] == pytest.approx(1.0)  # left 5 %
    assert l_mask[0, 7] == pytest.approx(0.6)  # 1 - 20·(0.07 - 0.05)
    assert np.all(l_mask[:, 10:] == 0.0)  # zero from 10 % on
    np.testing.assert_array_equal(r_mask, l_mask[:, ::-1])
    assert np.all(l_mask + r_mask <= 1.0)


def test_flip_post_process_blend_by_hand():
    w = 101
    direct = np.ones((1, 2, w))
    flipped_back = np.zeros((1, 2, w))
    out = P.flip_post_process(direct, flipped_back)
    assert out[0, 0, 0] == pytest.approx(0.0)  # left border: the flipped-back prediction
    assert out[0, 0, -1] == pytest.approx(1.0)  # right border: the direct prediction
    assert out[0, 0, 50] == pytest.approx(0.5)  # middle: the mean
    assert out[0, 0, 7] == pytest.approx(0.5 * (1 - 0.6))  # on the ramp: (1 - l - r)/2 with r = 0
    t = P.flip_post_process(torch.ones(1, 2, w), torch.zeros(1, 2, w))
    np.testing.assert_allclose(t.numpy(), out, atol=1e-7)


def test_pp_of_symmetric_prediction_is_identity():
    rng = np.random.default_rng(1)
    half = rng.uniform(0.1, 1.0, (5, 6))
    sym = torch.from_numpy(np.concatenate([half, half[:, ::-1]], 1)).float()[None, None]  # (1,1,5,12)

    def constant(x: torch.Tensor) -> torch.Tensor:
        return sym.expand(x.shape[0], 1, 5, 12)

    img = torch.rand(1, 3, 5, 12)
    pp = P.predict_disparity(constant, img, post_process=True)
    torch.testing.assert_close(pp, sym)
    assert torch.allclose(P.flip_post_process(sym, sym), sym)


def test_pp_of_flip_equivariant_predictor_is_identity_and_doubles_batch():
    seen: list[int] = []

    def pixelwise(x: torch.Tensor) -> torch.Tensor:
        seen.append(x.shape[0])
        return 0.2 + x[:, :1] ** 2

    img = torch.rand(2, 3, 8, 10)
    plain = P.predict_disparity(pixelwise, img)
    pp = P.predict_disparity(pixelwise, img, post_process=True)
    assert seen == [2, 4]
    torch.testing.assert_close(pp, plain)


def test_predict_disparity_upsampling_and_shape_check():
    def pred(x: torch.Tensor) -> torch.Tensor:
        return torch.arange(4.0).reshape(1, 1, 2, 2).expand(x.shape[0], 1, 2, 2) + 1

    img = torch.rand(1, 3, 2, 2)
    near = P.predict_disparity(pred, img, out_hw=(4, 4))
    assert near.shape == (1, 1, 4, 4)
    assert near[0, 0, 0].tolist() == [1.0, 1.0, 2.0, 2.0]
    bil = P.predict_disparity(pred, img, out_hw=(4, 4), upsample="bilinear")
    assert bil[0, 0, 0].tolist() == pytest.approx([1.0, 1.25, 1.75, 2.0])
    with pytest.raises(ValueError, match="upsample"):
        P.predict_disparity(pred, img, out_hw=(4, 4), upsample="cubic")
    with pytest.raises(ValueError, match=r"\(B,1,H,W\)"):
        P.predict_disparity(lambda x: x, img)


def test_depth_from_disparity():
    d = P.depth_from_disparity(torch.tensor([0.5, 0.0]))
    assert d[0] == pytest.approx(2.0)
    assert np.isfinite(d[1]) and d[1] > 1e6
