"""Turning relative depth metric: a fixed factor, or median scaling against a reference depth map.

A self-supervised monocular network predicts depth only up to an unknown scale. ``median_ratio`` is the
evaluation protocol's per-image factor ``median(ref) / median(pred)`` over the reference's valid pixels.
"""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np

from f2depth.errors import DataError
from f2depth.formats.images import read_png16
from f2depth.protocols.metrics import median_scale

_FIX = "give a 16-bit PNG in millimetres (0 or 65535 = no depth) or a float .npy (H, W) in metres"


def read_reference_depth(path: str | os.PathLike) -> np.ndarray:
    """A reference depth map → float32 (H, W) metres, 0 = invalid.

    ``.png``: single-channel uint16 millimetres, 0 and 65535 invalid (7-Scenes / Kinect convention);
    ``.npy``: float (H, W) metres, values ≤ 0 or not finite invalid.
    """
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix == ".png":
        try:
            mm = read_png16(p)
        except DataError as exc:
            raise DataError(exc.path, exc.problem, _FIX) from None
        depth = mm.astype(np.float32) / 1000.0
        depth[(mm == 0) | (mm == 65535)] = 0.0
        return depth
    if suffix == ".npy":
        if not p.is_file():
            raise DataError(p, "reference depth not found", _FIX)
        try:
            arr = np.load(p, allow_pickle=False)
        except (OSError, ValueError, EOFError) as exc:
            raise DataError(p, f"unreadable .npy ({exc})", _FIX) from None
        if arr.ndim != 2 or not np.issubdtype(arr.dtype, np.number):
            raise DataError(p, f"expected a numeric (H, W) array, found {arr.dtype} {arr.shape}", _FIX)
        arr = arr.astype(np.float32)
        arr[~np.isfinite(arr) | (arr < 0)] = 0.0
        return arr
    raise DataError(p, f"unsupported reference depth type '{suffix}'", _FIX)


def median_ratio(pred: np.ndarray, ref: np.ndarray, source: str = "reference") -> float:
    """``median(ref) / median(pred)`` over the pixels where ref > 0.

    pred (h,w) and ref (H,W) metres; pred is resized to ref's size (nearest) when they differ.
    No valid reference pixel → DataError naming ``source``.
    """
    pred = np.asarray(pred, np.float32)
    if pred.shape != ref.shape:
        pred = cv2.resize(pred, (ref.shape[1], ref.shape[0]), interpolation=cv2.INTER_NEAREST)
    valid = (ref > 0) & (pred > 0)
    if not valid.any():
        raise DataError(source, "reference depth has no valid pixel", _FIX)
    return median_scale(pred[valid], ref[valid])[1]
