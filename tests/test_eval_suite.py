"""Tests for f2depth.eval.suite: every protocol for one predictor, kept images, seeds, CSV rows.

Known answer: the ground truth of every fake sample is one constant depth per image (NYU, 7-Scenes) or
per Campus image, and the predictor returns a constant disparity, so after per-image median scaling the
prediction is exact (AbsRel 0, δ1 1) with and without post-processing.
"""

from __future__ import annotations

import csv
import io

import numpy as np
import pytest
import torch

from f2depth.eval import suite
from f2depth.formats.samples import EvalSample
from f2depth.protocols import registry
from f2depth.protocols.metrics import METRIC_NAMES


def constant(x: torch.Tensor) -> torch.Tensor:
    return torch.full((x.shape[0], 1, *x.shape[2:]), 0.4)


class Samples:
    """A list of samples as a SampleSet (``scene(i)`` as the loaders have it)."""

    def __init__(self, items):
        self.items = items

    def __len__(self):
        return len(self.items)

    def __getitem__(self, i):
        return self.items[i]

    def scene(self, i):
        return self.items[i].scene


def sets():
    rng = np.random.default_rng(0)
    nyu = []
    for i in range(3):
        depth = np.full((480, 640), 1.5 + i, np.float32)
        depth[:50, :50] = 0.0  # holes
        rgb = rng.integers(0, 256, (480, 640, 3), dtype=np.uint8)
        nyu.append(EvalSample(rgb, "room", (i + 1,), depth=depth))
    seven = [EvalSample(rng.integers(0, 256, (48, 64, 3), dtype=np.uint8), scene, (scene, "seq-01", k),
                        depth=np.full((48, 64), 1.2 + 0.1 * k, np.float32))
             for scene in ("chess", "fire") for k in range(3)]
    campus = [EvalSample(rng.integers(0, 256, (40, 30, 3), dtype=np.uint8), s, (s, f"img{k}"),
                         points=np.array([[1.0, 2.0, 3.0 + k], [20.0, 30.0, 3.0 + k], [5.0, 9.0, 3.0 + k]]))
              for s in ("1", "2") for k in range(2)]
    return {"nyu": Samples(nyu), "sevenscenes": Samples(seven), "campus": Samples(campus)}


CFG = suite.SuiteConfig(batch_size=2, timing_height=32, timing_width=64, timing_repeats=2, timing_warmup=1,
                        figure_images=2, figure_width=100)


def test_constant_prediction_of_constant_depth_is_perfect_everywhere():
    r = suite.evaluate_model(constant, sets(), CFG, (32, 64))
    assert set(r.headline) == {*suite.GROUPS, *suite.TIMING_KEYS}
    for group in suite.GROUPS:
        assert set(r.headline[group]) == set(METRIC_NAMES)
        assert r.headline[group]["abs_rel"] == pytest.approx(0.0, abs=1e-6), group
        assert r.headline[group]["a1"] == 1.0, group
    assert r.headline["ms"] > 0 and r.headline["ms_pp"] > 0
    assert r.details["input_hw"] == [32, 64]
    assert r.details["nyu"]["count"] == 3 and r.details["timing"]["ms"]["repeats"] == 2
    assert [row["scene"] for row in r.details["sevenscenes"]["rows"]] == ["chess", "fire", "Average",
                                                                          "All frames"]
    # per-image rows: every image, once without and once with PP
    assert len(r.per_image["nyu"]) == 6 and len(r.per_image["sevenscenes"]) == 12
    assert len(r.per_image["campus"]) == 8
    assert [row["post_process"] for row in r.per_image["nyu"]] == [False] * 3 + [True] * 3
    assert {row["index"] for row in r.per_image["nyu"]} == {1, 2, 3}


def test_kept_images_for_figures():
    r = suite.evaluate_model(constant, sets(), CFG, (32, 64))
    k = r.kept
    assert k["nyu_id"].tolist() == ["1", "3"]  # 2 evenly spaced of 3
    assert k["nyu_rgb"].shape == (2, 76, 100, 3)  # the 427×561 crop shrunk to width 100
    assert k["nyu_rgb"].dtype == np.uint8
    assert k["nyu_gt"].shape == k["nyu_pred"].shape == (2, 76, 100)
    np.testing.assert_allclose(k["nyu_pred"][1], 3.5, rtol=1e-5)  # median-scaled onto gt
    assert k["sevenscenes_id"].tolist() == ["chess/seq-01/1", "fire/seq-01/1"]  # middle frame per scene
    assert k["sevenscenes_rgb"].shape == (2, 48, 64, 3)  # narrower than figure_width: unchanged


def test_datasets_subset_and_own_size():
    cfg = suite.SuiteConfig(height=64, width=96, datasets=("campus",), timing_height=32, timing_width=32,
                            timing_repeats=1, timing_warmup=0, figure_images=0)
    r = suite.evaluate_model(constant, sets(), cfg, (32, 64))
    assert set(r.headline) == {"campus", "campus_pp", "ms", "ms_pp"}
    assert r.details["input_hw"] == [64, 96] and r.kept == {}
    assert r.details["campus"]["settings"]["height"] == 64


def test_settings_reach_the_protocols_that_read_them():
    cfg = suite.SuiteConfig(nyu_crop="eigen_sc", interpolation="lanczos", upsample="bilinear")
    assert suite.settings(registry.protocol("nyu"), cfg, (32, 64)) == {
        "height": 32, "width": 64, "interpolation": "lanczos", "upsample": "bilinear", "crop": "eigen_sc"}
    assert suite.settings(registry.protocol("campus"), cfg, (32, 64)) == {
        "height": 32, "width": 64, "interpolation": "lanczos"}


def test_config_errors():
    with pytest.raises(ValueError, match="unknown test sets \\['kitti'\\]"):
        suite.SuiteConfig(datasets=("nyu", "kitti"))
    with pytest.raises(ValueError, match="both evaluate.height and evaluate.width"):
        suite.SuiteConfig(height=288)
    with pytest.raises(ValueError, match="unknown NYU crop"):
        suite.SuiteConfig(nyu_crop="eigne")
    with pytest.raises(ValueError, match="'nyu' is listed in evaluate.datasets but was not loaded"):
        suite.evaluate_model(constant, {}, suite.SuiteConfig(datasets=("nyu",)), (32, 32))


def test_mean_over_seeds_and_metrics_document():
    a = {"nyu": {"abs_rel": 0.2, "a1": 0.7}, "ms": 10.0}
    b = {"nyu": {"abs_rel": 0.4, "a1": 0.9}, "ms": 20.0}
    doc = suite.metrics_document("full", [3, 1], [a, b])
    assert doc["nyu"] == pytest.approx({"abs_rel": 0.3, "a1": 0.8}) and doc["ms"] == 15.0
    assert doc["n_seeds"] == 2 and list(doc["per_seed"]) == ["seed3", "seed1"]
    assert doc["per_seed"]["seed1"] == b and doc["variant"] == "full"
    with pytest.raises(ValueError, match="2 seeds but 1 results"):
        suite.metrics_document("full", [0, 1], [a])


def test_rows_csv_round_trip():
    rows = [{"seed": 0, "post_process": False, "abs_rel": 0.1 + 0.2}, {"seed": 1, "abs_rel": 1 / 3, "x": "a"}]
    back = list(csv.DictReader(io.StringIO(suite.rows_csv(rows))))
    assert list(back[0]) == ["seed", "post_process", "abs_rel", "x"]
    assert float(back[0]["abs_rel"]) == 0.1 + 0.2 and float(back[1]["abs_rel"]) == 1 / 3
    assert back[1]["post_process"] == "" and back[0]["x"] == ""


def test_model_disparity_is_inverse_depth():
    from f2depth.depth import DepthModel, DepthModelConfig

    torch.manual_seed(0)
    model = DepthModel(DepthModelConfig(64, 64)).eval()
    x = torch.rand(1, 3, 64, 64)
    with torch.no_grad():
        disp = suite.model_disparity(model)(x)
        depth = model.predict_depth(x)
    torch.testing.assert_close(disp * depth, torch.ones_like(depth))


def test_one_pass_scores_with_and_without_pp_as_two_passes_do_and_each_image_runs_twice_not_thrice():
    """The suite scores both from one forward pass of [img, flip(img)]: the same numbers as the protocol's
    two separate runs (an image-dependent, asymmetric predictor), while the network sees 2 images per test
    image instead of 3."""
    seen = []

    def varied(x: torch.Tensor) -> torch.Tensor:  # brighter, and further right, is nearer
        seen.append(x.shape[0])
        ramp = torch.linspace(0.5, 1.5, x.shape[-1])
        return 0.2 + x.mean(1, keepdim=True) * ramp

    data = sets()
    for name in ("nyu", "sevenscenes", "campus"):
        p = registry.protocol(name)
        kw = suite.settings(p, CFG, (32, 64))
        seen.clear()
        plain, pp = p.evaluate_with_and_without_pp(data[name], varied, batch_size=2, keep=[0], **kw)
        assert sum(seen) == 2 * len(data[name])
        seen.clear()
        apart = [p.evaluate(data[name], varied, batch_size=2, keep=[0], post_process=f, **kw)
                 for f in (False, True)]
        assert sum(seen) == 3 * len(data[name])
        for got, want in zip((plain, pp), apart):
            assert got.metrics == pytest.approx(want.metrics, rel=1e-6, abs=1e-9), name
            assert got.settings == want.settings
            for m in METRIC_NAMES:
                np.testing.assert_allclose(got.per_image[m], want.per_image[m], rtol=1e-6, atol=1e-9)
        assert plain.metrics["abs_rel"] != pytest.approx(pp.metrics["abs_rel"], rel=1e-4)  # PP changes them
        assert plain.settings["post_process"] is False and pp.settings["post_process"] is True
    with pytest.raises(TypeError, match="scores both"):
        registry.protocol("nyu").evaluate_with_and_without_pp(data["nyu"], varied, post_process=True)


def test_timings_of_an_earlier_model_are_reused_not_measured_again(monkeypatch):
    first = suite.evaluate_model(constant, sets(), CFG, (32, 64))

    def no_timing(*args, **kwargs):
        raise AssertionError("timed again")

    monkeypatch.setattr(suite, "time_inference", no_timing)
    second = suite.evaluate_model(constant, sets(), CFG, (32, 64), timing=first.details["timing"])
    assert second.details["timing"] == first.details["timing"]
    assert [second.headline[k] for k in suite.TIMING_KEYS] == [first.headline[k] for k in suite.TIMING_KEYS]
