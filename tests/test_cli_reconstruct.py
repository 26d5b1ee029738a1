"""Tests for ``f2depth reconstruct`` on a tiny synthetic posed sequence (a box room).

Fusion needs Open3D, the optional extra 'recon' (not in requirements.lock): without it the fusion tests
are skipped with that reason, and the missing-dependency message (exit 3) is tested instead."""

from __future__ import annotations

import json
import sys

import inference_data
import numpy as np
import pytest

from f2depth.cli import main

NEEDS_OPEN3D = "open3d (optional extra 'recon') is not installed; `pip install 'f2depth[recon]'`"


@pytest.fixture(scope="module")
def seq(tmp_path_factory):
    root = tmp_path_factory.mktemp("seq")
    inference_data.write_box_sequence(root / "images", root / "gt", count=5)
    inference_data.make_checkpoint(root / "depth.pt", seed=4)
    return root


def _args(seq, out, *extra):
    return ["reconstruct", "--sequence", str(seq / "images"), "--poses", "synth", "--gt", str(seq / "gt"),
            "--output", str(out), "--voxel", "0.05", "--max-depth", "6", "--no-progress", *extra]


def test_reference_depth_gives_a_perfect_score(seq, tmp_path, capsys):
    o3d = pytest.importorskip("open3d", reason=NEEDS_OPEN3D)
    code = main(_args(seq, tmp_path / "ref.ply", "--depth-source", "reference", "--evaluate", "--metrics",
                      str(tmp_path / "m.json")))
    assert code == 0
    summary = json.loads((tmp_path / "m.json").read_text())
    assert summary["metrics"]["accuracy_mean"] < 1e-4 and summary["metrics"]["completeness"] == 1.0
    mesh = o3d.io.read_triangle_mesh(str(tmp_path / "ref.ply"))
    assert len(mesh.triangles) == summary["triangles"] > 1000 and mesh.has_vertex_colors()
    assert np.percentile(inference_data.box_distance(np.asarray(mesh.vertices)), 99) < 0.025
    assert "accuracy mean" in capsys.readouterr().out


def test_predicted_depth_is_median_scaled_and_fused(seq, tmp_path):
    o3d = pytest.importorskip("open3d", reason=NEEDS_OPEN3D)
    code = main(_args(seq, tmp_path / "pred.ply", "--model", str(seq / "depth.pt"), "--evaluate",
                      "--reference-mesh", str(tmp_path / "ref.ply"), "--metrics", str(tmp_path / "m.json")))
    assert code == 0
    s = json.loads((tmp_path / "m.json").read_text())
    assert s["scaling"] == "sequence" and s["scale_min"] == s["scale_max"] > 1  # one factor: ~2 m / ~0.2
    assert {"accuracy_mean", "accuracy_median", "completeness", "precision", "fscore"} <= set(s["metrics"])
    assert len(o3d.io.read_triangle_mesh(str(tmp_path / "pred.ply")).triangles) == s["triangles"] > 0
    assert len(o3d.io.read_triangle_mesh(str(tmp_path / "ref.ply")).vertices) == s["reference_vertices"]


def test_reconstruct_usage_and_input_errors(seq, tmp_path, capfd):
    assert main(["reconstruct", "--sequence", str(seq / "images"), "--output", str(tmp_path / "m.ply")]) == 2
    assert "give --model or --onnx" in capfd.readouterr().err
    assert main(["reconstruct", "--sequence", str(seq / "images"), "--poses", "synth", "--depth-source",
                 "reference", "--output", str(tmp_path / "m.ply")]) == 2
    assert "--poses synth needs --gt" in capfd.readouterr().err
    code = main(["reconstruct", "--sequence", str(seq / "images"), "--model", str(seq / "depth.pt"),
                 "--output", str(tmp_path / "m.ply")])  # 7-Scenes layout expected: no .pose.txt files
    err = capfd.readouterr().err.splitlines()
    assert code == 1 and len(err) == 1 and "frame-000000.pose.txt: pose file not found" in err[0]
    assert not (tmp_path / "m.ply").exists()


def test_missing_open3d_exit_3(seq, tmp_path, capfd, monkeypatch):
    monkeypatch.setitem(sys.modules, "open3d", None)
    code = main(_args(seq, tmp_path / "m.ply", "--depth-source", "reference"))
    err = capfd.readouterr().err.splitlines()
    assert code == 3 and len(err) == 1 and "needs the optional package 'open3d'" in err[0]
    assert "f2depth[recon]" in err[0] and not (tmp_path / "m.ply").exists()
