"""The intrinsics of a user's video or image folder: a camera file, a field of view, or the EXIF focal length.

:func:`choose_camera` applies the order of docs/ingest.md: a camera file (our JSON/YAML, COLMAP's
``cameras.txt`` or an OpenCV calibration YAML) → ``fov`` (horizontal field of view in degrees) → the EXIF
``FocalLengthIn35mmFilm`` of the first image → the caller's ``fallback`` (ingest: self-calibration from the
video, :mod:`f2depth.ingest.selfcal`) → a :class:`~f2depth.data.errors.DataError` asking for one of the first
two. Every camera is at a stated resolution and must be the frames' (a camera file calibrated at
another size is refused, not rescaled: a crop on the way would make a rescaled K silently wrong).

Distortion is OpenCV's (k1, k2, p1, p2, k3), the model of ``cv2.undistort`` and of NYU's calibration.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import yaml

from f2depth.camera import RawCamera
from f2depth.data.errors import DataError
from f2depth.inference.outputs import intrinsics

#: The 35 mm film frame (36 × 24 mm): its diagonal is what "35 mm equivalent" focal lengths refer to.
FILM_DIAGONAL_MM = math.hypot(36.0, 24.0)
EXIF_IFD, EXIF_FOCAL_35MM = 0x8769, 0xA405
_FIX_FILE = ("a camera file holds fx, fy, cx, cy, width, height (and optionally dist: [k1, k2, p1, p2, k3]), "
             "or is COLMAP's cameras.txt or an OpenCV calibration YAML (docs/ingest.md)")
#: COLMAP camera models → (fx, fy, cx, cy, dist) from their parameter list (COLMAP's ``models.h``).
_COLMAP = {
    "SIMPLE_PINHOLE": lambda p: (p[0], p[0], p[1], p[2], []),
    "PINHOLE": lambda p: (p[0], p[1], p[2], p[3], []),
    "SIMPLE_RADIAL": lambda p: (p[0], p[0], p[1], p[2], [p[3]]),
    "RADIAL": lambda p: (p[0], p[0], p[1], p[2], [p[3], p[4]]),
    "OPENCV": lambda p: (p[0], p[1], p[2], p[3], [p[4], p[5], p[6], p[7]]),
    "FULL_OPENCV": None,  # rational model: not OpenCV's 5-coefficient one
}


def _camera(path: Path, fx, fy, cx, cy, width, height, dist, what: str) -> RawCamera:
    values = [fx, fy, cx, cy, width, height, *dist]
    try:
        numbers = [float(v) for v in values]
    except (TypeError, ValueError):
        raise DataError(path, f"non-numeric intrinsics {values}", _FIX_FILE) from None
    fx, fy, cx, cy, width, height = numbers[:6]
    if not all(math.isfinite(v) for v in numbers) or min(fx, fy, width, height) <= 0:
        raise DataError(path, f"intrinsics must be finite with fx, fy, width, height > 0, found {values}",
                        _FIX_FILE)
    if len(dist) > 5:
        raise DataError(path, f"{len(dist)} distortion coefficients; OpenCV's model has k1 k2 p1 p2 k3",
                        _FIX_FILE)
    coeffs = np.zeros(5)
    coeffs[:len(dist)] = numbers[6:]
    hw = (int(round(height)), int(round(width)))
    return RawCamera(intrinsics(*hw, fx=fx, fy=fy, cx=cx, cy=cy), coeffs, hw,
                  f"{what} {path}")


def _read_mapping(path: Path, data: dict) -> RawCamera:
    missing = [k for k in ("fx", "fy", "cx", "cy", "width", "height") if k not in data]
    if missing:
        raise DataError(path, f"no {', '.join(missing)}", _FIX_FILE)
    dist = data.get("dist", [])
    if not isinstance(dist, list):
        raise DataError(path, "dist must be a list [k1, k2, p1, p2, k3]", _FIX_FILE)
    return _camera(path, data["fx"], data["fy"], data["cx"], data["cy"], data["width"], data["height"], dist,
                   "camera file")


def _read_colmap(path: Path, text: str) -> RawCamera:
    rows = [line.split() for line in text.splitlines() if line.strip() and not line.lstrip().startswith("#")]
    if len(rows) != 1:
        raise DataError(path, f"COLMAP cameras.txt with {len(rows)} cameras; one video is one camera",
                        "keep the line of the camera that recorded this input")
    _, model, width, height, *params = rows[0]
    if model not in _COLMAP or _COLMAP[model] is None:
        raise DataError(path, f"COLMAP camera model {model} is not supported",
                        f"use one of {', '.join(k for k, v in _COLMAP.items() if v)}")
    try:
        fx, fy, cx, cy, dist = _COLMAP[model]([float(p) for p in params])
    except (ValueError, IndexError):
        raise DataError(path, f"COLMAP {model} camera with parameters {params}", _FIX_FILE) from None
    # COLMAP's pixel centres are at +0.5 (its image origin is a pixel's corner); ours at integers.
    return _camera(path, fx, fy, cx - 0.5, cy - 0.5, width, height, dist, "COLMAP cameras.txt")


def _read_opencv_yaml(path: Path) -> RawCamera:
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    try:
        K, dist = fs.getNode("camera_matrix").mat(), fs.getNode("distortion_coefficients").mat()
        width, height = fs.getNode("image_width").real(), fs.getNode("image_height").real()
    finally:
        fs.release()
    if K is None or K.shape != (3, 3) or not width or not height:
        raise DataError(path, "OpenCV calibration without camera_matrix (3×3), image_width and image_height",
                        _FIX_FILE)
    coeffs = [] if dist is None else dist.ravel().tolist()
    return _camera(path, K[0, 0], K[1, 1], K[0, 2], K[1, 2], width, height, coeffs, "OpenCV calibration")


def read_camera_file(path: str | os.PathLike) -> RawCamera:
    """A camera file → :class:`~f2depth.camera.RawCamera` (module docstring for the formats); anything else
    → DataError."""
    p = Path(path)
    if not p.is_file():
        raise DataError(p, "camera file not found", "check --camera")
    text = p.read_text(errors="replace")
    if text.lstrip().startswith("%YAML") or "camera_matrix" in text:
        return _read_opencv_yaml(p)
    if p.name.lower() == "cameras.txt" or text.lstrip().startswith("#") or (
            text.split() and text.split()[1:2] and text.split()[1] in _COLMAP):
        return _read_colmap(p, text)
    try:
        data = json.loads(text) if p.suffix.lower() == ".json" else yaml.safe_load(text)
    except (json.JSONDecodeError, yaml.YAMLError) as exc:
        raise DataError(p, f"not valid JSON/YAML ({' '.join(str(exc).split())[:120]})", _FIX_FILE) from None
    if not isinstance(data, dict):
        raise DataError(p, "not a mapping of fx, fy, cx, cy, width, height", _FIX_FILE)
    return _read_mapping(p, data)


def from_fov(fov_deg: float, hw: tuple[int, int]) -> RawCamera:
    """Square pixels, the principal point at the centre, horizontal field of view ``fov_deg``."""
    if not 1.0 <= fov_deg <= 179.0:
        raise DataError(Path("--fov"), f"{fov_deg}° is not a horizontal field of view", "give 1–179 degrees")
    h, w = hw
    f = (w / 2) / math.tan(math.radians(fov_deg) / 2)
    return RawCamera(intrinsics(h, w, fx=f), np.zeros(5), hw, f"--fov {fov_deg:g}°")


def focal_35mm(path: str | os.PathLike) -> float | None:
    """The EXIF ``FocalLengthIn35mmFilm`` of an image in mm, or None when it has none."""
    from PIL import Image

    try:
        with Image.open(path) as im:
            value = im.getexif().get_ifd(EXIF_IFD).get(EXIF_FOCAL_35MM)
    except (OSError, ValueError, SyntaxError):
        return None
    try:
        return float(value) if value and float(value) > 0 else None
    except (TypeError, ValueError):
        return None


def from_exif(path: str | os.PathLike, hw: tuple[int, int]) -> RawCamera | None:
    """The camera of an image with an EXIF 35 mm-equivalent focal length (square pixels, centred principal
    point; the equivalence is over the diagonal, as the EXIF standard defines it), or None."""
    f35 = focal_35mm(path)
    if f35 is None:
        return None
    h, w = hw
    f = f35 * math.hypot(w, h) / FILM_DIAGONAL_MM
    return RawCamera(intrinsics(h, w, fx=f), np.zeros(5), hw,
                  f"EXIF FocalLengthIn35mmFilm {f35:g} mm of {path}")


def check_resolution(camera: RawCamera, hw: tuple[int, int], where: str | os.PathLike) -> None:
    """A camera must be at the frames' resolution (a rotated video: the resolution after rotation)."""
    if tuple(camera.hw) != tuple(hw):
        raise DataError(Path(where), f"frames are {hw[1]}×{hw[0]} but the camera ({camera.source}) is "
                        f"{camera.hw[1]}×{camera.hw[0]}",
                        "give the calibration of this resolution (or --fov); a rescaled K would be "
                        "wrong after any crop")


def choose_camera(hw: tuple[int, int], first_file: Path, camera_file: str | os.PathLike | None = None,
                  fov: float | None = None, fallback: Callable[[], RawCamera] | None = None) -> RawCamera:
    """The intrinsics of frames of size ``hw`` (module docstring): camera file, ``fov``, EXIF of
    ``first_file`` (the first image of a folder; videos carry none), ``fallback()``, else DataError."""
    if camera_file is not None:
        camera = read_camera_file(camera_file)
        check_resolution(camera, hw, first_file)
        return camera
    if fov is not None:
        return from_fov(fov, hw)
    camera = from_exif(first_file, hw)
    if camera is not None:
        return camera
    if fallback is not None:
        return fallback()
    raise DataError(first_file, "unknown intrinsics: no camera file, no --fov and no EXIF 35 mm focal length",
                    "give --camera FILE (docs/ingest.md) or --fov DEG (a phone's main camera: about 65–75)")
