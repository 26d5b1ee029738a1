"""The intrinsics of a user's video or image folder: a camera file, a field of view, or the EXIF focal length.

:func:`choose_camera` applies the order of docs/ingest.md: a camera file (our JSON/YAML, COLMAP's
``cameras.txt`` or an OpenCV calibration YAML) → ``fov`` (horizontal field of view in degrees) → the EXIF
``FocalLengthIn35mmFilm`` of the first image → the caller's ``fallback`` (ingest: self-calibration from the
video, :mod:`f2depth.ingest.selfcal`) → a :class:`~f2depth.errors.DataError` asking for one of the first
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

from f2depth.camera import RawCamera, intrinsics, undistorted_valid_share
from f2depth.errors import DataError
from f2depth.params import BoundedLoader, YamlBomb, load_yaml, short

#: The 35 mm film frame (36 × 24 mm): its diagonal is what "35 mm equivalent" focal lengths refer to.
FILM_DIAGONAL_MM = math.hypot(36.0, 24.0)
#: A camera file's fx and fy must lie within these multiples of the image width (horizontal fields of view
#: of about 157° to 6°): outside, the file is not this video's camera.
FOCAL_PER_WIDTH = (0.1, 10.0)
#: At least this share of an undistorted frame must come from inside the recorded frame (the rest is black).
MIN_VALID_SHARE = 0.5
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
    if len(dist) > 5:
        raise DataError(path, f"{len(dist)} distortion coefficients; OpenCV's model has k1 k2 p1 p2 k3",
                        _FIX_FILE)
    try:
        numbers = [float(v) for v in values]
    except (TypeError, ValueError):
        raise DataError(path, f"non-numeric intrinsics {short(values)}", _FIX_FILE) from None
    fx, fy, cx, cy, width, height = numbers[:6]
    if not all(math.isfinite(v) for v in numbers) or min(fx, fy, width, height) <= 0:
        raise DataError(path, f"intrinsics must be finite with fx, fy, width, height > 0, found "
                        f"{short(values)}", _FIX_FILE)
    coeffs = np.zeros(5)
    coeffs[:len(dist)] = numbers[6:]
    hw = (int(round(height)), int(round(width)))
    camera = RawCamera(intrinsics(*hw, fx=fx, fy=fy, cx=cx, cy=cy), coeffs, hw, f"{what} {path}")
    check_plausible(camera, path)
    return camera


def check_plausible(camera: RawCamera, path: str | os.PathLike) -> None:
    """Refuse a camera no lens has (DataError naming the file): the principal point outside the image, fx
    or fy outside :data:`FOCAL_PER_WIDTH` × the width, or a distortion that leaves less than
    :data:`MIN_VALID_SHARE` of an undistorted frame inside the recorded one (a k1 of 1e6 makes every frame
    black)."""
    (h, w), K = camera.hw, camera.K
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    if not (-0.5 <= cx <= w - 0.5 and -0.5 <= cy <= h - 0.5):
        raise DataError(path, f"principal point ({cx:g}, {cy:g}) px lies outside the {w}×{h} image",
                        "give cx, cy in pixels of this resolution (about the image centre)")
    lo, hi = (k * w for k in FOCAL_PER_WIDTH)
    if not (lo <= fx <= hi and lo <= fy <= hi):
        raise DataError(path, f"focal length fx {fx:g}, fy {fy:g} px is outside {lo:g}–{hi:g} px "
                        f"({FOCAL_PER_WIDTH[0]:g}–{FOCAL_PER_WIDTH[1]:g} × the width {w})",
                        "give fx, fy in pixels of this resolution, or --fov DEG")
    if np.any(camera.dist):
        share = undistorted_valid_share(K, camera.dist, camera.hw)
        if share < MIN_VALID_SHARE:
            raise DataError(path, f"distortion {short(camera.dist.tolist())} leaves only {100 * share:.0f} % "
                            f"of an undistorted frame inside the recorded one (at least "
                            f"{100 * MIN_VALID_SHARE:.0f} %)", "check the coefficients' order and units "
                            "(OpenCV's k1 k2 p1 p2 k3) or give --fov DEG")


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
    try:  # a damaged file: cv2.error, or SystemError from the binding
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
        try:
            K, dist = fs.getNode("camera_matrix").mat(), fs.getNode("distortion_coefficients").mat()
            width, height = fs.getNode("image_width").real(), fs.getNode("image_height").real()
        finally:
            fs.release()
    except (cv2.error, SystemError) as exc:
        text = " ".join(str(exc).split())
        raise DataError(path, f"OpenCV cannot read this calibration file ({short(text, 120)})",
                        _FIX_FILE) from None
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
    if text.lstrip().startswith("%YAML:"):  # the header cv2.FileStorage writes
        return _read_opencv_yaml(p)
    rows = [line.split() for line in text.splitlines() if line.strip() and not line.lstrip().startswith("#")]
    if p.name.lower() == "cameras.txt" or (rows and rows[0][1:2] and rows[0][1] in _COLMAP):
        return _read_colmap(p, text)
    try:  # the format is what the file holds, not a word in it (a comment may say "camera_matrix")
        data = json.loads(text) if p.suffix.lower() == ".json" else load_yaml(text, _CameraLoader)
    except YamlBomb as bomb:
        raise DataError(p, bomb.problem, _FIX_FILE) from None
    except (json.JSONDecodeError, yaml.YAMLError) as exc:
        raise DataError(p, f"not valid JSON/YAML ({short(' '.join(str(exc).split()), 120)})",
                        _FIX_FILE) from None
    if not isinstance(data, dict):
        raise DataError(p, "not a mapping of fx, fy, cx, cy, width, height", _FIX_FILE)
    if "camera_matrix" in data:  # an OpenCV calibration without its %YAML header
        return _read_opencv_yaml(p)
    return _read_mapping(p, data)


class _CameraLoader(BoundedLoader):
    """:class:`~f2depth.params.BoundedLoader` that also reads OpenCV's ``!!opencv-matrix`` values (as
    mappings), so that an OpenCV calibration is recognised by its keys."""


_CameraLoader.add_constructor("tag:yaml.org,2002:opencv-matrix", BoundedLoader.construct_mapping)


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
        check_plausible(camera, first_file)  # an EXIF focal length of 1 mm is no camera's either
        return camera
    if fallback is not None:
        return fallback()
    raise DataError(first_file, "unknown intrinsics: no camera file, no --fov and no EXIF 35 mm focal length",
                    "give --camera FILE (docs/ingest.md) or --fov DEG (a phone's main camera: about 65–75)")
