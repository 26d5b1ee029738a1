"""Tests for f2depth.report.published: the paper's headline numbers and the tables' internal consistency."""

from __future__ import annotations

import numpy as np
import pytest

from f2depth.report import published as P

#: frames in the official 7-Scenes test sequences (TestSplit.txt) per scene; 17,000 in all (the paper §4.1)
TEST_FRAMES = {"chess": 2000, "fire": 2000, "heads": 1000, "office": 4000, "pumpkin": 2000,
               "redkitchen": 5000, "stairs": 1000}


def nyu(method: str, post_process: bool) -> dict:
    return next(r for r in P.table1() if r["method"] == method and r["post_process"] == post_process)


def test_spec_headline_numbers():
    f, f_pp = nyu("F²Depth", False), nyu("F²Depth", True)
    assert (f["abs_rel"], f["rmse"], f["a1"]) == (0.158, 0.583, 0.779)
    assert (f_pp["abs_rel"], f_pp["rmse"], f_pp["a1"]) == (0.153, 0.569, 0.787)
    assert nyu("P²Net", False)["abs_rel"] == 0.159 and nyu("P²Net", True)["abs_rel"] == 0.157
    assert sum(TEST_FRAMES.values()) == 17_000


def test_spec_ablation_numbers():
    no_pp = {r["variant"]: r["rmse"] for r in P.table5() if not r["post_process"]}
    assert no_pp == {"baseline": 0.599, "no_feature": 0.586, "full": 0.583}
    assert {r["variant"]: r["rmse"] for r in P.table6()} == {
        "flow_pretrained": 0.591, "flow_full_ft": 0.596, "full": 0.583,
    }  # fmt: skip
    avg = [r for r in P.sevenscenes("F²Depth") if r["scene"] == "Average"][0]
    assert avg["a1"] == 0.758
    assert [r for r in P.campus() if r["method"] == "F²Depth"][0]["a1"] == 0.760
    assert (P.inference_ms()["no_pp"], P.inference_ms()["pp"]) == (9.4, 13.5)


def test_rows_are_marked_and_sourced():
    tables = {
        "tab:tab1": P.table1(), "tab:tab5": P.table5(), "tab:tab6": P.table6(),
        "tab:tab7scenes": P.sevenscenes("P²Net"), "tab:tab3": P.campus(),
        "tab:tab4": P.campus_scenes("P²Net"),
    }  # fmt: skip
    for label, rows in tables.items():
        assert rows and all(r["quoted"] and r["source"] == label for r in rows)
    assert len(P.table1()) == 25 and len(P.campus_scenes()) == 18 and len(P.sevenscenes()) == 8
    assert P.table1()[1]["a1"] is None  # "-" in the paper


@pytest.mark.parametrize("method", ["F²Depth", "P²Net"])
def test_sevenscenes_average_is_frame_weighted(method):
    rows = P.sevenscenes(method)
    scenes = {r["scene"]: r for r in rows if r["scene"] != "Average"}
    avg = rows[-1]
    n = np.array([TEST_FRAMES[s] for s in scenes])
    for k in ("abs_rel", "rmse", "a1", "a2", "a3"):
        v = np.array([scenes[s][k] for s in scenes])
        assert float((v * n).sum() / n.sum()) == pytest.approx(avg[k], abs=1.1e-3)  # rounding of inputs
    rmse = np.array([scenes[s]["rmse"] for s in scenes])
    assert abs(rmse.mean() - avg["rmse"]) > 9e-3  # the unweighted mean does not give the paper's row


@pytest.mark.parametrize("method", ["F²Depth", "P²Net"])
def test_campus_summary_is_mean_of_scene_rows(method):
    summary = [r for r in P.campus() if r["method"] == method][0]
    rows = P.campus_scenes(method)
    for k in ("abs_rel", "rmse", "log10", "a1", "a2", "a3"):
        assert np.mean([r[k] for r in rows]) == pytest.approx(summary[k], abs=6e-4)
