"""Tests for f2depth.ingest.sources: image, folder and video inputs, and their errors."""

from __future__ import annotations

import fakes
import inference_data
import numpy as np
import pytest

from f2depth.errors import DataError
from f2depth.ingest.sources import ImageSource, VideoSource, open_source


def test_folder_sorted_unsupported_and_hidden_ignored(tmp_path):
    paths = inference_data.write_images(tmp_path, 3)
    (tmp_path / "notes.txt").write_text("not an image")
    fakes.write_rgb(tmp_path / ".hidden.png", fakes.smooth_image((8, 8), 0))
    (tmp_path / "sub").mkdir()
    source = open_source(tmp_path)
    assert isinstance(source, ImageSource) and len(source) == 3
    frames = list(source)
    assert [f.name for f in frames] == ["img_00", "img_01", "img_02"]
    assert [f.origin for f in frames] == [str(p) for p in paths]
    assert frames[1].rgb.shape == (60, 80, 3) and frames[1].rgb.dtype == np.uint8
    np.testing.assert_array_equal(frames[1].rgb, fakes.smooth_image((60, 80), 1))  # RGB order, lossless


def test_same_stem_different_extension_get_distinct_names(tmp_path):
    fakes.write_rgb(tmp_path / "a.png", fakes.smooth_image((8, 8), 0))
    fakes.write_rgb(tmp_path / "a.jpg", fakes.smooth_image((8, 8), 1))
    fakes.write_rgb(tmp_path / "b.png", fakes.smooth_image((8, 8), 2))
    assert [f.name for f in open_source(tmp_path)] == ["a_jpg", "a_png", "b"]


def test_single_image(tmp_path):
    (path,) = inference_data.write_images(tmp_path, 1)
    frames = list(open_source(path))
    assert len(frames) == 1 and frames[0].name == "img_00"


def test_video_frames_in_order(tmp_path):
    written = inference_data.write_video(tmp_path / "clip.avi", 5)
    source = open_source(tmp_path / "clip.avi")
    assert isinstance(source, VideoSource) and len(source) == 5
    frames = list(source)
    assert [f.name for f in frames] == [f"frame_{i:06d}" for i in range(5)]
    for i, frame in enumerate(frames):  # MJPG is lossy, but each frame is closest to its own source (RGB)
        errors = [np.abs(frame.rgb.astype(int) - w.astype(int)).mean() for w in written]
        assert int(np.argmin(errors)) == i and errors[i] < 15
        assert errors[i] < np.abs(frame.rgb.astype(int) - written[i][..., ::-1].astype(int)).mean()
    assert list(source)[0].name == "frame_000000"  # iterating again starts over


def test_empty_folder(tmp_path):
    (tmp_path / "readme.txt").write_text("x")
    with pytest.raises(DataError, match=r"no images in this folder"):
        open_source(tmp_path)


def test_unreadable_image_in_folder_names_the_file(tmp_path):
    inference_data.write_images(tmp_path, 3)
    fakes.truncate(tmp_path / "img_01.png", 0.3)
    frames = iter(open_source(tmp_path))
    assert next(frames).name == "img_00"
    with pytest.raises(DataError, match=r"img_01\.png: truncated PNG.*replace the file"):
        next(frames)
    (tmp_path / "img_02.png").write_bytes(b"\x89PNG\r\n\x1a\n" + b"\0" * 30)
    with pytest.raises(DataError, match=r"img_02\.png"):
        list(open_source(tmp_path / "img_02.png"))


def test_bad_videos_and_paths(tmp_path):
    (tmp_path / "garbage.avi").write_bytes(np.random.default_rng(0).bytes(3000))
    with pytest.raises(DataError, match=r"garbage\.avi: cannot open video"):
        open_source(tmp_path / "garbage.avi")
    inference_data.write_video(tmp_path / "ok.avi", 3)
    data = (tmp_path / "ok.avi").read_bytes()
    (tmp_path / "cut.avi").write_bytes(data[: len(data) // 4])
    with pytest.raises(DataError, match=r"cut\.avi: cannot (open|decode) video"):
        open_source(tmp_path / "cut.avi")
    with pytest.raises(DataError, match="input not found"):
        open_source(tmp_path / "missing.png")
    (tmp_path / "model.pt").write_bytes(b"x")
    with pytest.raises(DataError, match=r"unsupported input type '\.pt'"):
        open_source(tmp_path / "model.pt")
