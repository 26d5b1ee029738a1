"""Tests of the Campus protocol (f2depth.protocols.campus): point sampling at the right pixels, per scene."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from f2depth.formats.samples import EvalSample
from f2depth.protocols.campus import PROTOCOL
from f2depth.protocols.scoring import network_size, sample_at_points

A, B, CV = 0.5, 0.03, 0.011  # disp(u, v) = A + B·u + CV·v, a known function of the pixel position


def linear_disp(h: int, w: int, H: int, W: int) -> torch.Tensor:
    """(1,1,h,w) map whose value at network pixel (x, y) is the linear function at the image pixel it
    covers: u = (x + 0.5)·W/w − 0.5, v = (y + 0.5)·H/h − 0.5."""
    u = (torch.arange(w, dtype=torch.float64) + 0.5) * W / w - 0.5
    v = (torch.arange(h, dtype=torch.float64) + 0.5) * H / h - 0.5
    return (A + B * u[None, :] + CV * v[:, None])[None, None]


def test_sample_at_points_reads_the_linear_function():
    H, W, h, w = 30, 40, 6, 8  # factor 5 both ways
    disp = linear_disp(h, w, H, W)[0, 0]
    rng = np.random.default_rng(0)
    # interior (no border clamping): u in [2, 37], v in [2, 27]; integer and fractional positions
    uv = np.column_stack([rng.uniform(2, 37, 50), rng.uniform(2, 27, 50)])
    uv[:10] = np.round(uv[:10])
    got = sample_at_points(disp, uv, (H, W))
    np.testing.assert_allclose(got, A + B * uv[:, 0] + CV * uv[:, 1], rtol=1e-12)
    # u is the column: swapping the roles gives different values
    assert not np.allclose(sample_at_points(disp, uv[:, ::-1], (H, W)), got)


def test_sample_at_points_equals_bilinear_upsampling_at_integer_pixels():
    rng = np.random.default_rng(1)
    small = torch.from_numpy(rng.uniform(0.1, 1.0, (1, 1, 7, 9)))
    H, W = 23, 31
    big = F.interpolate(small, size=(H, W), mode="bilinear", align_corners=False)[0, 0].numpy()
    vv, uu = np.mgrid[0:H, 0:W]
    uv = np.column_stack([uu.ravel(), vv.ravel()]).astype(np.float64)  # includes the borders
    np.testing.assert_allclose(sample_at_points(small[0, 0].numpy(), uv, (H, W)), big.ravel(), rtol=1e-12)


def test_network_size_keeps_orientation():
    assert network_size((480, 360), 288, 384, keep_orientation=True) == (384, 288)
    assert network_size((480, 360), 288, 384, keep_orientation=False) == (288, 384)
    assert network_size((4160, 6240), 288, 384, keep_orientation=True) == (288, 384)


def campus_sample(scene: str, image: str, rgb: np.ndarray, points: np.ndarray) -> EvalSample:
    return EvalSample(rgb, scene, (scene, image), points=points)


def _linear_sample(scene: str, image: str, H: int, W: int, scale: float, seed: int) -> EvalSample:
    rng = np.random.default_rng(seed)
    rgb = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
    side = min(H, W) - 3  # inside the image even when u and v are swapped
    u = rng.integers(3, side, 15).astype(np.float64)
    v = rng.integers(3, side, 15).astype(np.float64)
    gt = scale / (A + B * u + CV * v)
    return campus_sample(scene, image, rgb, np.column_stack([u, v, gt]))


def linear_predictor(image_hw):
    def predict(x: torch.Tensor) -> torch.Tensor:
        h, w = x.shape[-2:]
        return linear_disp(h, w, *image_hw).to(x.dtype).expand(x.shape[0], 1, h, w)

    return predict


def test_protocol_samples_points_at_their_pixels_in_a_portrait_image():
    H, W = 40, 30  # portrait; the network runs at 8×6 (orientation kept), factor 5
    samples = [_linear_sample("1", f"img{i}", H, W, scale, i) for i, scale in enumerate([1.0, 3.0])]
    res = PROTOCOL.evaluate(samples, linear_predictor((H, W)), height=6, width=8)
    assert res.summary.mean["abs_rel"] == pytest.approx(0.0, abs=1e-6)  # float32 network output
    assert res.summary.mean["a1"] == 1.0
    np.testing.assert_allclose(res.per_image["ratio"], [1.0, 3.0], rtol=1e-6)
    # the same points read as (row, column) would not match
    swapped = [replace(s, points=s.points[:, [1, 0, 2]]) for s in samples]
    bad = PROTOCOL.evaluate(swapped, linear_predictor((H, W)), height=6, width=8)
    assert bad.summary.mean["abs_rel"] > 0.01


def _pixelwise_sample(scene: str, image: str, seed: int, scale: float = 1.0) -> EvalSample:
    rng = np.random.default_rng(seed)
    rgb = rng.integers(0, 256, (24, 32, 3), dtype=np.uint8)
    u = rng.integers(0, 32, 14)
    v = rng.integers(0, 24, 14)
    gt = scale / (0.2 + rgb[v, u, 0] / 255.0)
    return campus_sample(scene, image, rgb, np.column_stack([u, v, gt]).astype(np.float64))


@pytest.mark.parametrize("post_process", [False, True])
def test_perfect_prediction_per_scene_and_over_scenes(post_process):
    samples = [
        _pixelwise_sample("2", "a", 0),
        _pixelwise_sample("2", "b", 1, 2.0),
        _pixelwise_sample("10", "c", 2, 0.5),
    ]
    res = PROTOCOL.evaluate(
        samples, lambda x: 0.2 + x[:, :1], height=24, width=32, post_process=post_process, keep=[2]
    )
    assert list(res.scenes) == ["2", "10"]  # numeric order
    assert res.scenes["2"].count == 2
    assert res.metrics == res.average  # the headline: the mean of the scene rows
    assert res.average["abs_rel"] == pytest.approx(0.0, abs=1e-6)
    assert res.average["a1"] == 1.0 and res.pooled["a1"] == 1.0
    assert res.per_image["points"].tolist() == [14, 14, 14]
    assert [(k.key, k.pred.shape) for k in res.kept] == [(("10", "c"), (24, 32))]  # network-size map
    assert [r["scene"] for r in PROTOCOL.rows(res)] == ["2", "10", "Average"]


def test_average_is_mean_of_scene_rows_and_pooled_differs():
    samples = [_pixelwise_sample("1", "a", 0), _pixelwise_sample("1", "b", 1), _pixelwise_sample("2", "c", 2)]
    wrong = samples[0].points.copy()
    wrong[:5, 2] *= 2.5
    samples[0] = replace(samples[0], points=wrong)
    res = PROTOCOL.evaluate(samples, lambda x: 0.2 + x[:, :1], height=24, width=32)
    per = res.per_image["abs_rel"]
    assert res.scenes["1"].mean["abs_rel"] == pytest.approx(per[:2].mean())
    assert res.average["abs_rel"] == pytest.approx((per[:2].mean() + per[2]) / 2)
    assert res.summary.mean["abs_rel"] == pytest.approx(per.mean())
    assert res.pooled["abs_rel"] > 0.0
    js = PROTOCOL.details(res)
    assert js["points"] == 42 and js["image_mean"]["count"] == 3
    assert list(js) == ["average", "image_mean", "pooled", "points", "scenes", "skipped", "settings", "rows"]


def test_sample_checks_and_skipped_images():
    s = _pixelwise_sample("3", "x", 0)
    with pytest.raises(ValueError, match=r"sample 3/x: 1 point\(s\) lie outside the 32×24 image"):
        replace(s, points=np.array([[40.0, 3.0, 1.0]]))
    with pytest.raises(ValueError, match=r"points must be \(K,3\)"):
        replace(s, points=np.ones((4, 2)))
    no_points = replace(s, points=np.array([[3.0, 3.0, 0.0]]))
    res = PROTOCOL.evaluate([no_points, s], lambda x: 0.2 + x[:, :1], height=24, width=32)
    assert res.skipped == [("3", "x")] and res.summary.count == 1
    assert PROTOCOL.details(res)["skipped"] == [["3", "x"]]
    assert list(PROTOCOL.image_rows(res, True)[0])[:4] == ["post_process", "scene", "image", "abs_rel"]
