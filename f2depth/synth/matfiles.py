"""MATLAB files as the real NYU Depth V2 ones: the v7.3 (HDF5) labeled set and the v5 ``splits.mat``.

MATLAB v7.3 conventions reproduced here: a 512-byte user block whose first 128 bytes are the MATLAB
header (116 bytes of text, 8 bytes of subsystem offset, version 0x0200, endian 'IM'); arrays stored with
their axes reversed (an H×W×3×N MATLAB array appears to h5py as (N, 3, W, H)); every dataset carries a
``MATLAB_class`` attribute; a cell array is a dataset of object references (class ``cell``) to its
elements, which live in the ``/#refs#`` group (each with an ``H5PATH`` attribute), next to MATLAB's
'canonical empty' ``#refs#/a``; a char array is uint16 UTF-16 code units with ``MATLAB_int_decode`` 2.
Everything is written without timestamps so the same input gives the same bytes.
"""

from __future__ import annotations

import io
import string
from pathlib import Path

import h5py
import numpy as np
import scipy.io

from f2depth.io import atomic_path, write_bytes

_V73_TEXT = "MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: f2depth synthetic world HDF5 schema 1.00 ."
_V5_TEXT = "MATLAB 5.0 MAT-file, Platform: GLNXA64, Created on: f2depth synthetic world"
_REF_LETTERS = string.ascii_lowercase + string.ascii_uppercase


def _ref_name(k: int) -> str:
    """MATLAB-like names for #refs# members: b, c, ..., z, A, ..., Z, ba, bb, ... ('a' is reserved)."""
    k += 1
    out = ""
    while True:
        out = _REF_LETTERS[k % 52] + out
        k //= 52
        if k == 0:
            return out


def _attr(obj, name: str, value: str) -> None:
    obj.attrs.create(name, np.bytes_(value))


def _cellstr(f: h5py.File, refs: h5py.Group, name: str, values: list[str], start: int) -> int:
    """Write a 1×N MATLAB cellstr (h5py shape (1, N)); returns the next free #refs# index."""
    ref_list = []
    for k, text in enumerate(values):
        data = np.frombuffer(text.encode("utf-16-le"), dtype="<u2").reshape(-1, 1)  # MATLAB 1×L char
        ds = refs.create_dataset(_ref_name(start + k), data=data, track_times=False)
        _attr(ds, "MATLAB_class", "char")
        ds.attrs.create("MATLAB_int_decode", np.int32(2))
        _attr(ds, "H5PATH", f"/{name}")
        ref_list.append(ds.ref)
    cell = f.create_dataset(name, shape=(1, len(values)), dtype=h5py.ref_dtype, track_times=False)
    cell[0, :] = ref_list
    _attr(cell, "MATLAB_class", "cell")
    return start + len(values)


def write_nyu_labeled(path: str | Path, images: np.ndarray, depths: np.ndarray, raw_depths: np.ndarray,
                      scenes: list[str], scene_types: list[str]) -> None:
    """Write ``nyu_depth_v2_labeled.mat``.

    images (N, H, W, 3) uint8 RGB; depths, raw_depths (N, H, W) float32 metres (raw: 0 = hole);
    scenes, scene_types: N names. Stored as h5py shows the real file: ``images`` (N, 3, W, H),
    ``depths``/``rawDepths`` (N, W, H), ``scenes``/``sceneTypes`` (1, N) cells.
    """
    n = len(images)
    if not (len(depths) == len(raw_depths) == len(scenes) == len(scene_types) == n):
        raise ValueError("images, depths, raw_depths, scenes and scene_types must have the same length")
    with atomic_path(path) as tmp:
        with h5py.File(tmp, "w", userblock_size=512, track_order=False) as f:
            refs = f.create_group("#refs#")
            empty = refs.create_dataset("a", data=np.zeros(2, np.uint64), track_times=False)
            _attr(empty, "MATLAB_class", "canonical empty")
            empty.attrs.create("MATLAB_empty", np.uint8(1))
            # (N, H, W, 3) -> MATLAB H×W×3×N -> h5py (N, 3, W, H)
            ds = f.create_dataset("images", data=np.ascontiguousarray(images.transpose(0, 3, 2, 1)),
                                  chunks=(1, 3, images.shape[2], images.shape[1]), track_times=False)
            _attr(ds, "MATLAB_class", "uint8")
            for name, arr in (("depths", depths), ("rawDepths", raw_depths)):
                ds = f.create_dataset(name,
                                      data=np.ascontiguousarray(arr.transpose(0, 2, 1), dtype=np.float32),
                                      chunks=(1, arr.shape[2], arr.shape[1]), track_times=False)
                _attr(ds, "MATLAB_class", "single")
            nxt = _cellstr(f, refs, "scenes", scenes, 0)
            _cellstr(f, refs, "sceneTypes", scene_types, nxt)
        header = _V73_TEXT.encode("ascii").ljust(116, b" ") + b"\x00" * 8 + b"\x00\x02IM"
        with open(tmp, "r+b") as fh:
            fh.write(header)


def write_splits(path: str | Path, train_ndxs: np.ndarray, test_ndxs: np.ndarray) -> None:
    """``splits.mat`` like the official one: ``trainNdxs``/``testNdxs`` (k, 1) uint16, one-based."""
    buf = io.BytesIO()
    scipy.io.savemat(buf, {"trainNdxs": np.asarray(train_ndxs, np.uint16).reshape(-1, 1),
                           "testNdxs": np.asarray(test_ndxs, np.uint16).reshape(-1, 1)},
                     format="5", do_compression=False)
    data = bytearray(buf.getvalue())
    data[:116] = _V5_TEXT.encode("ascii").ljust(116, b" ")  # fixed header text instead of the date
    write_bytes(path, bytes(data))
