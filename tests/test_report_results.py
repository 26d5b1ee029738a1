"""Tests for f2depth.report.results: which flow EPE belongs to a variant, history files, per-seed values."""

from __future__ import annotations

import json

import pytest

from f2depth.report.results import VariantResults, flow_epe, load_variant, read_history

FLOW = {
    "patch": {"pretrained": {"test": {"epe_all": 4.0, "epe_noc": 3.0, "epe_low_texture": 6.0}},
              "finetuned": {"test": {"epe_all": 1.0, "epe_noc": 0.5, "epe_low_texture": 2.0}}},
    "full": {"pretrained": {"test": {"epe_all": 4.0, "epe_noc": 3.0, "epe_low_texture": 6.0}},
             "finetuned": {"test": {"epe_all": 1.5, "epe_noc": 0.9, "epe_low_texture": 3.0}}},
}  # fmt: skip


def test_flow_epe_by_model_path():
    args = (FLOW, "models/flow_pretrained.pt", "models/flow_{loss}.pt")
    assert flow_epe("models/flow_patch.pt", *args) == {"epe_all": 1.0, "epe_noc": 0.5, "epe_low_texture": 2.0}
    assert flow_epe("./models/flow_full.pt", *args)["epe_all"] == 1.5
    assert flow_epe("models/flow_pretrained.pt", *args)["epe_low_texture"] == 6.0
    assert flow_epe(None, *args) is None
    assert flow_epe("elsewhere/arflow.pt", *args) is None
    no_gt = {"patch": {"finetuned": {"test": {"epe_all": None}}}}
    assert flow_epe("models/flow_patch.pt", no_gt, *args[1:])["epe_all"] is None


def test_read_history(tmp_path):
    p = tmp_path / "history.csv"
    p.write_text("epoch,total,val_a1\n0,,0.5\n1,0.9,0.6\n")
    h = read_history(p)
    assert h["epoch"] == [0.0, 1.0] and h["val_a1"] == [0.5, 0.6]
    assert h["total"][0] != h["total"][0] and h["total"][1] == 0.9  # blank → NaN
    assert read_history(tmp_path / "missing.csv") == {}


def test_variant_values_over_seeds(tmp_path):
    per_seed = {"seed0": {"nyu": {"a1": 0.6}, "ms": 2.0}, "seed4": {"nyu": {"a1": 0.8}, "ms": 4.0}}
    metrics = {"nyu": {"a1": 0.7}, "ms": 3.0, "n_seeds": 2, "per_seed": per_seed}
    campus = {k: {"scenes": {"3": {"mean": {"a1": a}, "count": 2}}, "average": {"a1": a}}
              for k, a in (("seed0", 0.1), ("seed4", 0.3))}
    details = {"seeds": {k: {"campus": c} for k, c in campus.items()}}
    (tmp_path / "m").mkdir()
    (tmp_path / "m" / "full.json").write_text(json.dumps(metrics))
    (tmp_path / "e" / "full").mkdir(parents=True)
    (tmp_path / "e" / "full" / "details.json").write_text(json.dumps(details))
    r = load_variant("full", tmp_path / "m", tmp_path / "e")
    assert isinstance(r, VariantResults) and r.n_seeds == 2 and r.kept == {}
    assert r.values("nyu", "a1") == [0.6, 0.8] and r.values("ms") == [2.0, 4.0]
    assert r.values("campus", "a1") is None
    assert r.scenes("campus") == ["3"] and r.scene_count("campus", "3") == 2
    assert r.scene_values("campus", "3", "a1") == [0.1, 0.3]
    assert r.scene_mean_values("campus", "a1") == [0.1, 0.3]
    (tmp_path / "m" / "bad.json").write_text("{")
    with pytest.raises(ValueError, match="bad.json: not valid JSON"):
        load_variant("bad", tmp_path / "m", tmp_path / "e")
