"""Tests for f2depth.train.data and f2depth.train.augment: items, flips, colour jitter, seeded order."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import train_fakes

from f2depth.colour import AugmentConfig
from f2depth.epochs import sample_generator as generator
from f2depth.formats.prepared import PreparedSet
from f2depth.keypoints import KeypointFile, save_keypoints
from f2depth.train import augment as A
from f2depth.train.data import (
    STREAM_AUGMENT,
    DataConfig,
    TupleDataset,
    epoch_order,
    rank_indices,
)


@pytest.fixture
def dataset(tmp_path):
    root = train_fakes.write_prepared(tmp_path / "prepared", hw=(32, 64), scenes=2, frames=5)
    return TupleDataset(root, tmp_path / "keypoints" / "train.npz", DataConfig(num_points=40), seed=3)


def find_item(ds, flipped: bool, jitter: bool | None = None, epoch: int = 0):
    for e in range(epoch, epoch + 50):
        for i in range(len(ds)):
            d = A.draw(ds.config.augment_config, generator(ds.seed, e, i, STREAM_AUGMENT))
            if d.flip == flipped and (jitter is None or d.jitter == jitter):
                return ds.item(i, e), i, e, d
    raise AssertionError("no such draw")


def test_item_layout_and_fill_up(dataset):
    item = dataset.item(1, 0)
    for k in ("target", "prev", "next", "target_aug", "prev_aug", "next_aug"):
        assert item[k].shape == (3, 32, 64) and item[k].dtype == torch.float32
        assert float(item[k].min()) >= 0.0 and float(item[k].max()) <= 1.0
    assert item["points"].shape == (40, 2) and item["points"].dtype == torch.int64
    assert item["points_real"].sum() == 12  # the fake keypoints, then random fill-up
    assert item["segments"].shape == (32, 64) and item["K"].shape == (3, 3)
    x, y = item["points"][:, 0], item["points"][:, 1]
    assert x.min() >= 0 and x.max() < 64 and y.min() >= 0 and y.max() < 32
    # the tuple whose target has no keypoints is all random points, without error
    ps = dataset.prepared
    kp = dataset.keypoints
    empty = [i for i, t in enumerate(ps.tuples) if len(kp.points(ps.frame_index(t.target))) == 0]
    assert empty and dataset.item(empty[0], 0)["points_real"].sum() == 0


def test_items_depend_only_on_seed_epoch_index(dataset):
    a, b = dataset.item(2, 5), dataset.item(2, 5)
    for k in a:
        assert torch.equal(a[k], b[k])
    other_epoch = dataset.item(2, 6)
    assert not torch.equal(a["points"], other_epoch["points"])
    dataset.seed = 4
    assert not torch.equal(a["points"], dataset.item(2, 5)["points"])


def test_flip_keeps_keypoints_segments_and_K_consistent(dataset):
    ps = dataset.prepared
    item, i, _, _ = find_item(dataset, flipped=True)
    assert bool(item["flipped"])
    t = ps.tuples[i]
    raw = torch.from_numpy(ps.image(t.target)).permute(2, 0, 1).float() / 255
    seg = torch.from_numpy(ps.segments(t.tuple_id))
    kp = torch.from_numpy(dataset.keypoints.points(ps.frame_index(t.target)).astype(np.int64))
    w = 64
    assert torch.equal(item["target"], raw.flip(-1))
    assert torch.equal(item["segments"], seg.flip(-1))
    real = item["points"][item["points_real"]]
    assert torch.equal(real[:, 0], (w - 1) - kp[:, 0]) and torch.equal(real[:, 1], kp[:, 1])
    for (x, y), (x0, y0) in zip(real.tolist(), kp[:, :2].tolist()):  # same image content under the points
        assert torch.equal(item["target"][:, y, x], raw[:, y0, x0])
        assert item["segments"][y, x] == seg[y0, x0]
    K0 = torch.from_numpy(ps.K).float()
    assert item["K"][0, 2] == pytest.approx((w - 1) - K0[0, 2]) and item["K"][1, 2] == K0[1, 2]
    assert item["K"][0, 0] == K0[0, 0]


def test_mirrored_intrinsics_project_the_mirrored_world():
    K = torch.tensor([[50.0, 0.0, 40.3], [0.0, 52.0, 20.0], [0.0, 0.0, 1.0]])
    W = 64
    X = torch.tensor([[0.3, -0.2, 2.0], [-0.7, 0.4, 3.5], [0.05, 0.1, 1.2]])
    p = (K @ X.T).T
    u, v = p[:, 0] / p[:, 2], p[:, 1] / p[:, 2]
    Xm = X * torch.tensor([-1.0, 1.0, 1.0])  # the world seen in a mirror (x → −x)
    pm = (A.flip_intrinsics(K, W) @ Xm.T).T
    assert torch.allclose(pm[:, 0] / pm[:, 2], (W - 1) - u, atol=1e-4)
    assert torch.allclose(pm[:, 1] / pm[:, 2], v, atol=1e-4)
    pb = (K @ Xm.T).T  # P²Net's unchanged K misplaces mirrored points by (W−1) − 2·cx pixels
    assert torch.allclose((W - 1) - u - pb[:, 0] / pb[:, 2], torch.full((3,), 63 - 2 * 40.3), atol=1e-3)


def test_unflipped_item_and_no_augment(tmp_path):
    root = train_fakes.write_prepared(tmp_path / "prepared", hw=(32, 64), scenes=1, frames=4)
    plain = TupleDataset(root, tmp_path / "keypoints" / "train.npz", DataConfig(num_points=20, augment=False))
    ps = PreparedSet(root)
    for e in range(4):
        item = plain.item(1, e)
        assert not bool(item["flipped"])
        assert torch.equal(item["target_aug"], item["target"])
        ref = torch.from_numpy(ps.image(ps.tuples[1].target)).permute(2, 0, 1).float() / 255
        assert torch.equal(item["target"], ref)


def test_one_jitter_draw_for_all_frames(dataset):
    item, _, _, d = find_item(dataset, flipped=False, jitter=True)
    stacked = torch.stack([item["target"], item["prev"], item["next"]])
    expected = A.color_jitter(stacked, d)
    assert torch.allclose(torch.stack([item["target_aug"], item["prev_aug"], item["next_aug"]]), expected)
    assert not torch.allclose(item["target_aug"], item["target"])
    # the un-augmented frames stay raw
    ps = dataset.prepared
    t = ps.tuples[int(item["index"])]
    assert torch.equal(item["prev"], torch.from_numpy(ps.image(t.prev)).permute(2, 0, 1).float() / 255)


def test_draw_ranges_and_rate():
    cfg = AugmentConfig()
    g = torch.Generator().manual_seed(0)
    draws = [A.draw(cfg, g) for _ in range(400)]
    assert 0.4 < np.mean([d.flip for d in draws]) < 0.6 and 0.4 < np.mean([d.jitter for d in draws]) < 0.6
    assert all(0.8 <= d.brightness <= 1.2 and 0.8 <= d.contrast <= 1.2 and 0.8 <= d.saturation <= 1.2
               and -0.1 <= d.hue <= 0.1 and sorted(d.order) == [0, 1, 2, 3] for d in draws)


def test_epoch_order_and_rank_split():
    a, b = epoch_order(10, 0, 1), epoch_order(10, 0, 1)
    assert a == b and sorted(a) == list(range(10)) and a != epoch_order(10, 0, 2)
    one = rank_indices(10, 0, 1, 4)
    assert one == a[:8]  # drop_last: two whole batches of 4
    r0, r1 = rank_indices(10, 0, 1, 4, 0, 2), rank_indices(10, 0, 1, 4, 1, 2)
    for k in range(2):  # the ranks' k-th local batches (of 2) make up the k-th global batch
        assert sorted(r0[2 * k: 2 * k + 2] + r1[2 * k: 2 * k + 2]) == sorted(one[4 * k: 4 * k + 4])
    with pytest.raises(ValueError, match="multiple of the world size"):
        rank_indices(10, 0, 1, 3, 0, 2)
    with pytest.raises(ValueError, match="fewer than one batch"):
        rank_indices(3, 0, 1, 4)


def test_missing_keypoints_named(tmp_path):
    root = train_fakes.write_prepared(tmp_path / "prepared", hw=(32, 32), scenes=1, frames=4)
    save_keypoints(tmp_path / "other.npz", [0], [np.zeros((0, 3), int)])
    with pytest.raises(ValueError, match=r"other\.npz: no keypoints for 2 target frames"):
        TupleDataset(root, KeypointFile(tmp_path / "other.npz"), DataConfig())
