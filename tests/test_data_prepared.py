"""Tests for f2depth.formats.prepared: the reader of data/prepared, on good and broken sets."""

from __future__ import annotations

import json

import cv2
import fakes
import numpy as np
import pytest

from f2depth.errors import DataError
from f2depth.formats.prepared import PreparedSet

HW = (8, 10)
K = [[9.0, 0.0, 4.5], [0.0, 9.0, 3.5], [0.0, 0.0, 1.0]]
IDS = ["s_00000", "s_00010", "s_00020"]


def write_prepared(root, hw=HW):
    root.mkdir()
    (root / "camera.json").write_text(json.dumps({"K": K, "height": hw[0], "width": hw[1], "crop": 16}))
    lines = ["frame_id,scene,raw_file,image,gt"]
    for k, fid in enumerate(IDS):
        fakes.write_rgb(root / "images" / "s" / f"{fid}.png", np.full((*hw, 3), 40 * k, np.uint8))
        gt = f"gt/s/{fid}.npz" if k == 1 else ""
        lines.append(f"{fid},s,s/r-{k}.0-{k}.ppm,images/s/{fid}.png,{gt}")
    (root / "gt" / "s").mkdir(parents=True)
    pose = np.eye(4)
    pose[2, 3] = 0.5
    np.savez(root / "gt" / "s" / "s_00010.npz", depth=np.full(hw, 2.5, np.float32), world_T_cam=pose)
    (root / "frames.csv").write_text("\n".join(lines) + "\n")
    (root / "tuples.csv").write_text("tuple_id,scene,target,prev,next,segments\n"
                                     "s_00010,s,s_00010,s_00000,s_00020,segments/s_00010.png\n")
    (root / "segments").mkdir()
    cv2.imwrite(str(root / "segments" / "s_00010.png"), np.arange(80, dtype=np.uint16).reshape(hw) % 3)
    (root / "pairs.csv").write_text("pair_id,scene,frame1,frame2\ns_00000,s,s_00000,s_00010\n"
                                    "s_00010,s,s_00010,s_00020\n")
    return root


def test_reads_everything(tmp_path):
    ps = PreparedSet(write_prepared(tmp_path / "p"))
    assert ps.hw == HW and ps.K.shape == (3, 3) and ps.K[0, 2] == 4.5
    assert [f.frame_id for f in ps.frames] == IDS and ps.frame_index("s_00020") == 2
    assert ps.tuples[0].prev == "s_00000" and len(ps.pairs) == 2
    assert ps.image("s_00020").shape == (*HW, 3) and ps.image("s_00020")[0, 0, 0] == 80
    assert ps.gt("s_00000") is None and not ps.has_gt("s_00000")
    depth, pose = ps.gt("s_00010")
    assert depth.dtype == np.float32 and depth[0, 0] == 2.5 and pose[2, 3] == 0.5
    seg = ps.segments("s_00010")
    assert seg.dtype == np.int64 and seg.shape == HW and seg.max() == 2
    with pytest.raises(KeyError, match="frame 'nope' is not in"):
        ps.image("nope")


def test_missing_set_and_camera(tmp_path):
    with pytest.raises(DataError, match="prepared set not found"):
        PreparedSet(tmp_path / "none")
    root = write_prepared(tmp_path / "p")
    (root / "camera.json").unlink()
    with pytest.raises(DataError, match="camera.json: not found"):
        PreparedSet(root)


def test_bad_tables(tmp_path):
    root = write_prepared(tmp_path / "p")
    (root / "tuples.csv").write_text("tuple_id,scene,target,prev,next,segments\n"
                                     "s_00010,s,s_00010,s_00000,s_00099,segments/s_00010.png\n")
    with pytest.raises(DataError, match="tuples.csv: tuple s_00010: unknown frame 's_00099'"):
        PreparedSet(root)
    (root / "pairs.csv").write_text("pair,scene,a,b\n")
    (root / "tuples.csv").unlink()
    with pytest.raises(DataError, match="tuples.csv: not found"):
        PreparedSet(root)


def test_missing_and_wrong_size_files(tmp_path):
    root = write_prepared(tmp_path / "p")
    (root / "segments" / "s_00010.png").unlink()
    with pytest.raises(DataError, match="s_00010.png: segments of tuple s_00010 missing"):
        PreparedSet(root)
    root = write_prepared(tmp_path / "q")
    fakes.write_rgb(root / "images" / "s" / "s_00000.png", np.zeros((4, 5, 3), np.uint8))
    ps = PreparedSet(root)
    with pytest.raises(DataError, match=r"s_00000.png: image is 4×5 \(H×W\), expected 8×10"):
        ps.image("s_00000")
    (root / "images" / "s" / "s_00020.png").unlink()
    with pytest.raises(DataError, match="s_00020.png: listed for frame s_00020 in frames.csv, missing"):
        PreparedSet(root)
