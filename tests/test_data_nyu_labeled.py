"""Tests for f2depth.formats.nyu_labeled: splits.mat, the HDF5 labeled .mat, NYULabeledSet."""

from __future__ import annotations

import pickle
from pathlib import Path

import fakes
import h5py
import numpy as np
import pytest

from f2depth.errors import DataError
from f2depth.formats.nyu_labeled import NYULabeledSet, read_splits, scene_names, scenes_of_test_images

REAL_SPLITS = Path(__file__).resolve().parent / "data" / "nyu" / "splits.mat"
SCENES = ["bedroom_0001", "kitchen_0003a", "bedroom_0001", "office_0012"]


@pytest.fixture
def labeled(tmp_path):
    mat, splits = tmp_path / "nyu_depth_v2_labeled.mat", tmp_path / "splits.mat"
    arrays = fakes.write_labeled_mat(mat, SCENES, seed=3)
    fakes.write_splits(splits, train=[1, 3], test=[2, 4])
    return mat, splits, arrays


def test_real_official_splits():
    train, test = read_splits(REAL_SPLITS, n_images=1449)
    assert len(test) == 654 and int(test.sum()) == 498838 and len(train) == 795
    assert test[:5].tolist() == [1, 2, 9, 14, 15] and test[-1] == 1449
    assert test.dtype == np.int64


def test_split_index_out_of_range(tmp_path):
    p = tmp_path / "splits.mat"
    fakes.write_splits(p, train=[1, 2], test=[3, 5])
    with pytest.raises(DataError, match=r"splits.mat: testNdxs\[1\] = 5 is outside 1..4"):
        read_splits(p, n_images=4)
    fakes.write_splits(p, train=[0, 2], test=[3])
    with pytest.raises(DataError, match=r"trainNdxs\[0\] = 0 is outside"):
        read_splits(p)


def test_split_bad_files(tmp_path):
    with pytest.raises(DataError, match="splits file not found"):
        read_splits(tmp_path / "none.mat")
    p = tmp_path / "splits.mat"
    fakes.write_splits(p, train=[1, 2], test=[2, 3])
    with pytest.raises(DataError, match="index 2 is in both"):
        read_splits(p)
    (tmp_path / "junk.mat").write_bytes(b"garbage" * 30)
    with pytest.raises(DataError, match="junk.mat: not a readable MATLAB v5 file"):
        read_splits(tmp_path / "junk.mat")


def test_labeled_set_reads_image_axes(labeled):
    mat, splits, arrays = labeled
    assert scene_names(mat) == SCENES
    with NYULabeledSet(mat, splits, split="test") as ds:
        assert len(ds) == 2 and ds.indices.tolist() == [2, 4]
        s = ds[1]
        assert s.key == (4,) and s.scene == ds.scene(1) == "office_0012" and s.points is None
        assert s.rgb.shape == (480, 640, 3) and s.rgb.dtype == np.uint8
        np.testing.assert_array_equal(s.rgb, arrays["rgb"][3])
        assert s.depth.shape == (480, 640) and s.depth.dtype == np.float32
        np.testing.assert_array_equal(s.depth, arrays["depths"][3])
        assert ds[-1].key == (4,)
        with pytest.raises(IndexError):
            ds[2]
    raw = NYULabeledSet(mat, splits, split="all", gt="rawDepths")
    assert len(raw) == 4
    np.testing.assert_array_equal(raw[0].depth, arrays["rawDepths"][0])
    assert (raw[0].depth == 0).any()
    clone = pickle.loads(pickle.dumps(raw))  # DataLoader workers get their own HDF5 handle
    np.testing.assert_array_equal(clone[2].rgb, arrays["rgb"][2])
    raw.close()
    clone.close()


def test_scenes_of_test_images(labeled):
    mat, splits, _ = labeled
    assert scenes_of_test_images(mat, splits) == {"kitchen_0003a", "office_0012"}


def test_labeled_bad_inputs(labeled, tmp_path):
    mat, splits, _ = labeled
    with pytest.raises(DataError, match="labeled .mat file not found"):
        NYULabeledSet(tmp_path / "missing.mat", splits)
    (tmp_path / "bad.mat").write_bytes(b"not hdf5")
    with pytest.raises(DataError, match="bad.mat: not an HDF5"):
        NYULabeledSet(tmp_path / "bad.mat", splits)
    big = tmp_path / "big_splits.mat"
    fakes.write_splits(big, train=[1], test=[2, 9])
    with pytest.raises(DataError, match=r"big_splits.mat: testNdxs\[1\] = 9 is outside 1..4"):
        NYULabeledSet(mat, big)
    with pytest.raises(ValueError, match="gt must be one of"):
        NYULabeledSet(mat, splits, gt="depth")


def test_labeled_wrong_layout(tmp_path):
    p = tmp_path / "l.mat"
    with h5py.File(p, "w") as f:
        f.create_dataset("images", data=np.zeros((2, 3, 480, 640), np.uint8))  # axes not reversed
    msg = r"'images' has shape \(2, 3, 480, 640\), expected \(N, 3, 640, 480\)"
    with pytest.raises(DataError, match=msg):
        scene_names(p)


def test_labeled_nan_depth(labeled):
    mat, splits, _ = labeled
    with h5py.File(mat, "r+") as f:
        f["depths"][1, 5, 5] = np.nan
    ds = NYULabeledSet(mat, splits)
    with pytest.raises(DataError, match="depths of image 2 has 1 negative or non-finite"):
        ds[0]
    ds.close()
