"""NYU Depth V2 raw video: ``<root>/<scene>/r-<timestamp>-<n>.ppm`` RGB frames (480×640, lens-distorted).

Only the RGB frames are read. The dump's depth (``d-*.pgm``), accelerometer (``a-*.dump``) and
``INDEX.txt`` files are recognised and left alone; any other ``r-*`` file with a malformed name is an
error, as is a scene folder without RGB frames.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from f2depth.camera import NYU_SIZE_HW
from f2depth.data.errors import DataError
from f2depth.data.images import read_image

RAW_RGB_RE = re.compile(r"^r-(\d+(?:\.\d+)?)-(\d+)\.ppm$")
SCENE_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_\-]*$")


@dataclass(frozen=True)
class RawFrame:
    """One RGB frame of a raw scene; ``index`` is its position in the scene sorted by timestamp."""

    scene: str
    index: int
    path: Path
    timestamp: float
    counter: int

    @property
    def stem(self) -> str:
        return self.path.stem


def _root(root: str | os.PathLike) -> Path:
    p = Path(root)
    if not p.is_dir():
        raise DataError(p, "NYU raw folder not found", "set data.nyu_raw in params.yaml to the folder of "
                        "scene folders (or run `dvc repro synth`)")
    return p


def list_scenes(root: str | os.PathLike) -> list[str]:
    """Sorted scene folder names under ``root``; hidden entries and plain files are not scenes."""
    r = _root(root)
    scenes = sorted(d.name for d in r.iterdir() if d.is_dir() and not d.name.startswith("."))
    for s in scenes:
        if SCENE_RE.match(s) is None:
            raise DataError(r / s, "scene folder name has characters other than letters, digits, '_' and '-'",
                            "rename it or move it out of the NYU raw folder")
    if not scenes:
        raise DataError(r, "no scene folders", "data.nyu_raw must hold <scene>/r-*.ppm folders")
    return scenes


def list_frames(root: str | os.PathLike, scene: str) -> list[RawFrame]:
    """The RGB frames of one scene, sorted by timestamp (then by the counter)."""
    d = _root(root) / scene
    if not d.is_dir():
        raise DataError(d, "scene folder not found", "check the scene name against data.nyu_raw")
    found = []
    for entry in d.iterdir():
        name = entry.name
        if not name.startswith("r-"):
            continue  # d-*.pgm, a-*.dump, INDEX.txt: parts of the raw dump that training does not use
        m = RAW_RGB_RE.match(name)
        if m is None or not entry.is_file():
            raise DataError(entry, "malformed RGB frame name (expected a file r-<timestamp>-<n>.ppm)",
                            "rename or remove it")
        found.append((float(m.group(1)), int(m.group(2)), entry))
    if not found:
        raise DataError(d, "scene folder holds no r-<timestamp>-<n>.ppm frames",
                        "remove the folder or copy its frames")
    found.sort(key=lambda t: (t[0], t[1]))
    for (t0, c0, p0), (t1, c1, _) in zip(found, found[1:]):
        if (t0, c0) == (t1, c1):
            raise DataError(p0, "two frames with the same timestamp and counter", "remove the duplicate")
    return [RawFrame(scene, i, p, t, c) for i, (t, c, p) in enumerate(found)]


def read_frame(path: str | os.PathLike) -> np.ndarray:
    """A raw RGB frame → RGB uint8 (480, 640, 3), still lens-distorted."""
    return read_image(path, expect_hw=NYU_SIZE_HW)
