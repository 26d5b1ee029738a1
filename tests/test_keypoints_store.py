"""Keypoint files and the losses' API (tensor per frame, P²Net's fill-up)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from f2depth.keypoints.store import KeypointFile, KeypointFileError, fill_up, pack, save_keypoints


def test_roundtrip_with_empty_frames(tmp_path):
    pts = [np.array([[1, 2, 0], [5, 6, 2]]), np.zeros((0, 3), int), np.array([[7, 8, 1]])]
    path = tmp_path / "kp" / "train.npz"
    save_keypoints(path, [4, 0, 9], pts)
    with np.load(path) as z:
        assert z["frame_ids"].dtype == np.int64 and z["offsets"].dtype == np.int64
        assert z["points"].dtype == np.int16 and z["points"].shape == (3, 3)
        np.testing.assert_array_equal(z["offsets"], [0, 2, 2, 3])
    f = KeypointFile(path)
    assert len(f) == 3 and 9 in f and 1 not in f
    np.testing.assert_array_equal(f.points(4), pts[0])
    assert f.points(0).shape == (0, 3)
    t = f.tensor(9)
    assert t.dtype == torch.int64 and t.tolist() == [[7, 8, 1]]
    assert np.diff(f.offsets).tolist() == [2, 0, 1]
    with pytest.raises(KeyError, match="no entry"):
        f.points(1)


def test_malformed_files_name_the_file_and_fix(tmp_path):
    with pytest.raises(KeypointFileError, match="not found.*dvc repro keypoints"):
        KeypointFile(tmp_path / "missing.npz")
    bad = pack([0, 1], [np.zeros((2, 3), int), np.zeros((1, 3), int)])
    bad["offsets"] = np.array([0, 3, 2])
    np.savez(tmp_path / "bad.npz", **bad)
    with pytest.raises(KeypointFileError, match=r"bad\.npz: offsets"):
        KeypointFile(tmp_path / "bad.npz")
    dup = pack([1, 1], [np.zeros((0, 3), int), np.zeros((0, 3), int)])
    np.savez(tmp_path / "dup.npz", **dup)
    with pytest.raises(KeypointFileError, match="not unique"):
        KeypointFile(tmp_path / "dup.npz")
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(KeypointFileError, match="unreadable"):
        KeypointFile(tmp_path / "junk.npz")
    with pytest.raises(ValueError, match="int16"):
        pack([0], [np.array([[70000, 0, 0]])])


def test_fill_up_is_seeded_uniform_and_masks_real_points():
    kp = torch.tensor([[3, 4, 0], [3, 4, 1], [10, 2, 0]])
    xy, real = fill_up(kp, 3000, 96, 128, generator=7)
    assert xy.shape == (3000, 2) and xy.dtype == torch.int64 and real.dtype == torch.bool
    assert real[:3].all() and not real[3:].any()
    assert xy[:3].tolist() == [[3, 4], [3, 4], [10, 2]]  # duplicates kept, x first
    rand = xy[3:]
    assert rand[:, 0].min() >= 0 and rand[:, 0].max() == 127 and rand[:, 1].max() == 95
    assert abs(rand[:, 0].float().mean().item() - 63.5) < 4
    assert abs(rand[:, 1].float().mean().item() - 47.5) < 3
    again, _ = fill_up(kp.numpy(), 3000, 96, 128, generator=torch.Generator().manual_seed(7))
    assert torch.equal(xy, again)
    other, _ = fill_up(kp, 3000, 96, 128, generator=8)
    assert not torch.equal(xy, other)


def test_fill_up_edge_cases():
    xy, real = fill_up(np.zeros((0, 3), np.int16), 5, 4, 4, generator=0)  # a flat frame: all random
    assert xy.shape == (5, 2) and not real.any()
    many = torch.arange(30).reshape(10, 3)
    xy, real = fill_up(many, 4, 96, 128)
    assert real.all() and xy.tolist() == many[:4, :2].tolist()
    with pytest.raises(ValueError):
        fill_up(many, 4, 0, 128)
