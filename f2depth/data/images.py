"""Reading image files with validation: missing, unreadable, truncated or wrongly sized → DataError.

OpenCV decodes a truncated JPEG without complaint (grey rows at the bottom), so before decoding the
bytes are checked against what the format's own header promises: the PNM payload size, the PNG chunk
chain up to ``IEND``, the JPEG end-of-image marker.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import cv2
import numpy as np

from f2depth.data.errors import DataError
from f2depth.io import imwrite

_FIX_REPLACE = "re-copy the file from the original dataset (or regenerate it with `dvc repro synth`)"
_PNM_TOKEN = re.compile(rb"\s*(?:#[^\n]*\n\s*)*(\S+)")


def read_bytes(path: str | os.PathLike, what: str = "file") -> bytes:
    """The whole file; a missing path or a folder → DataError."""
    p = Path(path)
    if not p.exists():
        raise DataError(p, f"{what} not found", "check the data paths in params.yaml (data.*)")
    if not p.is_file():
        raise DataError(p, f"expected a {what}, found a folder")
    try:
        return p.read_bytes()
    except OSError as exc:
        raise DataError(p, f"cannot read {what} ({exc.strerror})", "check its permissions") from exc


def _check_pnm(path: Path, data: bytes) -> None:
    pos, tokens = 2, []
    while len(tokens) < (2 if data[:2] in (b"P1", b"P4") else 3):
        m = _PNM_TOKEN.match(data, pos)
        if m is None:
            raise DataError(path, "truncated PNM header", _FIX_REPLACE)
        tokens.append(m.group(1))
        pos = m.end()
    try:
        w, h, *rest = (int(t) for t in tokens)
    except ValueError as exc:
        raise DataError(path, f"malformed PNM header {tokens!r}", _FIX_REPLACE) from exc
    if data[:2] not in (b"P5", b"P6"):
        return  # ASCII / bitmap PNM: no fixed payload size to check, leave it to the decoder
    channels = 3 if data[:2] == b"P6" else 1
    depth_bytes = 2 if rest[0] > 255 else 1
    need = pos + 1 + w * h * channels * depth_bytes  # exactly one whitespace after maxval
    if len(data) < need:
        raise DataError(
            path, f"truncated: {len(data)} bytes, its {w}×{h} header needs {need}", _FIX_REPLACE
        )


def _check_png(path: Path, data: bytes) -> None:
    pos = 8
    while True:
        if pos + 12 > len(data):
            raise DataError(path, f"truncated PNG: chunk chain ends at byte {len(data)} before IEND",
                            _FIX_REPLACE)
        length = int.from_bytes(data[pos:pos + 4], "big")
        ctype = data[pos + 4:pos + 8]
        end = pos + 12 + length
        if end > len(data):
            raise DataError(path, f"truncated PNG: chunk {ctype!r} needs {end} bytes, file has {len(data)}",
                            _FIX_REPLACE)
        if ctype == b"IEND":
            return
        pos = end


def _check_jpeg(path: Path, data: bytes) -> None:
    if not data.rstrip(b"\x00\r\n ").endswith(b"\xff\xd9"):
        raise DataError(path, "truncated JPEG: no end-of-image marker (FF D9) at the end", _FIX_REPLACE)


def check_complete(path: str | os.PathLike, data: bytes) -> None:
    """Raise DataError when ``data`` (the bytes of ``path``) is shorter than its format header promises."""
    p = Path(path)
    if len(data) == 0:
        raise DataError(p, "empty file", _FIX_REPLACE)
    if data[:2] in (b"P1", b"P2", b"P3", b"P4", b"P5", b"P6"):
        _check_pnm(p, data)
    elif data[:8] == b"\x89PNG\r\n\x1a\n":
        _check_png(p, data)
    elif data[:2] == b"\xff\xd8":
        _check_jpeg(p, data)


def _decode(path: Path, data: bytes, flags: int) -> np.ndarray:
    check_complete(path, data)
    img = cv2.imdecode(np.frombuffer(data, np.uint8), flags)
    if img is None:
        raise DataError(path, "unreadable image (OpenCV cannot decode it)", _FIX_REPLACE)
    return img


def _check_size(path: Path, img: np.ndarray, expect_hw: tuple[int, int] | None) -> None:
    if expect_hw is not None and tuple(img.shape[:2]) != tuple(expect_hw):
        raise DataError(
            path,
            f"image is {img.shape[0]}×{img.shape[1]} (H×W), expected {expect_hw[0]}×{expect_hw[1]}",
            "all images of this dataset must have the same size",
        )


def read_image(path: str | os.PathLike, expect_hw: tuple[int, int] | None = None) -> np.ndarray:
    """Colour image → RGB uint8 (H, W, 3); grey files are expanded to three channels."""
    p = Path(path)
    img = _decode(p, read_bytes(p, "image"), cv2.IMREAD_COLOR)
    _check_size(p, img, expect_hw)
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def read_png16(path: str | os.PathLike, expect_hw: tuple[int, int] | None = None) -> np.ndarray:
    """Single-channel 16-bit PNG (depth maps, segment labels) → uint16 (H, W)."""
    p = Path(path)
    img = _decode(p, read_bytes(p, "image"), cv2.IMREAD_UNCHANGED)
    if img.ndim != 2 or img.dtype != np.uint16:
        raise DataError(p, f"expected a single-channel 16-bit image, found {img.dtype} with shape "
                           f"{img.shape}", _FIX_REPLACE)
    _check_size(p, img, expect_hw)
    return img


def write_rgb(path: str | os.PathLike, rgb: np.ndarray) -> None:
    """Write an RGB uint8 (H, W, 3) image atomically (PNG/JPEG by extension)."""
    imwrite(path, cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
