"""NYU Depth V2 test protocol, as P²Net's ``evaluation/nyuv2_eval_depth.py`` does it.

Per image: crop rgb and ground truth to the Eigen crop (rows 44:471, cols 40:601, 427×561), resize
the rgb crop to the network size (288×384; INTER_AREA by default like our training images, PIL LANCZOS
as P²Net by option, see ``f2depth.data.images.INTERPOLATIONS``), predict (optionally with flip
post-processing), upsample the disparity to the crop (nearest, as P²Net; bilinear by option) *before*
the PP blend, depth = 1/disp, valid where gt > 0 (and ≤ ``max_gt_depth`` if given; P²Net has no cap),
median-scale, clip to [0.1, 10] m, eight metrics. Dataset metrics are the mean over images.

Samples (from ``f2depth.data``), read by attribute (or mapping key, or position in a plain tuple):
``index`` (0, optional: the running position is used when absent), ``rgb`` (1) (H,W,3) uint8,
``depth`` (2) (H,W) float32 metres with 0 = invalid (NaN or inf → DataError), ``scene`` (3, optional).
Images without a valid pixel are skipped and logged in one warning line.
"""

from __future__ import annotations

from collections.abc import Collection, Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from tqdm import tqdm

from f2depth.eval.inputs import batched, check_finite_gt, check_rgb, report_skipped, run_batch, to_input
from f2depth.eval.inputs import field as sample_field
from f2depth.eval.metrics import (
    EmptyMaskError,
    PredictDisp,
    Summary,
    aggregate,
    clip_depth,
    depth_from_disparity,
    image_metrics,
    stack_per_image,
)

CROPS: dict[str, tuple[int, int, int, int] | None] = {
    "eigen": (44, 471, 40, 601),  # NYU toolbox mask(45:471, 41:601), 1-based inclusive → 427×561
    "eigen_sc": (45, 471, 41, 601),  # SC-Depth's eval_depth.py / ZoeDepth's compute_metrics, 426×560
    "none": None,
}
"""Crops as (top, bottom, left, right), 0-based, end exclusive."""


def resolve_crop(crop: str | tuple[int, int, int, int] | None) -> tuple[int, int, int, int] | None:
    """``"eigen"`` | ``"eigen_sc"`` | ``"none"`` | None | (top, bottom, left, right) → a tuple or None."""
    if crop is None:
        return None
    if isinstance(crop, str):
        if crop not in CROPS:
            raise ValueError(
                f"unknown NYU crop {crop!r}; use one of {sorted(CROPS)} or (top, bottom, left, right)"
            )
        return CROPS[crop]
    t, b, l, r = (int(v) for v in crop)
    if not (0 <= t < b and 0 <= l < r):
        raise ValueError(f"crop {crop} must be (top, bottom, left, right) with top < bottom, left < right")
    return t, b, l, r


@dataclass
class NyuResult:
    """Dataset metrics plus the per-image arrays (for figures and significance tests)."""

    summary: Summary
    per_image: dict[str, np.ndarray]  # metric name (and "ratio") → (N,) float64, in sample order
    index: np.ndarray  # (N,) int64 sample indices
    scene: list[str]
    skipped: list[int] = field(default_factory=list)  # indices without any valid gt pixel
    settings: dict[str, Any] = field(default_factory=dict)
    predictions: dict[int, np.ndarray] = field(default_factory=dict)  # index → scaled, clipped depth (H,W)

    @property
    def metrics(self) -> dict[str, float]:
        return dict(self.summary.mean)

    def to_json(self) -> dict[str, Any]:
        ratio = self.per_image.get("ratio", np.zeros(0))
        return {
            "metrics": self.metrics,
            "std": dict(self.summary.std),
            "count": self.summary.count,
            "ratio_median": float(np.median(ratio)) if ratio.size else None,
            "ratio_std": float(np.std(ratio)) if ratio.size else None,
            "skipped": list(self.skipped),
            "settings": dict(self.settings),
        }


def evaluate_nyu(
    samples: Iterable[Any],
    predict_disp: PredictDisp,
    *,
    height: int = 288,
    width: int = 384,
    crop: str | tuple[int, int, int, int] | None = "eigen",
    interpolation: str = "area",
    upsample: str = "nearest",
    post_process: bool = False,
    median_scaling: bool = True,
    min_depth: float = 0.1,
    max_depth: float = 10.0,
    max_gt_depth: float | None = None,
    batch_size: int = 1,
    device: str = "cpu",
    keep: Collection[int] = (),
    progress: bool = False,
) -> NyuResult:
    """Evaluate ``predict_disp`` on NYU test samples with P²Net's protocol (module docstring).

    predict_disp: ``img (B,3,height,width) in [0,1] → disp (B,1,h,w)``, depth ∝ 1/disp.
    interpolation: input resize filter, ``area`` (OpenCV, as our training images) or ``lanczos`` (PIL,
    P²Net's exact filter); see ``f2depth.data.images.INTERPOLATIONS``. keep: sample indices whose
    final depth map is returned in ``predictions``. Returns a :class:`NyuResult`.
    """
    box = resolve_crop(crop)
    settings = {
        "height": height, "width": width, "crop": list(box) if box else None, "interpolation": interpolation,
        "upsample": upsample, "post_process": post_process, "median_scaling": median_scaling,
        "min_depth": min_depth, "max_depth": max_depth, "max_gt_depth": max_gt_depth,
    }  # fmt: skip
    keep = set(keep)
    records: list[dict[str, float]] = []
    indices: list[int] = []
    scenes: list[str] = []
    skipped: list[int] = []
    predictions: dict[int, np.ndarray] = {}
    counter = 0

    def prepared(sample: Any) -> tuple[int, str, Any, np.ndarray]:
        nonlocal counter
        try:
            idx = int(sample_field(sample, "index", 0))
        except TypeError:
            idx = counter
        counter += 1
        rgb = check_rgb(sample_field(sample, "rgb", 1), f"NYU sample {idx}")
        gt = np.asarray(sample_field(sample, "depth", 2), dtype=np.float32)
        check_finite_gt(gt, f"NYU sample {idx}")
        if gt.shape != rgb.shape[:2]:
            raise ValueError(f"NYU sample {idx}: depth {gt.shape} does not match rgb {rgb.shape[:2]}")
        try:
            scene = str(sample_field(sample, "scene", 3))
        except TypeError:
            scene = ""
        if box is not None:
            t, b, l, r = box
            if b > gt.shape[0] or r > gt.shape[1]:
                raise ValueError(f"NYU sample {idx}: crop {box} does not fit an image of {gt.shape}")
            rgb, gt = rgb[t:b, l:r], gt[t:b, l:r]
        return idx, scene, to_input(rgb, (height, width), interpolation), gt

    for chunk in batched(tqdm(samples, desc="NYU", disable=not progress), batch_size):
        items = [prepared(s) for s in chunk]
        for group in _same_shape_groups(items):
            disp = run_batch(
                predict_disp, [it[2] for it in group], device=device, post_process=post_process,
                out_hw=group[0][3].shape, upsample=upsample,
            )  # fmt: skip
            for (idx, scene, _, gt), d in zip(group, disp):
                pred = depth_from_disparity(d)
                mask = gt > 0 if max_gt_depth is None else (gt > 0) & (gt <= max_gt_depth)
                try:
                    m, ratio = image_metrics(
                        gt,
                        pred,
                        mask,
                        median_scaling=median_scaling,
                        min_depth=min_depth,
                        max_depth=max_depth,
                    )
                except EmptyMaskError:
                    skipped.append(idx)
                    continue
                records.append({**m, "ratio": ratio})
                indices.append(idx)
                scenes.append(scene)
                if idx in keep:
                    predictions[idx] = clip_depth(pred * ratio, min_depth, max_depth).astype(np.float32)
    report_skipped("NYU", skipped, len(records))
    per_image = stack_per_image(records)
    return NyuResult(
        summary=aggregate(per_image), per_image=per_image, index=np.asarray(indices, dtype=np.int64),
        scene=scenes, skipped=skipped, settings=settings, predictions=predictions,
    )  # fmt: skip


def _same_shape_groups(
    items: list[tuple[int, str, Any, np.ndarray]],
) -> list[list[tuple[int, str, Any, np.ndarray]]]:
    """Split a batch where ground-truth shapes change (network inputs all share one size)."""
    groups: list[list[tuple[int, str, Any, np.ndarray]]] = []
    for it in items:
        if groups and groups[-1][0][3].shape == it[3].shape:
            groups[-1].append(it)
        else:
            groups.append([it])
    return groups
