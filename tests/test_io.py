"""Atomic writers: the destination appears whole or not at all, with ordinary permissions."""

from __future__ import annotations

import json
import os
import stat

import numpy as np
import pytest

from f2depth import io


def test_write_json_converts_numpy_and_is_readable_by_others(tmp_path):
    path = tmp_path / "sub" / "m.json"
    io.write_json(path, {"a": np.float32(1.5), "b": np.arange(3), "c": tmp_path})
    assert json.loads(path.read_text()) == {"a": 1.5, "b": [0, 1, 2], "c": str(tmp_path)}
    umask = os.umask(0)
    os.umask(umask)
    assert stat.S_IMODE(path.stat().st_mode) == 0o666 & ~umask


def test_failed_write_leaves_old_file_and_no_temporaries(tmp_path):
    path = tmp_path / "x.txt"
    io.write_text(path, "old")
    with pytest.raises(RuntimeError), io.atomic_path(path) as tmp:
        tmp.write_text("half")
        raise RuntimeError("crash")
    assert path.read_text() == "old"
    assert os.listdir(tmp_path) == ["x.txt"]


def test_imwrite_and_npz_round_trip(tmp_path):
    img = np.random.default_rng(0).integers(0, 255, (5, 7, 3), dtype=np.uint8)
    io.imwrite(tmp_path / "a.png", img)
    import cv2

    assert np.array_equal(cv2.imread(str(tmp_path / "a.png")), img)
    io.save_npz(tmp_path / "a.npz", depth=img[..., 0].astype(np.float32))
    assert np.array_equal(np.load(tmp_path / "a.npz")["depth"], img[..., 0])
    with pytest.raises(OSError, match="could not write"):
        io.imwrite(tmp_path / "a.unknownext", img)
