"""DSO's ``makeMaps``: adapt the cell size to a density target, re-select, thin (``PixelSelector2.cpp``).

Float32 where DSO computes in float; comparisons with DSO's double literals are done in double.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from f2depth.keypoints.random_pattern import random_pattern
from f2depth.keypoints.select import Prepared, select


@dataclass(frozen=True)
class MapsResult:
    """Output of one makeMaps call.

    ``points`` (N, 3) int64 x, y, level in raster order (after thinning); ``pot_out`` the pot for the
    next frame (DSO's ``currentPotential`` afterwards); ``pots`` the pots select() ran with;
    ``counts`` (level 0, 1, 2) of the last select() before thinning; ``quotia`` density / selected.
    """

    points: np.ndarray
    pot_out: int
    pots: tuple[int, ...]
    counts: tuple[int, int, int]
    quotia: float


def ideal_potential(num_have: int, pot: int, density: float) -> int:
    """``max(1, (int)(sqrtf(numHave·(pot+1)·(pot+1) / numWant) − 1))`` in float32."""
    k = np.float32(num_have) * np.float32(pot + 1) * np.float32(pot + 1)
    ideal = np.sqrt(k / np.float32(density)) - np.float32(1)
    return max(int(ideal), 1)  # int() truncates toward zero like the C cast


def thin(points: np.ndarray, quotia: float) -> np.ndarray:
    """Keep the k-th point (raster order) iff ``pattern[k] ≤ (unsigned char)(255·quotia)``."""
    char_th = int(np.float32(255) * np.float32(quotia))
    keep = random_pattern(len(points)) <= char_th
    return points[keep]


def make_maps(prep: Prepared, pot: int, density: float, recursions: int = 1) -> MapsResult:
    """Select with cell size ``pot``, re-select up to ``recursions`` times, then thin to ``density``."""
    if not density > 0:
        raise ValueError(f"density must be > 0, got {density}")
    if pot < 1:
        raise ValueError(f"pot must be >= 1, got {pot}")
    left = int(recursions)
    pots = []
    while True:
        pots.append(pot)
        points, counts = select(prep, pot)
        num_have = sum(counts)
        quotia = float(np.float32(density) / np.float32(num_have)) if num_have else float("inf")
        ideal = ideal_potential(num_have, pot, density)
        if left > 0 and quotia > 1.25 and pot > 1:
            pot = min(ideal, pot - 1)
        elif left > 0 and quotia < 0.25:
            pot = max(ideal, pot + 1)
        else:
            break
        left -= 1
    if quotia < 0.95:
        points = thin(points, quotia)
    return MapsResult(points, ideal, tuple(pots), counts, quotia)
