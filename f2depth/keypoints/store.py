"""Keypoint files (``data/keypoints/<split>.npz``, docs/formats.md) and the API the losses use.

A file holds ``frame_ids`` (N,) int64 — the frame's row in the prepared set's frames.csv
(:meth:`f2depth.formats.prepared.PreparedSet.frame_index`) —, ``offsets`` (N+1,) int64 and ``points``
(M, 3) int16 = x, y, level at the training resolution; frame i owns ``points[offsets[i]:offsets[i+1]]``.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from f2depth.errors import DataError
from f2depth.io import save_npz

_FIX = "re-run `dvc repro keypoints`"


class KeypointFileError(DataError):
    """A keypoint file is missing or malformed; the message names the file and the fix (a DataError, so
    the stages report it in one line)."""


def pack(frame_ids: Sequence[int], points: Sequence[np.ndarray]) -> dict[str, np.ndarray]:
    """The arrays of a keypoint file from per-frame (n_i, 3) x, y, level arrays."""
    if len(frame_ids) != len(points):
        raise ValueError(f"{len(frame_ids)} frame ids but {len(points)} point arrays")
    counts = [len(p) for p in points]
    offsets = np.zeros(len(points) + 1, np.int64)
    np.cumsum(counts, out=offsets[1:])
    for p in points:
        if len(p) and (p.ndim != 2 or p.shape[1] != 3 or p.min() < np.iinfo(np.int16).min
                       or p.max() > np.iinfo(np.int16).max):
            raise ValueError(f"points must be (n, 3) x, y, level within int16, got shape {p.shape}")
    stacked = np.concatenate([np.asarray(p).reshape(-1, 3) for p in points]) if points else np.zeros((0, 3))
    return {"frame_ids": np.asarray(frame_ids, np.int64), "offsets": offsets,
            "points": stacked.astype(np.int16).reshape(-1, 3)}


def save_keypoints(path: str | os.PathLike, frame_ids: Sequence[int], points: Sequence[np.ndarray]) -> None:
    """Write a keypoint file atomically (compressed npz)."""
    save_npz(path, **pack(frame_ids, points))


class KeypointFile:
    """A loaded, validated keypoint file; ``points(frame_id)`` / ``tensor(frame_id)`` per frame."""

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        if not self.path.is_file():
            raise KeypointFileError(f"{self.path}: keypoint file not found; {_FIX}")
        try:
            with np.load(self.path) as z:
                self.frame_ids = np.asarray(z["frame_ids"])
                self.offsets = np.asarray(z["offsets"])
                self._points = np.asarray(z["points"])
        except (OSError, ValueError, KeyError, EOFError) as exc:
            raise KeypointFileError(f"{self.path}: unreadable keypoint file ({exc}); {_FIX}") from exc
        n = len(self.frame_ids)
        problems = []
        if self.frame_ids.ndim != 1 or not np.issubdtype(self.frame_ids.dtype, np.integer):
            problems.append(f"frame_ids must be (N,) integers, got {self.frame_ids.dtype} "
                            f"{self.frame_ids.shape}")
        elif len(np.unique(self.frame_ids)) != n:
            problems.append("frame_ids are not unique")
        if self._points.ndim != 2 or self._points.shape[1] != 3:
            problems.append(f"points must be (M, 3), got {self._points.shape}")
        if (self.offsets.shape != (n + 1,) or self.offsets[0] != 0 or self.offsets[-1] != len(self._points)
                or np.any(np.diff(self.offsets) < 0)):
            problems.append(f"offsets must be (N+1,) = ({n + 1},), non-decreasing from 0 to len(points)")
        if problems:
            raise KeypointFileError(f"{self.path}: {'; '.join(problems)}; {_FIX}")
        self._row = {int(f): i for i, f in enumerate(self.frame_ids)}

    def __len__(self) -> int:
        return len(self.frame_ids)

    def __contains__(self, frame_id: int) -> bool:
        return int(frame_id) in self._row

    def points(self, frame_id: int) -> np.ndarray:
        """(n, 3) int16 x, y, level of a frame (possibly empty)."""
        try:
            i = self._row[int(frame_id)]
        except KeyError:
            raise KeyError(f"frame {frame_id} has no entry in {self.path}; {_FIX}") from None
        return self._points[self.offsets[i] : self.offsets[i + 1]]

    def tensor(self, frame_id: int):
        """(n, 3) torch.int64 x, y, level of a frame (possibly empty)."""
        import torch

        return torch.from_numpy(self.points(frame_id).astype(np.int64))

    def check_inside(self, height: int, width: int) -> None:
        """KeypointFileError when any point lies outside the ``height`` × ``width`` training grid (x in
        [0, width), y in [0, height)), with the count and the first frame. The losses would otherwise
        clamp such points onto the image border and train on the wrong pixels without a word."""
        x, y = self._points[:, 0].astype(np.int64), self._points[:, 1].astype(np.int64)
        outside = (x < 0) | (x >= width) | (y < 0) | (y >= height)
        if not outside.any():
            return
        first = int(np.flatnonzero(outside)[0])
        row = int(np.searchsorted(self.offsets, first, side="right")) - 1
        frames = np.unique(np.searchsorted(self.offsets, np.flatnonzero(outside), side="right") - 1)
        raise KeypointFileError(f"{self.path}: {int(outside.sum())} of {len(self._points)} keypoints in "
                                f"{len(frames)} frame(s) lie outside the {width}×{height} training images "
                                f"(first: frame {int(self.frame_ids[row])} at x={int(x[first])}, "
                                f"y={int(y[first])}); the file was made for another size: {_FIX}")


def fill_up(points, count: int, height: int, width: int, generator=0):
    """P²Net's fill-up: the keypoints, then uniform random pixels up to ``count`` points.

    points: (n, ≥2) tensor or array, x, y first (level etc. ignored); height, width: the grid of the
    random points (x in [0, width), y in [0, height), like ``np.random.randint``); generator: a
    ``torch.Generator`` or an int seed. Returns ``(xy (count, 2) int64 x first, real (count,) bool)``
    with ``real`` True for the keypoints. Duplicates are kept (as P²Net). If there are more than
    ``count`` keypoints the first ``count`` are kept. With no keypoints every point is random.
    """
    import torch

    if count < 0 or height < 1 or width < 1:
        raise ValueError(f"need count >= 0 and a non-empty grid, got count={count}, {height}x{width}")
    if not isinstance(generator, torch.Generator):
        generator = torch.Generator().manual_seed(int(generator))
    xy = torch.as_tensor(np.asarray(points) if not torch.is_tensor(points) else points)
    xy = xy.reshape(-1, xy.shape[-1] if xy.ndim > 1 else 2)[:count, :2].to(torch.int64)
    n_rand = count - len(xy)
    rand_x = torch.randint(0, width, (n_rand,), generator=generator)
    rand_y = torch.randint(0, height, (n_rand,), generator=generator)
    out = torch.cat([xy, torch.stack([rand_x, rand_y], dim=1)])
    real = torch.zeros(count, dtype=torch.bool)
    real[: len(xy)] = True
    return out, real
