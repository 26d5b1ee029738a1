"""Tests for f2depth.inference.sequences and reconstruct: posed sequences, scale factors, TSDF fusion of
exact depth onto a known room, mesh metrics.

The fusion tests need Open3D, the optional extra 'recon' (not in requirements.lock): without it they
are skipped with that reason; everything else runs."""

from __future__ import annotations

import copy

import inference_data
import numpy as np
import pytest

from f2depth.errors import DataError
from f2depth.inference.optional import MissingDependency, require
from f2depth.inference.reconstruct import frame_scales
from f2depth.inference.sequences import read_gt_npz, sevenscenes_sequence, synth_sequence

NEEDS_OPEN3D = "open3d (optional extra 'recon') is not installed; `pip install 'f2depth[recon]'`"


def _open3d():
    return pytest.importorskip("open3d", reason=NEEDS_OPEN3D)


@pytest.fixture(scope="module")
def box(tmp_path_factory):
    root = tmp_path_factory.mktemp("box")
    poses = inference_data.write_box_sequence(root / "images", root / "gt", count=6)
    return root, poses


def test_synth_sequence(box):
    root, poses = box
    frames = synth_sequence(root / "images", root / "gt")
    assert [f.key for f in frames] == [f"frame-{k:06d}" for k in range(6)]
    np.testing.assert_allclose(frames[2].world_T_cam, poses[2])
    rgb = frames[0].rgb()
    depth = frames[0].reference_depth(rgb.shape[:2])
    assert rgb.shape == (96, 128, 3) and depth.shape == (96, 128) and depth.min() > 0.5
    assert [f.key for f in synth_sequence(root / "images", root / "gt", stride=2, max_frames=2)] == [
        "frame-000000", "frame-000002"]


def test_sequence_errors(box, tmp_path):
    root, _ = box
    (tmp_path / "images").mkdir()
    inference_data.write_images(tmp_path / "images", 1)
    with pytest.raises(DataError, match=r"img_00\.npz: ground-truth \.npz not found"):
        synth_sequence(tmp_path / "images", root / "gt")
    with pytest.raises(DataError, match="ground-truth folder not found"):
        synth_sequence(root / "images", tmp_path / "nowhere")
    with pytest.raises(DataError, match=r"no frame-XXXXXX\.color\.png files"):
        sevenscenes_sequence(tmp_path / "images")
    np.savez(tmp_path / "bad.npz", depth=np.ones((4, 4)))
    with pytest.raises(DataError, match=r"bad\.npz: no \['world_T_cam', 'K'\] arrays"):
        read_gt_npz(tmp_path / "bad.npz")


def test_frame_scales():
    assert frame_scales([2.0, 4.0, 9.0], "sequence") == [4.0, 4.0, 4.0]
    assert frame_scales([2.0, 4.0], "frame") == [2.0, 4.0]
    assert frame_scales([None, None], "fixed", 1.5) == [1.5, 1.5]
    with pytest.raises(ValueError, match="reference depth"):
        frame_scales([2.0, None], "sequence")


def test_missing_open3d_is_reported(monkeypatch):
    monkeypatch.setitem(__import__("sys").modules, "open3d", None)
    with pytest.raises(MissingDependency, match=r"needs the optional package 'open3d'.*f2depth\[recon\]"):
        require("open3d", "3-D reconstruction")


def test_fusing_exact_depth_reproduces_the_room(box):
    _open3d()
    from f2depth.inference.reconstruct import TSDFFusion, TSDFSettings, mesh_metrics

    root, _ = box
    fusion = TSDFFusion(TSDFSettings(voxel=0.04, max_depth=6.0))
    for f in synth_sequence(root / "images", root / "gt"):
        rgb = f.rgb()
        fusion.integrate(rgb, f.reference_depth(rgb.shape[:2]), f.K, f.world_T_cam)
    mesh = fusion.mesh()
    vertices = np.asarray(mesh.vertices)
    assert len(mesh.triangles) > 10_000
    assert np.percentile(inference_data.box_distance(vertices), 99) < 0.02  # half a voxel from the walls
    colours = np.asarray(mesh.vertex_colors)
    assert colours.shape == vertices.shape and colours.min() > 0.1 and colours.max() <= 200 / 255 + 1e-3
    same = mesh_metrics(mesh, mesh, samples=20_000)
    assert same["accuracy_mean"] < 1e-5 and same["completeness"] == 1.0 and same["fscore"] == 1.0
    shifted = mesh_metrics(copy.deepcopy(mesh).translate((0.0, 0.0, 0.1)), mesh, samples=20_000)
    assert 0.01 < shifted["accuracy_mean"] < 0.1 and shifted["completeness"] < 0.95


def test_sevenscenes_sequence_reads_poses_and_kinect_depth(tmp_path):
    poses = inference_data.write_box_sequence(tmp_path / "seq-01", tmp_path / "gt", count=2, hw=(480, 640),
                                              sevenscenes=True)
    frames = sevenscenes_sequence(tmp_path / "seq-01")
    assert len(frames) == 2 and frames[1].K[0, 0] == 585.0
    np.testing.assert_allclose(frames[1].world_T_cam, poses[1], atol=1e-6)  # text with 8 digits
    exact = read_gt_npz(tmp_path / "gt" / "frame-000001.npz")[0]
    np.testing.assert_allclose(frames[1].reference_depth((480, 640)), exact, atol=5e-4)  # millimetres
