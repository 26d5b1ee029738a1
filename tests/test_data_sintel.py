"""MPI-Sintel layout loader and .flo files (f2depth.formats.sintel)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from f2depth.errors import DataError
from f2depth.formats.sintel import (
    SintelPairs,
    list_pairs,
    list_sequences,
    load_pair,
    read_flo,
    read_occlusion,
    write_flo,
)

HW = (12, 16)


def _png(path: Path, img: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(str(path), img)


def make_sintel(root: Path, seqs=("alley_1", "cave_2"), frames=3, passes=("clean", "final"), gt=True) -> Path:
    rng = np.random.default_rng(0)
    t = root / "training"
    for seq in seqs:
        for p in passes:
            for i in range(1, frames + 1):
                _png(t / p / seq / f"frame_{i:04d}.png", rng.integers(0, 255, (*HW, 3), dtype=np.uint8))
        if gt:
            for i in range(1, frames):
                flow = rng.normal(size=(*HW, 2)).astype(np.float32)
                write_flo(t / "flow" / seq / f"frame_{i:04d}.flo", flow)
                occ = np.zeros(HW, np.uint8)
                occ[:, :3] = 255
                _png(t / "occlusions" / seq / f"frame_{i:04d}.png", occ)
    return root


def test_flo_round_trip_and_layout(tmp_path):
    flow = np.random.default_rng(1).normal(size=(5, 7, 2)).astype(np.float32)
    write_flo(tmp_path / "a.flo", flow)
    data = (tmp_path / "a.flo").read_bytes()
    assert data[:4] == b"PIEH" and np.frombuffer(data[4:12], "<i4").tolist() == [7, 5]
    assert len(data) == 12 + 5 * 7 * 2 * 4
    assert np.array_equal(read_flo(tmp_path / "a.flo"), flow)


def test_flo_errors(tmp_path):
    with pytest.raises(DataError, match="not found"):
        read_flo(tmp_path / "missing.flo")
    (tmp_path / "magic.flo").write_bytes(b"XXXX" + np.array([2, 2], "<i4").tobytes() + bytes(32))
    with pytest.raises(DataError, match=r"magic\.flo: not a \.flo file: magic"):
        read_flo(tmp_path / "magic.flo")
    (tmp_path / "short.flo").write_bytes(b"PIEH" + np.array([4, 3], "<i4").tobytes() + bytes(40))
    with pytest.raises(DataError, match="bad .flo size: 52 bytes, a 4×3 flow needs 108"):
        read_flo(tmp_path / "short.flo")
    (tmp_path / "tiny.flo").write_bytes(b"PIE")
    with pytest.raises(DataError, match="header alone"):
        read_flo(tmp_path / "tiny.flo")
    (tmp_path / "neg.flo").write_bytes(b"PIEH" + np.array([-1, 3], "<i4").tobytes())
    with pytest.raises(DataError, match="bad .flo header"):
        read_flo(tmp_path / "neg.flo")


def test_pairs_and_loading(tmp_path):
    root = make_sintel(tmp_path / "sintel")
    assert list_sequences(root) == ["alley_1", "cave_2"]
    pairs = list_pairs(root, ("clean", "final"), require_flow=True)
    assert len(pairs) == 2 * 2 * 2
    p = pairs[0]
    assert (p.sequence, p.frame, p.pass_name) == ("alley_1", 1, "clean")
    assert p.image2.name == "frame_0002.png" and p.flow.name == "frame_0001.flo"
    d = load_pair(p)
    assert d["image1"].shape == (*HW, 3) and d["image1"].dtype == np.uint8
    assert d["flow"].shape == (*HW, 2) and d["occluded"].dtype == bool
    assert d["occluded"][:, :3].all() and not d["occluded"][:, 3:].any()
    assert np.array_equal(read_occlusion(p.occlusion), d["occluded"])
    only = list_pairs(root, ("final",), sequences=["cave_2"])
    assert [(q.sequence, q.frame) for q in only] == [("cave_2", 1), ("cave_2", 2)]


def test_training_dataset_resizes_without_random_draws(tmp_path):
    root = make_sintel(tmp_path / "sintel", gt=False)
    pairs = list_pairs(root)
    assert all(p.flow is None for p in pairs)
    ds = SintelPairs(pairs, (8, 10))
    state = torch.get_rng_state()
    a, b = ds[0]
    assert torch.equal(torch.get_rng_state(), state)  # augmentation is the trainer's, from its generator
    assert a.shape == b.shape == (3, 8, 10) and a.dtype == torch.float32
    assert float(a.min()) >= 0 and float(a.max()) <= 1 and not torch.equal(a, b)
    assert all(torch.equal(x, y) for x, y in zip(ds[0], (a, b)))


def test_missing_folders_and_files(tmp_path):
    with pytest.raises(DataError, match="Sintel folder not found"):
        list_pairs(tmp_path / "nope")
    (tmp_path / "empty").mkdir()
    with pytest.raises(DataError, match="missing 'training' folder"):
        list_pairs(tmp_path / "empty")
    root = make_sintel(tmp_path / "s", passes=("clean",))
    with pytest.raises(DataError, match="missing 'final' pass folder"):
        list_pairs(root, ("final",))
    with pytest.raises(DataError, match="missing sequence folder"):
        list_pairs(root, ("clean",), sequences=["market_9"])
    (root / "training" / "flow" / "cave_2" / "frame_0002.flo").unlink()
    with pytest.raises(DataError, match=r"frame_0002\.flo: missing ground truth \(flow\)"):
        list_pairs(root, ("clean",), require_flow=True)
    (root / "training" / "clean" / "alley_1" / "frame_0002.png").unlink()
    with pytest.raises(DataError, match="not consecutive"):
        list_pairs(root)


def test_unreadable_and_mismatched_files(tmp_path):
    root = make_sintel(tmp_path / "s", passes=("clean",))
    pairs = list_pairs(root, require_flow=True)
    pairs[0].image2.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(10))
    with pytest.raises(DataError, match=r"frame_0002\.png: truncated PNG"):
        load_pair(pairs[0])
    assert pairs[2].sequence == "cave_2"
    write_flo(pairs[2].flow, np.zeros((3, 3, 2), np.float32))
    with pytest.raises(DataError, match=r"flow is 3×3, its frames are 12×16"):
        load_pair(pairs[2])
