"""Seeds with intervals: a variant's headline and each ablation gap with a bootstrap interval.

The evaluate stage writes, per variant, ``reports/eval/<variant>/<set>.csv``: one row per seed, test image
and post-processing. :func:`read_scores` reads one file's rows without PP into metric → (S, N) arrays (S
seeds, N test images, aligned by the image key); :func:`load_set` does so for every variant of a set and
refuses two that differ in seeds or images (a paired difference needs both the same).

The statistic is the evaluate stage's headline, averaged over seeds: the mean over the test images (one
stratum: NYU, 7-Scenes) or the mean of the scene means (a stratum per scene: Campus), i.e. the mean over the
strata of the mean over each stratum's images. One resample draws S seeds with replacement and, independently,
the resampling UNITS with replacement, within each stratum as many as it has; a drawn unit brings all its
images. A unit is one image (NYU; Campus, whose scenes stay fixed with their weight, as the headline treats
them) or a group of images that are not independent of each other (7-Scenes: a test sequence, whose
consecutive frames are near-duplicates; drawing its frames one by one would count one sequence's luck as
hundreds of independent images). Every variant of a set gets the same draws, so the draws of a − b are the
PAIRED difference (same seeds, same images). The interval is the percentile interval of ``resamples`` draws
from ``numpy.random.default_rng(seed)``: the same inputs give the same numbers. With one seed the seed level
has no spread and the interval covers the test images only (``n_seeds`` says how many seeds there were).
"""

from __future__ import annotations

import csv
import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

Pair = tuple[str, str]


@dataclass(frozen=True)
class Interval:
    """A point estimate (the mean over seeds, or a difference of two) and its interval [lo, hi]."""

    estimate: float
    lo: float
    hi: float

    @property
    def significant(self) -> bool:
        """The interval excludes 0: the sign of a difference is supported."""
        return bool(self.lo > 0 or self.hi < 0)


@dataclass(frozen=True)
class SetScores:
    """One test set's per-image scores of every variant, aligned. ``values``: variant → metric → (S, N)
    float64 (rows: ``seeds``, columns: ``keys``, the N image keys); ``units``: (N,) int, the resampling unit
    of each image; ``strata``: (N,) int, its stratum (a unit lies in one stratum)."""

    name: str
    seeds: tuple[int, ...]
    keys: tuple[tuple[str, ...], ...]
    units: np.ndarray
    strata: np.ndarray
    values: dict[str, dict[str, np.ndarray]]


@dataclass(frozen=True)
class SetIntervals:
    """One set's intervals: ``variants`` variant → metric → :class:`Interval` of its mean over seeds; ``gaps``
    (a, b) → metric → :class:`Interval` of the paired difference a − b; ``n_units``: the units resampled."""

    name: str
    n_seeds: int
    n_images: int
    n_units: int
    variants: dict[str, dict[str, Interval]]
    gaps: dict[Pair, dict[str, Interval]]


@dataclass(frozen=True)
class Intervals:
    """Every set's intervals (set name → :class:`SetIntervals`) and what they were computed with."""

    gaps: tuple[Pair, ...]
    confidence: float
    resamples: int
    sets: dict[str, SetIntervals]


Rows = dict[tuple[str, ...], dict[str, str]]


def read_scores(path: str | os.PathLike, key_columns: Sequence[str], metrics: Sequence[str]
                ) -> tuple[tuple[int, ...], list[tuple[str, ...]], Rows, dict[str, np.ndarray]]:
    """The rows without PP (``post_process`` False) of one per-image CSV → (seeds (S,) ascending, the N image
    keys in the first seed's order, the first seed's rows by key, metric → (S, N) float64). Every seed must
    have scored the same images, each once."""
    p = Path(path)
    with p.open(newline="") as fh:
        reader = csv.DictReader(fh)
        missing = [c for c in ("seed", "post_process", "scene", *key_columns, *metrics)
                   if c not in (reader.fieldnames or [])]
        if missing:
            raise ValueError(f"{p}: no column {missing}; re-run the evaluate stage")
        rows = [r for r in reader if r["post_process"] == "False"]
    if not rows:
        raise ValueError(f"{p}: no rows without post-processing (post_process False); re-run the evaluate "
                         "stage")
    by_seed: dict[int, Rows] = {}
    for r in rows:
        seed, key = int(r["seed"]), tuple(r[c] for c in key_columns)
        if key in by_seed.setdefault(seed, {}):
            raise ValueError(f"{p}: seed {seed} has image {'/'.join(key)} twice")
        by_seed[seed][key] = r
    seeds = tuple(sorted(by_seed))
    keys = list(by_seed[seeds[0]])
    for s in seeds[1:]:
        if set(by_seed[s]) != set(keys):
            raise ValueError(f"{p}: seed {s} scored other test images than seed {seeds[0]}; re-run the "
                             "evaluate stage")
    try:
        values = {m: np.array([[float(by_seed[s][k][m]) for k in keys] for s in seeds]) for m in metrics}
    except ValueError as exc:
        raise ValueError(f"{p}: a metric cell is no number ({exc}); re-run the evaluate stage") from None
    return seeds, keys, by_seed[seeds[0]], values


def _codes(labels: list[tuple[str, ...]]) -> np.ndarray:
    """N labels → (N,) int codes 0..L-1, equal labels equal codes."""
    positions: dict[tuple[str, ...], int] = {}
    return np.array([positions.setdefault(x, len(positions)) for x in labels], dtype=np.int64)


def load_set(name: str, files: Mapping[str, str | os.PathLike], key_columns: Sequence[str],
             unit_columns: Sequence[str], by_scene: bool, metrics: Sequence[str]) -> SetScores:
    """Every variant's scores of test set ``name`` (``files``: variant → its CSV), aligned to the first
    variant's image order. ``unit_columns``: the columns naming an image's resampling unit (its key columns:
    the image itself); ``by_scene``: the headline is the mean of the scene means (a stratum per ``scene``). A
    variant whose seeds or images differ from the first's → ValueError, one line naming both files."""
    values: dict[str, dict[str, np.ndarray]] = {}
    first: tuple[Path, tuple[int, ...], list[tuple[str, ...]], Rows] | None = None
    for variant, path in files.items():
        seeds, keys, rows, scores = read_scores(path, key_columns, metrics)
        if first is None:
            first = (Path(path), seeds, keys, rows)
        elif seeds != first[1]:
            raise ValueError(f"{path}: seeds {list(seeds)}, but {first[0]} has {list(first[1])}; a paired "
                             "difference needs the same seeds: evaluate every variant with train_depth.seeds")
        elif set(keys) != set(first[2]):
            odd = sorted(set(keys) ^ set(first[2]))
            raise ValueError(f"{path}: {len(odd)} test image(s) not in both it and {first[0]} (e.g. "
                             f"{'/'.join(odd[0])}); a paired difference needs the same test images: re-run "
                             "the evaluate stage of both with the same evaluate settings")
        else:
            position = {k: i for i, k in enumerate(keys)}
            order = np.array([position[k] for k in first[2]], dtype=np.int64)
            scores = {m: a[:, order] for m, a in scores.items()}
        values[variant] = scores
    if first is None:
        raise ValueError(f"test set {name}: no variant to read")
    rows = [first[3][k] for k in first[2]]
    units = _codes([tuple(r[c] for c in ("scene", *unit_columns)) for r in rows])
    strata = _codes([(r["scene"],) if by_scene else () for r in rows])
    return SetScores(name, first[1], tuple(first[2]), units, strata, values)


def _unit_sampler(unit_stratum: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(U,) stratum of each unit → (order, start, size): the units sorted by stratum, and for each unit its
    stratum's first position in ``order`` and its unit count (what :func:`_draw_units` draws from)."""
    _, inverse, counts = np.unique(unit_stratum, return_inverse=True, return_counts=True)
    inverse = inverse.ravel()
    start = np.concatenate([[0], np.cumsum(counts)[:-1]])
    return np.argsort(unit_stratum, kind="stable"), start[inverse], counts[inverse]


def _draw_units(rng: np.random.Generator, sampler: tuple[np.ndarray, np.ndarray, np.ndarray]) -> np.ndarray:
    """(U,) how often each unit is drawn: each stratum's unit count, with replacement from its own units."""
    order, start, size = sampler
    picked = order[start + (rng.random(len(order)) * size).astype(np.int64)]
    return np.bincount(picked, minlength=len(order))


def _image_weights(scores: SetScores, unit_counts: np.ndarray) -> np.ndarray:
    """(U,) draws of each unit → (N,) weights w with w · x = the mean over strata of the mean over each
    stratum's drawn images."""
    counts = unit_counts[scores.units].astype(np.float64)
    totals = np.bincount(scores.strata, weights=counts)
    return counts / (totals[scores.strata] * len(totals))


def point(scores: SetScores) -> dict[str, dict[str, float]]:
    """variant → metric → the headline statistic averaged over seeds (what ``metrics/evaluate`` holds)."""
    w = _image_weights(scores, np.ones(int(scores.units.max()) + 1, dtype=np.int64))
    return {v: {m: float(np.mean(a @ w)) for m, a in ms.items()} for v, ms in scores.values.items()}


def bootstrap(scores: SetScores, resamples: int, seed: int) -> dict[str, dict[str, np.ndarray]]:
    """variant → metric → (resamples,) draws of the statistic, every variant with the same seed and unit
    draws (module docstring)."""
    names = [(v, m) for v, ms in scores.values.items() for m in ms]
    stack = np.stack([scores.values[v][m] for v, m in names])  # (K, S, N)
    n_seeds = stack.shape[1]
    unit_stratum = np.zeros(int(scores.units.max()) + 1, dtype=np.int64)
    unit_stratum[scores.units] = scores.strata
    sampler, rng = _unit_sampler(unit_stratum), np.random.default_rng(seed)
    draws = np.empty((len(names), resamples))
    for b in range(resamples):
        seed_weight = np.bincount(rng.integers(0, n_seeds, n_seeds), minlength=n_seeds) / n_seeds
        image_weight = _image_weights(scores, _draw_units(rng, sampler))
        draws[:, b] = (stack @ image_weight) @ seed_weight
    out: dict[str, dict[str, np.ndarray]] = {}
    for (v, m), row in zip(names, draws):
        out.setdefault(v, {})[m] = row
    return out


def percentile(draws: np.ndarray, estimate: float, confidence: float) -> Interval:
    """The percentile interval of ``draws`` (R,) at ``confidence`` around ``estimate`` (NaN draws: NaN)."""
    if np.isnan(draws).any():
        return Interval(float(estimate), math.nan, math.nan)
    lo, hi = np.quantile(draws, [(1 - confidence) / 2, (1 + confidence) / 2])
    return Interval(float(estimate), float(lo), float(hi))


def summarize(scores: SetScores, gaps: Sequence[Pair], resamples: int, confidence: float,
              seed: int) -> SetIntervals:
    """Each variant's interval and each gap's (a − b, both variants in ``scores``; others left out). One seed
    and one unit in every stratum leave nothing to resample: every interval is then NaN (none), not a point
    that would make any difference look significant."""
    est, draws = point(scores), bootstrap(scores, resamples, seed)
    units_per_stratum = np.bincount(np.unique(np.stack([scores.strata, scores.units]), axis=1)[0])
    if len(scores.seeds) == 1 and units_per_stratum.max() == 1:
        draws = {v: {m: np.full(resamples, np.nan) for m in ms} for v, ms in draws.items()}
    variants = {v: {m: percentile(d, est[v][m], confidence) for m, d in ms.items()}
                for v, ms in draws.items()}
    paired = {(a, b): {m: percentile(draws[a][m] - draws[b][m], est[a][m] - est[b][m], confidence)
                       for m in draws[a] if m in draws[b]}
              for a, b in gaps if a in draws and b in draws}  # fmt: skip
    return SetIntervals(scores.name, len(scores.seeds), len(scores.keys), int(scores.units.max()) + 1,
                        variants, paired)
