"""Tests for f2depth.formats.nyu_raw: scene and frame listing (names parsed and checked), frame reading."""

from __future__ import annotations

import fakes
import numpy as np
import pytest

from f2depth.errors import DataError
from f2depth.formats.nyu_raw import list_frames, list_scenes, read_frame


def test_scenes_and_frames_sorted_by_timestamp(tmp_path):
    fakes.write_nyu_raw(tmp_path, {"office_0002": 4, "bedroom_0076b": 3})
    (tmp_path / "README.txt").write_text("a file at the root is not a scene")
    assert list_scenes(tmp_path) == ["bedroom_0076b", "office_0002"]
    frames = list_frames(tmp_path, "office_0002")
    assert [f.index for f in frames] == [0, 1, 2, 3]
    ts = [f.timestamp for f in frames]
    assert ts == sorted(ts) and ts == fakes.raw_timestamps(4)
    names = [f.path.name for f in frames]
    assert names != sorted(names)  # "r-1000.0..." sorts before "r-999.9..." as text
    assert all(f.scene == "office_0002" and f.stem == f.path.stem for f in frames)
    img = read_frame(frames[0].path)
    assert img.shape == (480, 640, 3) and img.dtype == np.uint8


def test_missing_root(tmp_path):
    with pytest.raises(DataError, match="NYU raw folder not found"):
        list_scenes(tmp_path / "nowhere")


def test_missing_scene_and_empty_scene(tmp_path):
    fakes.write_nyu_raw(tmp_path, {"office_0002": 1}, extras=False)
    with pytest.raises(DataError, match="kitchen_0001: scene folder not found"):
        list_frames(tmp_path, "kitchen_0001")
    (tmp_path / "kitchen_0001").mkdir()
    (tmp_path / "kitchen_0001" / "INDEX.txt").write_text("")
    with pytest.raises(DataError, match="kitchen_0001: scene folder holds no r-"):
        list_frames(tmp_path, "kitchen_0001")


def test_malformed_frame_name(tmp_path):
    fakes.write_nyu_raw(tmp_path, {"office_0002": 1}, extras=False)
    (tmp_path / "office_0002" / "r-12.5.ppm").write_bytes(b"")
    with pytest.raises(DataError, match=r"r-12\.5\.ppm: malformed RGB frame name"):
        list_frames(tmp_path, "office_0002")


def test_bad_scene_folder_name(tmp_path):
    (tmp_path / "bad scene").mkdir()
    with pytest.raises(DataError, match="bad scene: scene folder name"):
        list_scenes(tmp_path)


def test_truncated_and_wrong_size_frames(tmp_path):
    fakes.write_nyu_raw(tmp_path, {"office_0002": 2}, extras=False)
    f0, f1 = list_frames(tmp_path, "office_0002")
    fakes.truncate(f0.path, 0.5)
    with pytest.raises(DataError, match=rf"{f0.path.name}: truncated"):
        read_frame(f0.path)
    fakes.write_ppm(f1.path, np.zeros((240, 320, 3), np.uint8))
    with pytest.raises(DataError, match=rf"{f1.path.name}: image is 240×320"):
        read_frame(f1.path)
