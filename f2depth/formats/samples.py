"""The typed sample every test-set loader returns, and the sample sets built from them.

Every loader of a test set (``f2depth.formats.nyu_labeled``, ``sevenscenes``, ``campus``) returns
:class:`EvalSample` s and has ``scene(i)`` (the scene of sample ``i`` without reading it): a
:class:`SampleSet`. The evaluation protocols (``f2depth.protocols``) read nothing else.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol as Interface

import numpy as np


@dataclass(frozen=True)
class EvalSample:
    """One test image and its ground truth, as every test-set loader returns it.

    ``rgb`` (H,W,3) uint8. Exactly one kind of ground truth: ``depth`` (H,W) float metres, 0 = invalid
    (dense), or ``points`` (K,3) float = u (column), v (row), depth_m at pixels of this image (sparse,
    laser-measured; pixel centres at integer coordinates). ``scene``: the scene it was taken in; ``key``:
    its id within the set, the values of the protocol's id columns (NYU ``(index,)``, 7-Scenes ``(scene,
    seq, frame)``, Campus ``(scene, image)``). Checked on construction (ValueError naming the sample).
    """

    rgb: np.ndarray
    scene: str
    key: tuple[str | int, ...]
    depth: np.ndarray | None = None
    points: np.ndarray | None = None

    @property
    def name(self) -> str:
        """The key as text, e.g. ``chess/seq-03/5``."""
        return "/".join(map(str, self.key))

    def __post_init__(self) -> None:
        what = f"sample {self.name}"
        if self.rgb.ndim != 3 or self.rgb.shape[2] != 3:
            raise ValueError(f"{what}: rgb must be (H,W,3), got {self.rgb.shape}")
        if self.rgb.dtype != np.uint8:
            raise ValueError(f"{what}: rgb must be uint8 (0..255), got {self.rgb.dtype}")
        if (self.depth is None) == (self.points is None):
            raise ValueError(f"{what}: give exactly one of depth (dense) and points (sparse ground truth)")
        h, w = self.rgb.shape[:2]
        if self.depth is not None:
            if self.depth.shape != (h, w) or not np.issubdtype(self.depth.dtype, np.floating):
                raise ValueError(f"{what}: depth must be float metres of the rgb's size {(h, w)}, got "
                                 f"{self.depth.dtype} {self.depth.shape} (millimetres: convert first)")
            return
        p = self.points
        if p.ndim != 2 or p.shape[1] != 3:
            raise ValueError(f"{what}: points must be (K,3) = u, v, depth_m, got {p.shape}")
        u, v = p[:, 0], p[:, 1]
        outside = ~((u >= -0.5) & (u <= w - 0.5) & (v >= -0.5) & (v <= h - 0.5))
        if np.any(outside):
            raise ValueError(f"{what}: {int(outside.sum())} point(s) lie outside the {w}×{h} image; u is the "
                             "column and v the row in pixels of this image")


class SampleSet(Interface):
    """A test set as its loader gives it: ``len``, ``[i]`` → :class:`EvalSample`, ``scene(i)``."""

    def __len__(self) -> int: ...

    def __getitem__(self, i: int) -> EvalSample: ...

    def scene(self, i: int) -> str: ...


class Subset:
    """The samples at ``positions`` of a :class:`SampleSet`; a SampleSet itself."""

    def __init__(self, samples: SampleSet, positions: Sequence[int]) -> None:
        self.samples, self.positions = samples, [int(p) for p in positions]

    def __len__(self) -> int:
        return len(self.positions)

    def __getitem__(self, i: int) -> EvalSample:
        return self.samples[self.positions[i]]

    def scene(self, i: int) -> str:
        return self.samples.scene(self.positions[i])


def spread(n: int, k: int | None) -> list[int]:
    """``k`` evenly spaced positions out of ``n`` (all of them when ``k`` is None or ≥ n)."""
    if k is None or k >= n:
        return list(range(n))
    if k < 1:
        raise ValueError(f"need at least one image, got max_images={k}")
    return np.unique(np.linspace(0, n - 1, k).round().astype(int)).tolist()


def limit(samples: SampleSet, max_images: int | None) -> SampleSet:
    """The set itself, or an evenly spaced :class:`Subset` of ``max_images`` samples."""
    if max_images is None or max_images >= len(samples):
        return samples
    return Subset(samples, spread(len(samples), max_images))


def middle_frames(samples: SampleSet) -> list[int]:
    """Position of the middle sample of every scene (scenes in order of first appearance)."""
    by_scene: dict[str, list[int]] = {}
    for i in range(len(samples)):
        by_scene.setdefault(samples.scene(i), []).append(i)
    return [pos[len(pos) // 2] for pos in by_scene.values()]
