"""Depth metrics and median scaling (the network's disparity, with Monodepth's flip post-processing:
:mod:`f2depth.depth.predict`).

Every protocol (NYU, 7-Scenes, Campus) uses the same per-image recipe (P²Net's
``evaluation/nyuv2_eval_depth.py``; Monodepth2's ``evaluate_depth.py``, ``compute_errors``): keep the
valid pixels, scale the prediction by the ratio of medians, clip it to ``[min_depth, max_depth]`` and
compute the eight metrics on those pixels. Dataset numbers are the mean
of the per-image numbers (RMS is the mean of per-image RMS, not a pooled RMS).

Metric names are stable and used as keys everywhere (metrics JSON, tables, MLflow): see
:data:`METRIC_NAMES`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from f2depth.geometry import MAX_DEPTH, MIN_DEPTH

METRIC_NAMES: tuple[str, ...] = ("abs_rel", "sq_rel", "rmse", "rmse_log", "log10", "a1", "a2", "a3")
"""Error metrics first (lower is better), then the three accuracies (higher is better)."""


class EmptyMaskError(ValueError):
    """An image has no valid ground-truth pixel/point, so its metrics are undefined."""


# ---- per-image metrics ---------------------------------------------------------------------------


def compute_errors(gt: np.ndarray, pred: np.ndarray) -> dict[str, float]:
    """The eight metrics of one image.

    gt, pred: (N,) metres, the valid pixels only, all > 0 (mask, scale and clip first).
    Returns ``{name: value}`` for every name in :data:`METRIC_NAMES`.
    """
    gt = np.asarray(gt, dtype=np.float64).ravel()
    pred = np.asarray(pred, dtype=np.float64).ravel()
    if gt.shape != pred.shape:
        raise ValueError(f"gt and pred differ in size: {gt.shape} vs {pred.shape}")
    if gt.size == 0:
        raise EmptyMaskError("no valid pixels to compute metrics on")
    if np.any(gt <= 0) or np.any(pred <= 0):
        raise ValueError("gt and pred must be > 0 on the pixels passed to compute_errors "
                         "(mask and clip first)")
    diff = gt - pred
    sq = diff * diff
    ratio = np.maximum(gt / pred, pred / gt)  # the reference definition (exact at the thresholds)
    log_diff = np.log(ratio)  # |ln gt − ln pred|; log10 is this / ln 10
    return {"abs_rel": float(np.mean(np.abs(diff) / gt)), "sq_rel": float(np.mean(sq / gt)),
            "rmse": float(np.sqrt(np.mean(sq))), "rmse_log": float(np.sqrt(np.mean(log_diff * log_diff))),
            "log10": float(np.mean(log_diff) / np.log(10.0)), "a1": float(np.mean(ratio < 1.25)),
            "a2": float(np.mean(ratio < 1.25**2)), "a3": float(np.mean(ratio < 1.25**3))}


def median_scale(pred: np.ndarray, gt: np.ndarray) -> tuple[np.ndarray, float]:
    """Scale ``pred`` so its median equals the median of ``gt``.

    pred, gt: (N,) metres on the valid pixels. Returns ``(pred * ratio, ratio)`` with
    ``ratio = median(gt) / median(pred)``.
    """
    pred = np.asarray(pred, dtype=np.float64)
    med_pred = float(np.median(pred))
    if not med_pred > 0:
        raise ValueError(f"median of the prediction is {med_pred}; depths must be positive")
    ratio = float(np.median(np.asarray(gt, dtype=np.float64))) / med_pred
    return pred * ratio, ratio


def clip_depth(pred: np.ndarray, min_depth: float = MIN_DEPTH, max_depth: float = MAX_DEPTH) -> np.ndarray:
    """Clip depths to ``[min_depth, max_depth]`` metres (applied after median scaling). Any shape."""
    return np.clip(pred, min_depth, max_depth)


def image_metrics(gt: np.ndarray, pred: np.ndarray, mask: np.ndarray | None = None, *,
                  median_scaling: bool = True, min_depth: float = MIN_DEPTH,
                  max_depth: float = MAX_DEPTH) -> tuple[dict[str, float], float]:
    """Mask → median-scale → clip → metrics for one image.

    gt, pred: same shape (H,W) or (N,), metres; mask: bool, same shape, default ``gt > 0``.
    Returns ``(metrics, ratio)``; ``ratio`` is 1.0 without median scaling.
    Raises :class:`EmptyMaskError` when no pixel is valid.
    """
    gt = np.asarray(gt)
    pred = np.asarray(pred)
    if gt.shape != pred.shape:
        raise ValueError(f"gt {gt.shape} and pred {pred.shape} must have the same shape")
    valid = gt > 0 if mask is None else (np.asarray(mask, dtype=bool) & (gt > 0))
    g = gt[valid].astype(np.float64)
    p = pred[valid].astype(np.float64)
    if g.size == 0:
        raise EmptyMaskError("no valid ground-truth pixel")
    ratio = 1.0
    if median_scaling:
        p, ratio = median_scale(p, g)
    p = clip_depth(p, min_depth, max_depth)
    return compute_errors(g, p), ratio


# ---- aggregation -----------------------------------------------------------------------------------


@dataclass(frozen=True)
class Summary:
    """Mean and (population) standard deviation of per-image metrics over ``count`` images."""

    mean: dict[str, float]
    std: dict[str, float]
    count: int

    def as_dict(self) -> dict[str, Any]:
        return {"mean": dict(self.mean), "std": dict(self.std), "count": self.count}


def stack_per_image(records: Sequence[Mapping[str, float]]) -> dict[str, np.ndarray]:
    """List of per-image metric dicts → ``{name: (N,) float64}`` for every key of the first record
    (metric names first); an empty list gives empty arrays for every metric name."""
    if not records:
        return {n: np.zeros(0) for n in METRIC_NAMES}
    names = [n for n in METRIC_NAMES if n in records[0]]
    extra = [k for k in records[0] if k not in METRIC_NAMES]
    return {k: np.array([r[k] for r in records], dtype=np.float64) for k in names + extra}


def aggregate(per_image: Mapping[str, Sequence[float]] | Sequence[Mapping[str, float]]) -> Summary:
    """Mean over images (and std, ddof=0) of each metric in :data:`METRIC_NAMES`.

    per_image: ``{name: (N,)}`` arrays or a list of N per-image dicts. Keys other than the metric
    names (e.g. ``ratio``) are ignored. An empty input gives NaN means and ``count`` 0.
    """
    arrays = stack_per_image(per_image) if not isinstance(per_image, Mapping) else per_image
    mean: dict[str, float] = {}
    std: dict[str, float] = {}
    count = 0
    for name in METRIC_NAMES:
        if name not in arrays:
            continue
        v = np.asarray(arrays[name], dtype=np.float64)
        count = int(v.size)
        mean[name] = float(v.mean()) if v.size else float("nan")
        std[name] = float(v.std()) if v.size else float("nan")
    return Summary(mean=mean, std=std, count=count)


def mean_of_rows(rows: Sequence[Mapping[str, float]]) -> dict[str, float]:
    """Unweighted mean of metric rows (e.g. per-scene means → one average row)."""
    return {n: float(np.mean([r[n] for r in rows])) for n in METRIC_NAMES if rows and n in rows[0]}
