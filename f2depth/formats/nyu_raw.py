"""NYU Depth V2 raw video: ``<root>/<scene>/r-<timestamp>-<n>.ppm`` RGB frames (480×640, lens-distorted).

The same layout holds a user's video after ``f2depth ingest`` (docs/ingest.md): ``.png`` frames and a
``<root>/camera.json`` with their intrinsics (:func:`raw_camera`); without that file the frames are NYU's.
Only the RGB frames are read. The dump's depth (``d-*.pgm``), accelerometer (``a-*.dump``) and
``INDEX.txt`` files are recognised and left alone; any other ``r-*`` file with a malformed name is an
error, as is a scene folder without RGB frames.
"""

from __future__ import annotations

import json
import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from f2depth.camera import NYU_RAW_CAMERA, NYU_SIZE_HW, RawCamera
from f2depth.errors import DataError
from f2depth.formats.images import read_image

RAW_RGB_RE = re.compile(r"^r-(\d+(?:\.\d+)?)-(\d+)\.(?:ppm|png)$")
CAMERA_FILE = "camera.json"  # of an ingested folder: RawCamera.to_json
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
            raise DataError(entry, "malformed RGB frame name (expected a file r-<timestamp>-<n>.ppm or .png)",
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


def read_frame(path: str | os.PathLike, hw: tuple[int, int] = NYU_SIZE_HW) -> np.ndarray:
    """A raw RGB frame → RGB uint8 ``hw + (3,)`` (NYU's: (480, 640, 3), still lens-distorted)."""
    return read_image(path, expect_hw=hw)


def raw_camera(root: str | os.PathLike) -> RawCamera:
    """The camera of the frames under ``root``: its ``camera.json`` (written by ``f2depth ingest``) or,
    without one, NYU Depth V2's RGB calibration."""
    path = _root(root) / CAMERA_FILE
    if not path.is_file():
        return NYU_RAW_CAMERA
    fix = "re-run `f2depth ingest` (docs/ingest.md) or remove the file for NYU raw data"
    try:
        cam = json.loads(path.read_text())
        K = np.asarray(cam["K"], dtype=np.float64)
        dist = np.asarray(cam.get("dist", [0.0] * 5), dtype=np.float64)
        hw = (int(cam["height"]), int(cam["width"]))
    except (json.JSONDecodeError, KeyError, TypeError, ValueError) as exc:
        raise DataError(path, f"unreadable camera file ({type(exc).__name__}: {exc})", fix) from None
    if K.shape != (3, 3) or dist.shape != (5,) or not np.all(np.isfinite(K)) or min(hw) < 1:
        raise DataError(path, "K must be a finite 3×3 matrix, dist 5 OpenCV coefficients, height and width "
                        "positive", fix)
    return RawCamera(K, dist, hw, str(cam.get("intrinsics_source", path)))
