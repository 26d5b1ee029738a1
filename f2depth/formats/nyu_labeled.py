"""NYU Depth V2 labeled set: ``nyu_depth_v2_labeled.mat`` (MATLAB v7.3 = HDF5) and ``splits.mat``.

h5py shows MATLAB's column-major arrays with their axes reversed: ``images`` (N, 3, 640, 480) uint8,
``depths`` / ``rawDepths`` (N, 640, 480) float32 metres, ``scenes`` (1, N) object references to char
arrays. ``splits.mat`` (MATLAB v5, scipy) holds one-based ``trainNdxs`` / ``testNdxs`` (k, 1).
The images are already undistorted.
"""

from __future__ import annotations

import os
from pathlib import Path

import h5py
import numpy as np
import scipy.io

from f2depth.camera import NYU_SIZE_HW
from f2depth.errors import DataError
from f2depth.formats.samples import EvalSample

SPLITS = ("train", "test", "all")
GT_KEYS = ("depths", "rawDepths")
_FIX_MAT = "point data.nyu_labeled at the official nyu_depth_v2_labeled.mat (or run `dvc repro synth`)"


def _indices(path: Path, mat: dict, key: str, n_images: int | None) -> np.ndarray:
    if key not in mat:
        raise DataError(path, f"no '{key}' array", "splits.mat must hold trainNdxs and testNdxs")
    raw = np.asarray(mat[key]).ravel()
    if raw.size == 0:
        raise DataError(path, f"'{key}' is empty")
    numeric = np.issubdtype(raw.dtype, np.number)
    if not numeric or not np.all(np.isfinite(raw)) or np.any(raw != np.round(raw)):
        raise DataError(path, f"'{key}' holds non-integer values", "indices are one-based integers")
    idx = raw.astype(np.int64)
    hi = n_images if n_images is not None else np.iinfo(np.int64).max
    bad = np.flatnonzero((idx < 1) | (idx > hi))
    if bad.size:
        k = int(bad[0])
        rng = f"1..{n_images}" if n_images is not None else "≥ 1"
        raise DataError(path, f"{key}[{k}] = {idx[k]} is outside {rng} ({bad.size} such indices; "
                              "indices are one-based into the labeled images)",
                        "use the splits.mat that belongs to this labeled .mat")
    uniq, counts = np.unique(idx, return_counts=True)
    if np.any(counts > 1):
        raise DataError(path, f"{key} repeats index {int(uniq[counts > 1][0])}")
    return idx


def read_splits(path: str | os.PathLike, n_images: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``splits.mat`` → (train, test) one-based int64 index arrays, validated against ``n_images``."""
    p = Path(path)
    if not p.is_file():
        raise DataError(p, "splits file not found",
                        "set data.nyu_splits in params.yaml (or run `dvc repro synth`)")
    try:
        mat = scipy.io.loadmat(str(p))
    except (ValueError, OSError, NotImplementedError, TypeError) as exc:
        raise DataError(p, f"not a readable MATLAB v5 file ({exc})", "use the official splits.mat") from exc
    train = _indices(p, mat, "trainNdxs", n_images)
    test = _indices(p, mat, "testNdxs", n_images)
    both = np.intersect1d(train, test)
    if both.size:
        raise DataError(p, f"index {int(both[0])} is in both trainNdxs and testNdxs ({both.size} shared)")
    return train, test


def _open(path: str | os.PathLike) -> h5py.File:
    p = Path(path)
    if not p.is_file():
        raise DataError(p, "labeled .mat file not found", _FIX_MAT)
    try:
        return h5py.File(p, "r")
    except OSError as exc:
        raise DataError(p, f"not an HDF5 (MATLAB v7.3) file ({exc})", _FIX_MAT) from exc


def _dataset(f: h5py.File, path: Path, key: str, shape_tail: tuple[int, ...]) -> h5py.Dataset:
    if key not in f or not isinstance(f[key], h5py.Dataset):
        raise DataError(path, f"no '{key}' dataset", _FIX_MAT)
    ds = f[key]
    if ds.ndim != 1 + len(shape_tail) or tuple(ds.shape[1:]) != shape_tail:
        tail = ", ".join(map(str, shape_tail))
        raise DataError(path, f"'{key}' has shape {ds.shape}, expected (N, {tail})", _FIX_MAT)
    return ds


def _check_layout(f: h5py.File, path: Path, gt: str) -> int:
    h, w = NYU_SIZE_HW
    images = _dataset(f, path, "images", (3, w, h))
    if images.dtype != np.uint8:
        raise DataError(path, f"'images' is {images.dtype}, expected uint8", _FIX_MAT)
    n = images.shape[0]
    depth = _dataset(f, path, gt, (w, h))
    if depth.shape[0] != n or not np.issubdtype(depth.dtype, np.floating):
        raise DataError(path, f"'{gt}' is {depth.dtype} {depth.shape}, expected float ({n}, {w}, {h})",
                        _FIX_MAT)
    return n


def _read_scenes(f: h5py.File, path: Path) -> list[str]:
    if "scenes" not in f:
        raise DataError(path, "no 'scenes' cell array", _FIX_MAT)
    refs = f["scenes"][()]
    if refs.dtype != h5py.ref_dtype:
        raise DataError(path, f"'scenes' is {refs.dtype}, expected a cell array (object references)",
                        _FIX_MAT)
    names = []
    for k, ref in enumerate(refs.ravel()):
        try:
            obj = f[ref]
        except (ValueError, KeyError) as exc:
            raise DataError(path, f"scenes{{{k + 1}}} is a dangling reference", _FIX_MAT) from exc
        chars = np.asarray(obj[()]).ravel()
        if obj.attrs.get("MATLAB_empty", 0) or chars.size == 0:
            raise DataError(path, f"scenes{{{k + 1}}} is empty", _FIX_MAT)
        names.append("".join(chr(int(c)) for c in chars))
    return names


def scene_names(mat_path: str | os.PathLike) -> list[str]:
    """Scene name of every labeled image, in file order (entry i ↔ one-based index i + 1)."""
    with _open(mat_path) as f:
        n = _check_layout(f, Path(mat_path), "depths")
        names = _read_scenes(f, Path(mat_path))
    if len(names) != n:
        raise DataError(mat_path, f"'scenes' has {len(names)} entries for {n} images", _FIX_MAT)
    return names


def scenes_of_test_images(mat_path: str | os.PathLike, splits_path: str | os.PathLike) -> set[str]:
    """Scenes of the labeled test images (``testNdxs``): their raw videos must not be trained on."""
    names = scene_names(mat_path)
    _, test = read_splits(splits_path, len(names))
    return {names[i - 1] for i in test}


class NYULabeledSet:
    """The labeled images of one split, read lazily from the HDF5 file (one handle per process).

    ``split``: ``"test"`` (654 official), ``"train"`` or ``"all"``; ``gt``: ``"depths"`` (filled)
    or ``"rawDepths"`` (0 = hole). Samples: :class:`~f2depth.formats.samples.EvalSample` with rgb uint8
    (480, 640, 3), depth float32 (480, 640) m and key ``(index,)``, one-based in the labeled set.
    """

    def __init__(self, mat_path: str | os.PathLike, splits_path: str | os.PathLike,
                 split: str = "test", gt: str = "depths"):
        if split not in SPLITS:
            raise ValueError(f"split must be one of {SPLITS}, got {split!r}")
        if gt not in GT_KEYS:
            raise ValueError(f"gt must be one of {GT_KEYS} (evaluate.nyu_gt), got {gt!r}")
        self.mat_path, self.split, self.gt = Path(mat_path), split, gt
        with _open(self.mat_path) as f:
            self.num_images = _check_layout(f, self.mat_path, gt)
            self._scenes = _read_scenes(f, self.mat_path)
        if len(self._scenes) != self.num_images:
            raise DataError(self.mat_path, f"'scenes' has {len(self._scenes)} entries for {self.num_images} "
                                           "images", _FIX_MAT)
        train, test = read_splits(splits_path, self.num_images)
        all_idx = np.arange(1, self.num_images + 1, dtype=np.int64)
        #: one-based indices of this split, in increasing order of the split file
        self.indices = {"train": train, "test": test, "all": all_idx}[split]
        self._file: h5py.File | None = None
        self._pid = -1

    def __len__(self) -> int:
        return len(self.indices)

    def _h5(self) -> h5py.File:
        if self._file is None or self._pid != os.getpid():
            self._file = _open(self.mat_path)
            self._pid = os.getpid()
        return self._file

    def scene(self, i: int) -> str:
        return self._scenes[int(self.indices[i]) - 1]

    def __getitem__(self, i: int) -> EvalSample:
        if not -len(self) <= i < len(self):
            raise IndexError(f"sample {i} of {len(self)}")
        idx = int(self.indices[i])
        f = self._h5()
        rgb = np.ascontiguousarray(f["images"][idx - 1].transpose(2, 1, 0))
        depth = np.ascontiguousarray(f[self.gt][idx - 1].T, dtype=np.float32)
        bad = ~np.isfinite(depth) | (depth < 0)
        if bad.any():
            raise DataError(self.mat_path, f"{self.gt} of image {idx} has {int(bad.sum())} negative or "
                                           "non-finite values", _FIX_MAT)
        return EvalSample(rgb, self._scenes[idx - 1], (idx,), depth=depth)

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None

    def __enter__(self) -> NYULabeledSet:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __getstate__(self) -> dict:
        state = self.__dict__.copy()
        state["_file"], state["_pid"] = None, -1  # h5py handles do not cross process boundaries
        return state
