"""Tests for f2depth.formats.sevenscenes: split files, depth units and invalid values, poses, bad inputs."""

from __future__ import annotations

import shutil

import cv2
import fakes
import numpy as np
import pytest

from f2depth.errors import DataError
from f2depth.formats.sevenscenes import SevenScenesSet, read_pose

SCENES = {"chess": ([3, 5], [1]), "heads": ([1], [2])}


@pytest.fixture(scope="module")
def template(tmp_path_factory):
    root = tmp_path_factory.mktemp("7scenes")
    fakes.write_sevenscenes(root, SCENES, frames=3)
    return root


@pytest.fixture
def root(template, tmp_path):
    shutil.copytree(template, tmp_path / "7scenes")
    return tmp_path / "7scenes"


def test_test_split_and_sample(root):
    ds = SevenScenesSet(root)
    assert len(ds) == 3 * 3  # chess seq-03, seq-05, heads seq-01
    seqs = [ds[i].key[:2] for i in (0, 3, 6)]
    assert seqs == [("chess", "seq-03"), ("chess", "seq-05"), ("heads", "seq-01")]
    assert [ds.scene(i) for i in (0, 3, 6)] == ["chess", "chess", "heads"]
    s = ds[2]
    assert s.key == ("chess", "seq-03", 2) and s.scene == "chess" and s.points is None
    assert s.rgb.shape == (480, 640, 3) and s.rgb.dtype == np.uint8
    assert s.depth.dtype == np.float32 and s.depth.shape == (480, 640)
    assert s.depth[5, 5] == pytest.approx(1.52)  # 1520 mm
    assert (s.depth[0] == 0).all() and (s.depth[1] == 0).all()  # 65535 and 0 → invalid
    pose = read_pose(root / "chess" / "seq-03" / "frame-000002.pose.txt")
    np.testing.assert_allclose(pose[:3, 3], [0.2, 0.0, 0.5])
    np.testing.assert_array_equal(ds.K, [[585, 0, 320], [0, 585, 240], [0, 0, 1]])


def test_train_split_stride_and_scene_subset(root):
    assert len(SevenScenesSet(root, split="train")) == 6
    ds = SevenScenesSet(root, stride=2, scenes=["heads"])
    assert [ds[i].key for i in range(len(ds))] == [("heads", "seq-01", 0), ("heads", "seq-01", 2)]


def test_missing_folders(root, tmp_path):
    with pytest.raises(DataError, match="7-Scenes folder not found"):
        SevenScenesSet(tmp_path / "none")
    with pytest.raises(DataError, match="fire: scene folder not found"):
        SevenScenesSet(root, scenes=["fire"])
    (root / "heads" / "TestSplit.txt").write_text("sequence1\nsequence4\n")
    with pytest.raises(DataError, match="seq-04: sequence folder listed in TestSplit.txt not found"):
        SevenScenesSet(root)


def test_bad_split_line(root):
    (root / "chess" / "TestSplit.txt").write_text("sequence3\nseq5\n")
    with pytest.raises(DataError, match="TestSplit.txt: line 2 is 'seq5'"):
        SevenScenesSet(root)


def test_missing_depth_and_bad_files(root):
    (root / "chess" / "seq-03" / "frame-000001.depth.png").unlink()
    with pytest.raises(DataError, match=r"frame-000001\.depth\.png: missing"):
        SevenScenesSet(root)


def test_truncated_wrong_size_bad_pose(root):
    ds = SevenScenesSet(root, scenes=["heads"])
    q = root / "heads" / "seq-01"
    fakes.truncate(q / "frame-000000.color.png", 0.5)
    with pytest.raises(DataError, match=r"frame-000000\.color\.png: truncated PNG"):
        ds[0]
    cv2.imwrite(str(q / "frame-000001.depth.png"), np.zeros((240, 320), np.uint16))
    with pytest.raises(DataError, match=r"frame-000001\.depth\.png: image is 240×320"):
        ds[1]
    (q / "frame-000002.pose.txt").write_text("1 0 0\n0 1 0\n")
    with pytest.raises(DataError, match=r"frame-000002\.pose\.txt: expected a finite 4×4"):
        read_pose(q / "frame-000002.pose.txt")


def test_an_empty_pose_file_is_one_line_without_numpy_warnings(root, recwarn):
    """Issue 25 item 9. Before: `reconstruct` with an empty pose file added numpy's "loadtxt: input
    contained no data" warning to its one line. Now: a DataError saying the file is empty, no warning."""
    q = root / "heads" / "seq-01"
    for text in ("", "\n  \n"):
        (q / "frame-000002.pose.txt").write_text(text)
        with pytest.raises(DataError, match=r"frame-000002\.pose\.txt: empty pose file \(no matrix\)"):
            read_pose(q / "frame-000002.pose.txt")
    (q / "frame-000002.pose.txt").write_text("# a comment only\n")
    with pytest.raises(DataError, match=r"frame-000002\.pose\.txt: expected a finite 4×4"):
        read_pose(q / "frame-000002.pose.txt")
    assert len(recwarn) == 0, [str(w.message) for w in recwarn]
