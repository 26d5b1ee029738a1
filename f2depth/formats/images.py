"""Reading image files with validation: missing, unreadable, truncated or wrongly sized → DataError.

OpenCV decodes a truncated JPEG without complaint (grey rows at the bottom), so before decoding the
bytes are checked against what the format's own header promises: the PNM payload size, the PNG chunk
chain up to ``IEND``, the JPEG end-of-image marker.

The image size is read from the header before anything is decoded (PNG ``IHDR``, the JPEG frame header,
the PNM header; other formats through Pillow's lazy ``Image.open``), and images of more than
:data:`MAX_PIXELS` (100 megapixels) are refused: a header may claim any size (100000×100000 is 30 GB of
RGB), and the depth pipeline keeps several full-size float copies of every image.
"""

from __future__ import annotations

import io
import os
import re
import warnings
from pathlib import Path

import cv2
import numpy as np
import torch
from PIL import Image

from f2depth.errors import DataError

_FIX_REPLACE = "re-copy the file from the original dataset (or regenerate it with `dvc repro synth`)"
_PNM_TOKEN = re.compile(rb"\s*(?:#[^\n]*\n\s*)*(\S+)")
#: largest image (height × width) that is decoded; larger ones are refused from their header
MAX_PIXELS = 100_000_000
#: JPEG start-of-frame markers (SOF0..SOF15 without DHT C4, JPG C8 and DAC CC): they carry the size
_JPEG_SOF = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}


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


def _pnm_header(path: Path, data: bytes) -> tuple[int, int, list[int], int]:
    """(width, height, [maxval], offset after the header tokens) of a PNM file."""
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
    return w, h, rest, pos


def _check_pnm(path: Path, data: bytes) -> None:
    w, h, rest, pos = _pnm_header(path, data)
    if data[:2] not in (b"P5", b"P6"):
        return  # ASCII / bitmap PNM: no fixed payload size to check, leave it to the decoder
    channels = 3 if data[:2] == b"P6" else 1
    depth_bytes = 2 if rest[0] > 255 else 1
    need = pos + 1 + w * h * channels * depth_bytes  # exactly one whitespace after maxval
    if len(data) < need:
        raise DataError(path, f"truncated: {len(data)} bytes, its {w}×{h} header needs {need}", _FIX_REPLACE)


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


def _jpeg_hw(data: bytes) -> tuple[int, int] | None:
    """(height, width) from the first start-of-frame segment of a JPEG; None if there is none."""
    pos = 2
    while pos + 4 <= len(data):
        if data[pos] != 0xFF:
            return None  # not at a marker: a damaged stream, left to the decoder
        marker = data[pos + 1]
        if marker == 0xFF:  # fill byte
            pos += 1
            continue
        if marker in (0x01, *range(0xD0, 0xD8)):  # markers without a length
            pos += 2
            continue
        if marker in (0xD9, 0xDA):  # end of image / start of scan before any frame header
            return None
        if marker in _JPEG_SOF:
            if pos + 9 > len(data):
                return None
            return int.from_bytes(data[pos + 5:pos + 7], "big"), int.from_bytes(data[pos + 7:pos + 9], "big")
        pos += 2 + int.from_bytes(data[pos + 2:pos + 4], "big")
    return None


def header_hw(path: str | os.PathLike, data: bytes) -> tuple[int, int] | None:
    """(height, width) that the header of image bytes ``data`` claims, without decoding the pixels.

    PNG, JPEG and PNM headers are parsed here, other formats by Pillow's lazy ``Image.open``; None when
    the format is not recognised (the decoder then decides). A header that claims more than Pillow's
    decompression-bomb limit → DataError.
    """
    if data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) >= 24 and data[12:16] == b"IHDR":
        return int.from_bytes(data[20:24], "big"), int.from_bytes(data[16:20], "big")
    if data[:2] == b"\xff\xd8":
        return _jpeg_hw(data)
    if data[:2] in (b"P1", b"P2", b"P3", b"P4", b"P5", b"P6"):
        w, h, _, _ = _pnm_header(Path(path), data)
        return h, w
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", Image.DecompressionBombWarning)
        try:
            with Image.open(io.BytesIO(data)) as im:
                w, h = im.size
        except Image.DecompressionBombError as exc:
            raise DataError(path, f"image too large ({exc})", "use an image of at most "
                                  f"{MAX_PIXELS // 1_000_000} megapixels") from None
        except (OSError, SyntaxError, ValueError):  # Pillow cannot read it: leave it to OpenCV
            return None
    return h, w


def check_pixels(path: str | os.PathLike, data: bytes, max_pixels: int = MAX_PIXELS) -> None:
    """Raise DataError when the header of ``data`` claims an empty image or one of more than
    ``max_pixels`` pixels (checked before decoding, so a forged header costs nothing)."""
    hw = header_hw(path, data)
    if hw is None:
        return
    h, w = hw
    if h <= 0 or w <= 0:
        raise DataError(path, f"its header claims an empty image ({w}×{h})", _FIX_REPLACE)
    if h * w > max_pixels:
        raise DataError(path, f"its header claims {w}×{h} pixels ({h * w / 1e6:.0f} megapixels), more than "
                              f"the {max_pixels / 1e6:g} megapixels f2depth decodes",
                        "downscale the image (or check that the file is not damaged)")


def decode(path: str | os.PathLike, data: bytes, flags: int = cv2.IMREAD_COLOR) -> np.ndarray:
    """Image bytes, checked to be complete (:func:`check_complete`) and of a decodable size
    (:func:`check_pixels`) → OpenCV's array (BGR for colour); anything OpenCV refuses → DataError."""
    p = Path(path)
    check_complete(p, data)
    check_pixels(p, data)
    try:
        img = cv2.imdecode(np.frombuffer(data, np.uint8), flags)
    except cv2.error as exc:  # e.g. its own pixel limit for formats whose header is not read here
        detail = " ".join(str(exc).split())[-160:]
        raise DataError(p, f"unreadable image (OpenCV: {detail})", _FIX_REPLACE) from None
    if img is None:
        raise DataError(p, "unreadable image (OpenCV cannot decode it)", _FIX_REPLACE)
    return img


def _check_size(path: Path, img: np.ndarray, expect_hw: tuple[int, int] | None) -> None:
    if expect_hw is not None and tuple(img.shape[:2]) != tuple(expect_hw):
        raise DataError(path, f"image is {img.shape[0]}×{img.shape[1]} (H×W), expected {expect_hw[0]}×"
                              f"{expect_hw[1]}", "all images of this dataset must have the same size")


def read_image(path: str | os.PathLike, expect_hw: tuple[int, int] | None = None) -> np.ndarray:
    """Colour image → RGB uint8 (H, W, 3); grey files are expanded to three channels."""
    p = Path(path)
    img = decode(p, read_bytes(p, "image"), cv2.IMREAD_COLOR)
    _check_size(p, img, expect_hw)
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def read_png16(path: str | os.PathLike, expect_hw: tuple[int, int] | None = None) -> np.ndarray:
    """Single-channel 16-bit PNG (depth maps, segment labels) → uint16 (H, W)."""
    p = Path(path)
    img = decode(p, read_bytes(p, "image"), cv2.IMREAD_UNCHANGED)
    if img.ndim != 2 or img.dtype != np.uint16:
        raise DataError(p, f"expected a single-channel 16-bit image, found {img.dtype} with shape "
                           f"{img.shape}", _FIX_REPLACE)
    _check_size(p, img, expect_hw)
    return img


INTERPOLATIONS = ("area", "lanczos")
"""Filters that shrink an RGB image to the network size (``prepare.interpolation``,
``evaluate.interpolation``).

``area``: OpenCV's INTER_AREA (box average), anti-aliased (exact block means at integer factors).
``lanczos``: PIL's LANCZOS on the uint8 image, exactly what P²Net's training and NYU evaluation do
(``transforms.Resize`` / ``Image.ANTIALIAS``, which is LANCZOS in Pillow ≥ 10; P²Net's code,
``datasets/nyu_dataset.py`` and ``evaluation/nyuv2_eval_depth.py``); PIL widens the kernel by the scale
factor, so it anti-aliases too. The two differ by about 1 grey level on average (0..255) on a natural
photo shrunk 427×561 → 288×384. cv2.INTER_LANCZOS4 is not offered: its fixed 8×8 kernel aliases when
shrinking.
"""


def resize_rgb(rgb: np.ndarray, hw: tuple[int, int], interpolation: str = "area") -> np.ndarray:
    """rgb (H,W,3) uint8 → (h,w,3) uint8 with the filter named in :data:`INTERPOLATIONS`."""
    h, w = hw
    if rgb.shape[:2] == (h, w):
        return rgb
    if interpolation == "lanczos":
        return np.asarray(Image.fromarray(np.ascontiguousarray(rgb)).resize((w, h), Image.Resampling.LANCZOS))
    if interpolation == "area":
        return cv2.resize(np.ascontiguousarray(rgb), (w, h), interpolation=cv2.INTER_AREA)
    raise ValueError(f"interpolation must be one of {INTERPOLATIONS}, got {interpolation!r}")


def to_tensor(rgb: np.ndarray) -> torch.Tensor:
    """RGB uint8 ``(H,W,3)`` → float32 ``(3,H,W)`` in [0, 1]."""
    return torch.from_numpy(np.ascontiguousarray(rgb)).permute(2, 0, 1).float().div_(255.0)
