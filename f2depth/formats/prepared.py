"""Reader of the prepared training set (``data/prepared/``, written by the ``prepare`` stage).

``PreparedSet(root)`` validates the tables at construction (headers, unique ids, references between
them, every referenced file present) and each image, ground-truth and segment file when it is read
(size equal to ``camera.json``'s height × width).

:func:`prepare_image` is how a raw frame becomes one of its images (undistort, crop, resize), the steps the
``prepare`` stage, ``f2depth ingest`` and the keypoints' full-resolution source share.
"""

from __future__ import annotations

import csv
import json
import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from f2depth.camera import NYU_RAW_CAMERA, RawCamera, undistort_image
from f2depth.errors import DataError
from f2depth.formats.images import read_image, read_png16, resize_rgb

FRAMES_HEADER = ["frame_id", "scene", "raw_file", "image", "gt"]
TUPLES_HEADER = ["tuple_id", "scene", "target", "prev", "next", "segments"]
PAIRS_HEADER = ["pair_id", "scene", "frame1", "frame2"]
#: The held-out tuples (``prepare.val_share``; format of tuples.csv). Sets made before it existed have none.
VAL_TUPLES = "val_tuples.csv"
_FIX = "re-run `dvc repro prepare`"


@dataclass(frozen=True)
class FrameRecord:
    frame_id: str
    scene: str
    raw_file: str
    image: str
    gt: str  # "" without ground truth


@dataclass(frozen=True)
class TupleRecord:
    tuple_id: str
    scene: str
    target: str
    prev: str
    next: str
    segments: str


@dataclass(frozen=True)
class PairRecord:
    pair_id: str
    scene: str
    frame1: str
    frame2: str


def _read_table(path: Path, header: list[str]) -> list[list[str]]:
    if not path.is_file():
        raise DataError(path, "not found", _FIX)
    with path.open(newline="") as fh:
        rows = list(csv.reader(fh))
    if not rows or rows[0] != header:
        raise DataError(path, f"header is {rows[0] if rows else None}, expected {','.join(header)}", _FIX)
    for n, row in enumerate(rows[1:], 2):
        if len(row) != len(header):
            raise DataError(path, f"row {n} has {len(row)} columns, expected {len(header)}", _FIX)
    return rows[1:]


class PreparedSet:
    """Frames, tuples, held-out tuples and pairs of a prepared set, with loaders for images, GT, K and
    segments."""

    def __init__(self, root: str | os.PathLike):
        self.root = Path(root)
        if not self.root.is_dir():
            raise DataError(self.root, "prepared set not found", "run `dvc repro prepare` (data.prepared)")
        self.camera = self._read_camera(self.root / "camera.json")
        self.height, self.width = int(self.camera["height"]), int(self.camera["width"])
        self.K = np.asarray(self.camera["K"], dtype=np.float64)
        self.frames = [FrameRecord(*r) for r in _read_table(self.root / "frames.csv", FRAMES_HEADER)]
        self.tuples = [TupleRecord(*r) for r in _read_table(self.root / "tuples.csv", TUPLES_HEADER)]
        val = self.root / VAL_TUPLES
        self.val_tuples = [TupleRecord(*r) for r in _read_table(val, TUPLES_HEADER)] if val.is_file() else []
        self.pairs = [PairRecord(*r) for r in _read_table(self.root / "pairs.csv", PAIRS_HEADER)]
        self._frame_index = self._index(self.frames, "frame_id", self.root / "frames.csv")
        self._index(self.tuples, "tuple_id", self.root / "tuples.csv")
        self._all_tuples = self.tuples + self.val_tuples
        self._tuple_index = self._index(self._all_tuples, "tuple_id", self.root / VAL_TUPLES)
        self._check_references()

    @staticmethod
    def _read_camera(path: Path) -> dict:
        if not path.is_file():
            raise DataError(path, "not found", _FIX)
        try:
            cam = json.loads(path.read_text())
        except json.JSONDecodeError as exc:
            raise DataError(path, f"not valid JSON ({exc})", _FIX) from exc
        for key in ("K", "height", "width"):
            if key not in cam:
                raise DataError(path, f"no '{key}'", _FIX)
        K = np.asarray(cam["K"], dtype=np.float64)
        if K.shape != (3, 3) or not np.all(np.isfinite(K)) or int(cam["height"]) < 1 or int(cam["width"]) < 1:
            raise DataError(path, "K must be a finite 3×3 matrix and height, width positive", _FIX)
        return cam

    @staticmethod
    def _index(records: list, key: str, path: Path) -> dict[str, int]:
        index: dict[str, int] = {}
        for i, r in enumerate(records):
            k = getattr(r, key)
            if k in index:
                raise DataError(path, f"{key} {k!r} appears twice", _FIX)
            index[k] = i
        return index

    def _check_references(self) -> None:
        for f in self.frames:
            for rel in (f.image, f.gt):
                if rel and not (self.root / rel).is_file():
                    raise DataError(self.root / rel, f"listed for frame {f.frame_id} in frames.csv, missing",
                                    _FIX)
        for table, rows in (("tuples.csv", self.tuples), (VAL_TUPLES, self.val_tuples)):
            for t in rows:
                for fid in (t.target, t.prev, t.next):
                    if fid not in self._frame_index:
                        raise DataError(self.root / table, f"tuple {t.tuple_id}: unknown frame {fid!r}", _FIX)
        train_frames = {f for t in self.tuples for f in (t.target, t.prev, t.next)}
        for t in self.val_tuples:
            if shared := train_frames & {t.target, t.prev, t.next}:
                raise DataError(self.root / VAL_TUPLES, f"held-out tuple {t.tuple_id}: frame {min(shared)} "
                                "is in a training tuple", _FIX)
        for t in self._all_tuples:
            if not (self.root / t.segments).is_file():
                raise DataError(self.root / t.segments, f"segments of tuple {t.tuple_id} missing", _FIX)
        for p in self.pairs:
            for fid in (p.frame1, p.frame2):
                if fid not in self._frame_index:
                    raise DataError(self.root / "pairs.csv", f"pair {p.pair_id}: unknown frame {fid!r}",
                                    _FIX)

    # ---- lookups ----------------------------------------------------------------------------------
    @property
    def hw(self) -> tuple[int, int]:
        return self.height, self.width

    @property
    def crop(self) -> int:
        """Pixels prepare cut from every side of the undistorted raw frame (camera.json ``crop``)."""
        path = self.root / "camera.json"
        try:
            crop = int(self.camera["crop"])
        except (KeyError, TypeError, ValueError):
            raise DataError(path, "no integer 'crop'", _FIX) from None
        if crop < 0:
            raise DataError(path, f"crop {crop} is negative", _FIX)
        return crop

    @property
    def interpolation(self) -> str:
        """The filter prepare shrank the images with (camera.json ``interpolation``; sets made before the
        key existed used ``area``)."""
        return str(self.camera.get("interpolation", "area"))

    @property
    def source_camera(self) -> RawCamera:
        """The camera of the raw frames the set was made from (camera.json ``source_*``; sets made before
        these keys were recorded are NYU's)."""
        cam = self.camera
        if "source_K" not in cam:
            return NYU_RAW_CAMERA
        try:
            return RawCamera(np.asarray(cam["source_K"], dtype=np.float64).reshape(3, 3),
                             np.asarray(cam["source_dist"], dtype=np.float64).reshape(5),
                             (int(cam["source_height"]), int(cam["source_width"])),
                             str(cam.get("intrinsics_source", "NYU Depth V2 RGB calibration")))
        except (KeyError, TypeError, ValueError) as exc:
            raise DataError(self.root / "camera.json", f"bad source camera ({exc})", _FIX) from None

    def raw_path(self, frame_id: str, nyu_raw: str | os.PathLike) -> Path:
        """The NYU raw frame a prepared frame was made from: ``nyu_raw / raw_file`` (not checked)."""
        return Path(nyu_raw) / self.frame(frame_id).raw_file

    def frame(self, frame_id: str) -> FrameRecord:
        try:
            return self.frames[self._frame_index[frame_id]]
        except KeyError:
            raise KeyError(f"frame {frame_id!r} is not in {self.root / 'frames.csv'}") from None

    def frame_index(self, frame_id: str) -> int:
        """Row of ``frame_id`` in frames.csv (the integer frame id of the keypoint files)."""
        self.frame(frame_id)
        return self._frame_index[frame_id]

    def tuple(self, tuple_id: str) -> TupleRecord:
        """A training or held-out tuple by id."""
        try:
            return self._all_tuples[self._tuple_index[tuple_id]]
        except KeyError:
            raise KeyError(f"tuple {tuple_id!r} is in neither tuples.csv nor {VAL_TUPLES} of "
                           f"{self.root}") from None

    # ---- data -------------------------------------------------------------------------------------
    def image(self, frame_id: str) -> np.ndarray:
        """RGB uint8 (H, W, 3) at the training size."""
        return read_image(self.root / self.frame(frame_id).image, self.hw)

    def has_gt(self, frame_id: str) -> bool:
        return bool(self.frame(frame_id).gt)

    def gt(self, frame_id: str) -> tuple[np.ndarray, np.ndarray] | None:
        """(depth float32 (H, W) m, 0 = invalid; world_T_cam (4, 4)) or None for real data."""
        rel = self.frame(frame_id).gt
        if not rel:
            return None
        path = self.root / rel
        try:
            with np.load(path) as z:
                depth, pose = z["depth"], z["world_T_cam"]
        except (OSError, ValueError, KeyError, EOFError) as exc:
            raise DataError(path, f"unreadable ground truth ({exc})", _FIX) from exc
        if depth.shape != self.hw or pose.shape != (4, 4):
            raise DataError(path, f"depth {depth.shape} / pose {pose.shape}, expected {self.hw} / (4, 4)",
                            _FIX)
        return depth.astype(np.float32), pose.astype(np.float64)

    def segments(self, tuple_id: str) -> np.ndarray:
        """Felzenszwalb labels of the tuple's target, int64 (H, W), 0-based."""
        return read_png16(self.root / self.tuple(tuple_id).segments, self.hw).astype(np.int64)


# ---- a prepared image: how a raw frame becomes one (the prepare stage, f2depth ingest, keypoints) -----

def crop_border(image: np.ndarray, crop: int) -> np.ndarray:
    """Cut ``crop`` px from every side of an (H, W[, C]) array (a view)."""
    h, w = image.shape[:2]
    if crop < 0 or 2 * crop >= min(h, w):
        raise ValueError(f"crop {crop} leaves nothing of a {h}×{w} image")
    return image[crop:h - crop, crop:w - crop]


def resize_image(image: np.ndarray, hw: tuple[int, int], nearest: bool = False,
                 interpolation: str = "area") -> np.ndarray:
    """Resize an (H, W[, C]) array to ``hw`` as prepare does.

    Images: ``interpolation`` ``lanczos`` (PIL, uint8 RGB, as P²Net) or ``area`` (``INTER_AREA`` when
    shrinking, bilinear otherwise). ``nearest=True`` (depth): exact nearest-neighbour on pixel centres
    (``INTER_NEAREST_EXACT``; plain ``INTER_NEAREST`` is offset by up to half a source pixel, which would
    misalign depth and image).
    """
    if interpolation == "lanczos" and not nearest:
        return resize_rgb(image, hw, "lanczos")
    if nearest:
        interp = cv2.INTER_NEAREST_EXACT
    elif hw[0] <= image.shape[0] and hw[1] <= image.shape[1]:
        interp = cv2.INTER_AREA
    else:
        interp = cv2.INTER_LINEAR
    return cv2.resize(np.ascontiguousarray(image), (hw[1], hw[0]), interpolation=interp)


def undistort_crop(raw_rgb: np.ndarray, crop: int, camera: RawCamera = NYU_RAW_CAMERA) -> np.ndarray:
    """Distorted raw frame (``camera.hw``, 3) → undistorted RGB uint8 with ``crop`` px cut from every side,
    at full resolution (NYU: (448, 608, 3) for crop 16): the image P²Net selects its keypoints on (its
    ``datasets/nyu_dataset.py``). A camera without distortion (an ingested video) is only cropped."""
    if raw_rgb.shape[:2] != tuple(camera.hw):
        raise ValueError(f"a {raw_rgb.shape[:2]} frame for a camera of {camera.hw}")
    undistorted = undistort_image(raw_rgb, camera.K, camera.dist) if np.any(camera.dist) else raw_rgb
    return crop_border(undistorted, crop)


def prepare_image(raw_rgb: np.ndarray, crop: int, hw: tuple[int, int], interpolation: str = "area",
                  camera: RawCamera = NYU_RAW_CAMERA) -> np.ndarray:
    """Distorted raw frame (``camera.hw``, 3) → undistorted, cropped, resized RGB uint8 (H, W, 3)."""
    return resize_image(undistort_crop(raw_rgb, crop, camera), hw, interpolation=interpolation)
