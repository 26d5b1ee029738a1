"""Tests of the 7-Scenes protocol (f2depth.protocols.sevenscenes) on fake frames with a known perfect
prediction.

Frames are 480×640 made of 10×10 blocks, the network size is 48×64 (INTER_AREA and nearest upsampling
are exact), and the predictor maps red to disparity pixel by pixel.
"""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest
import torch

from f2depth.formats.samples import EvalSample
from f2depth.formats.sevenscenes import read_depth_mm
from f2depth.protocols import sevenscenes as S
from f2depth.protocols.scoring import Settings

PROTOCOL = S.PROTOCOL


def predictor(x: torch.Tensor) -> torch.Tensor:
    return 0.2 + x[:, :1]


def make_frame(scene: str, frame: int, scale: float = 1.0) -> EvalSample:
    rng = np.random.default_rng([*map(ord, scene), frame])
    blocks = rng.integers(0, 256, (48, 64, 3), dtype=np.uint8)
    rgb = np.repeat(np.repeat(blocks, 10, 0), 10, 1)
    depth = (scale / (0.2 + rgb[..., 0] / 255.0)).astype(np.float32)  # 0.83 .. 5 m
    return EvalSample(rgb, scene, (scene, "seq-01", frame), depth=depth)


def run(frames, **kw):
    return PROTOCOL.evaluate(frames, predictor, height=48, width=64, interpolation="area", **kw)


@pytest.mark.parametrize("post_process", [False, True])
def test_perfect_prediction(post_process):
    frames = [make_frame("chess", i, 1.0 + i) for i in range(2)] + [make_frame("fire", 0, 0.7)]
    res = run(frames, post_process=post_process, batch_size=2, keep=[2])
    assert res.summary.count == 3
    assert res.metrics == res.summary.mean  # the headline: the mean over all frames
    assert res.summary.mean["abs_rel"] == pytest.approx(0.0, abs=1e-6)
    assert res.summary.mean["a1"] == 1.0
    assert res.average["a1"] == 1.0
    assert list(res.scenes) == ["chess", "fire"]
    [kept] = res.kept
    assert kept.key == ("fire", "seq-01", 0) and kept.pred.shape == (480, 640)


def test_invalid_depths_are_excluded(caplog):
    f = make_frame("heads", 0)
    depth = f.depth.copy()
    depth[:40] = 0.0  # holes
    depth[40:80] = 65535 / 1000.0  # the 65535 mm code read as metres
    depth[80:120] = 12.0  # beyond 10 m
    depth[120:130] = np.nan  # counts as missing, with one warning line
    res = run([replace(f, depth=depth)])
    assert res.summary.mean["abs_rel"] == pytest.approx(0.0, abs=1e-6)
    assert res.summary.mean["a1"] == 1.0
    assert "6400 ground-truth pixels in 1 image(s) are NaN or inf and count as missing depth" in caplog.text
    # the 10 m bound is inclusive by default and the range is a parameter
    kept = run([replace(f, depth=depth)], max_gt_depth=70.0)
    assert kept.summary.mean["abs_rel"] > 0.1


def test_raw_millimetre_png_values(tmp_path):
    """The loader reads the raw PNG (uint16 mm, 65535 and 0 invalid) as metres; scored as the metres."""
    f = make_frame("office", 0)
    mm = np.round(f.depth * 1000).astype(np.uint16)
    mm[:50] = 65535
    mm[50:60] = 0
    assert cv2.imwrite(str(tmp_path / "d.png"), mm)
    m = read_depth_mm(tmp_path / "d.png")
    assert m.dtype == np.float32
    assert np.all(m[:60] == 0.0)
    np.testing.assert_allclose(m[60:], f.depth[60:], atol=6e-4)
    res = run([replace(f, depth=m)])
    assert res.summary.mean["a1"] == 1.0
    assert res.summary.mean["abs_rel"] < 1e-3  # only the mm rounding


def test_valid_mask_bounds():
    gt = np.array([0.0, 0.05, 5.0, 10.0, 10.01, 65.535])
    assert PROTOCOL.defaults.valid(gt).tolist() == [False, True, True, True, False, False]
    assert Settings(min_gt_depth=0.1, max_gt_depth=10.0).valid(gt).tolist() == [False, False, True, True,
                                                                                   False, False]


def test_scene_rows_average_and_frame_weighted():
    frames = []
    for i in range(3):  # chess: 3 frames, each wrong on a different share of the image
        f = make_frame("chess", i)
        d = f.depth.copy()
        d[: 100 * (i + 1)] *= 2.0
        frames.append(replace(f, depth=d))
    f = make_frame("stairs", 0)
    frames.append(f)  # stairs: 1 perfect frame
    res = run(frames)
    chess = res.per_image["abs_rel"][:3]
    assert res.scenes["chess"].count == 3 and res.scenes["stairs"].count == 1
    assert res.scenes["chess"].mean["abs_rel"] == pytest.approx(chess.mean())
    assert res.scenes["stairs"].mean["abs_rel"] == pytest.approx(0.0, abs=1e-6)
    # average = mean of scene rows; frame-weighted = mean of all frames
    assert res.average["abs_rel"] == pytest.approx(chess.mean() / 2, rel=1e-5)
    assert res.summary.mean["abs_rel"] == pytest.approx(chess.sum() / 4, rel=1e-5)
    rows = PROTOCOL.rows(res)
    assert [r["scene"] for r in rows] == ["chess", "stairs", "Average", "All frames"]
    assert rows[0]["frames"] == 3 and rows[-1]["frames"] == 4
    js = PROTOCOL.details(res)
    assert list(js) == ["average", "frame_weighted", "scenes", "skipped", "settings", "rows"]
    assert js["scenes"]["chess"]["count"] == 3 and js["frame_weighted"]["count"] == 4
    assert list(js["settings"]) == list(PROTOCOL.records) and js["settings"]["max_gt_depth"] == 10.0
    csv_rows = PROTOCOL.image_rows(res, False)
    assert list(csv_rows[0])[:5] == ["post_process", "scene", "seq", "frame", "abs_rel"]


def test_frame_without_valid_pixel_is_skipped():
    f = make_frame("pumpkin", 0)
    empty = EvalSample(f.rgb, "pumpkin", ("pumpkin", "seq-01", 9), depth=np.zeros_like(f.depth))
    res = run([empty, f])
    assert res.skipped == [("pumpkin", "seq-01", 9)]
    assert res.summary.count == 1
    assert PROTOCOL.details(res)["skipped"] == [["pumpkin", "seq-01", "9"]]

