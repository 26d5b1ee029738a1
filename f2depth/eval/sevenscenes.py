"""7-Scenes zero-shot protocol (the paper §4.1 and §4.2.2; Shotton et al., CVPR 2013).

Per frame: the full 480×640 rgb resized to the network size (288×384), predict (optionally with flip
post-processing), upsample the disparity to the ground-truth size (nearest by default, as P²Net's
ScanNet evaluation), depth = 1/disp, valid where ``min_gt_depth < gt ≤ max_gt_depth`` (default (0, 10] m;
0 and the 65535 mm code are invalid), median-scale, clip to [0.1, 10] m, eight metrics.

Rows: one per scene (mean over its frames), then two summary rows:
- ``average``: the **unweighted mean of the scene rows** (each scene counts once);
- ``frame_weighted``: the mean over all frames (= scene rows weighted by their frame counts).
The paper's "Average" row (Table 2) is reproduced by the *frame-weighted* mean of its scene rows
with the official test counts (:data:`TEST_FRAMES`), not by the unweighted one: compare with
``frame_weighted`` (see tests/test_eval_published.py).

Samples (from ``f2depth.data``), read by attribute or mapping key: ``rgb`` (H,W,3) uint8, ``depth``
(H,W) float metres with 0 = invalid (an integer array is taken as the raw PNG in millimetres, 65535
invalid; NaN or inf metres count as invalid too, and their count is logged in one warning line),
``scene`` (str), ``seq`` and ``frame`` (identifiers, any type). Frames without a valid pixel are skipped
and logged.
"""

from __future__ import annotations

import logging
from collections.abc import Collection, Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from tqdm import tqdm

from f2depth.eval.inputs import batched, check_rgb, nonfinite_count, report_skipped, run_batch, to_input
from f2depth.eval.inputs import field as sample_field
from f2depth.eval.metrics import (
    METRIC_NAMES,
    EmptyMaskError,
    PredictDisp,
    Summary,
    aggregate,
    clip_depth,
    depth_from_disparity,
    image_metrics,
    mean_of_rows,
    stack_per_image,
)

TEST_FRAMES: dict[str, int] = {
    "chess": 2000, "fire": 2000, "heads": 1000, "office": 4000, "pumpkin": 2000, "redkitchen": 5000,
    "stairs": 1000,
}  # fmt: skip
"""Frames in the official test sequences (TestSplit.txt) per scene; 17,000 in all (the paper §4.1)."""

INVALID_MM = 65535
AVERAGE_ROW = "Average"
ALL_FRAMES_ROW = "All frames"
log = logging.getLogger(__name__)


def depth_metres(depth: Any) -> np.ndarray:
    """Ground truth → float32 metres with 0 = invalid. Integer input is millimetres (65535 → 0);
    float input is already metres (NaN → 0). Shape (H,W) unchanged."""
    d = np.asarray(depth)
    if np.issubdtype(d.dtype, np.integer):
        out = d.astype(np.float32) / 1000.0
        out[d == INVALID_MM] = 0.0
        return out
    out = d.astype(np.float32)
    out[~np.isfinite(out)] = 0.0
    return out


def valid_mask(gt: np.ndarray, min_gt_depth: float = 0.0, max_gt_depth: float = 10.0) -> np.ndarray:
    """gt (H,W) metres → bool mask of ``min_gt_depth < gt ≤ max_gt_depth``."""
    return (gt > min_gt_depth) & (gt <= max_gt_depth)


@dataclass
class SevenScenesResult:
    scenes: dict[str, Summary]  # scene → mean/std over its frames, scenes sorted by name
    average: dict[str, float]  # unweighted mean of the scene rows
    frame_weighted: Summary  # mean over all frames
    per_image: dict[str, np.ndarray]  # metric name (and "ratio") → (N,)
    scene: list[str]
    seq: list[Any]
    frame: list[Any]
    skipped: list[tuple[str, Any, Any]] = field(default_factory=list)  # frames without a valid pixel
    settings: dict[str, Any] = field(default_factory=dict)
    predictions: dict[tuple[str, Any, Any], np.ndarray] = field(default_factory=dict)

    def rows(self) -> list[dict[str, Any]]:
        """Table rows: ``{"scene", "frames", <metrics>}`` per scene, then ``Average`` (mean of scene
        rows) and ``All frames`` (frame-weighted)."""
        out: list[dict[str, Any]] = [
            {"scene": s, "frames": v.count, **v.mean} for s, v in self.scenes.items()
        ]
        out.append({"scene": AVERAGE_ROW, "frames": self.frame_weighted.count, **self.average})
        out.append({"scene": ALL_FRAMES_ROW, "frames": self.frame_weighted.count, **self.frame_weighted.mean})
        return out

    def to_json(self) -> dict[str, Any]:
        return {
            "average": dict(self.average),
            "frame_weighted": self.frame_weighted.as_dict(),
            "scenes": {s: v.as_dict() for s, v in self.scenes.items()},
            "skipped": [list(map(str, k)) for k in self.skipped],
            "settings": dict(self.settings),
        }


def evaluate_sevenscenes(
    samples: Iterable[Any],
    predict_disp: PredictDisp,
    *,
    height: int = 288,
    width: int = 384,
    interpolation: str = "area",
    upsample: str = "nearest",
    post_process: bool = False,
    median_scaling: bool = True,
    min_depth: float = 0.1,
    max_depth: float = 10.0,
    min_gt_depth: float = 0.0,
    max_gt_depth: float = 10.0,
    batch_size: int = 1,
    device: str = "cpu",
    keep: Collection[tuple[str, Any, Any]] = (),
    progress: bool = False,
) -> SevenScenesResult:
    """Evaluate ``predict_disp`` on 7-Scenes test frames (module docstring).

    predict_disp: ``img (B,3,height,width) in [0,1] → disp (B,1,h,w)``. keep: ``(scene, seq, frame)``
    keys whose final depth map (H,W) is returned in ``predictions``.
    """
    settings = {
        "height": height, "width": width, "interpolation": interpolation, "upsample": upsample,
        "post_process": post_process, "median_scaling": median_scaling, "min_depth": min_depth,
        "max_depth": max_depth, "min_gt_depth": min_gt_depth, "max_gt_depth": max_gt_depth,
    }  # fmt: skip
    keep = set(keep)
    records: list[dict[str, float]] = []
    keys: list[tuple[str, Any, Any]] = []
    skipped: list[tuple[str, Any, Any]] = []
    predictions: dict[tuple[str, Any, Any], np.ndarray] = {}

    nonfinite = {"pixels": 0, "frames": 0, "first": None}

    def prepared(sample: Any) -> tuple[tuple[str, Any, Any], Any, np.ndarray]:
        key = (str(sample_field(sample, "scene")), sample_field(sample, "seq"), sample_field(sample, "frame"))
        rgb = check_rgb(sample_field(sample, "rgb"), f"7-Scenes {key}")
        raw = sample_field(sample, "depth")
        bad = nonfinite_count(raw)  # NaN/inf metres count as missing (depth_metres), and are reported
        if bad:
            nonfinite["pixels"] += bad
            nonfinite["frames"] += 1
            nonfinite["first"] = nonfinite["first"] or key
        gt = depth_metres(raw)
        if gt.ndim != 2:
            raise ValueError(f"7-Scenes {key}: depth must be (H,W), got {gt.shape}")
        return key, to_input(rgb, (height, width), interpolation), gt

    for chunk in batched(tqdm(samples, desc="7-Scenes", disable=not progress), batch_size):
        items = [prepared(s) for s in chunk]
        groups: list[list[tuple[tuple[str, Any, Any], Any, np.ndarray]]] = []
        for it in items:
            if groups and groups[-1][0][2].shape == it[2].shape:
                groups[-1].append(it)
            else:
                groups.append([it])
        for group in groups:
            disp = run_batch(
                predict_disp, [it[1] for it in group], device=device, post_process=post_process,
                out_hw=group[0][2].shape, upsample=upsample,
            )  # fmt: skip
            for (key, _, gt), d in zip(group, disp):
                pred = depth_from_disparity(d)
                try:
                    m, ratio = image_metrics(
                        gt, pred, valid_mask(gt, min_gt_depth, max_gt_depth),
                        median_scaling=median_scaling, min_depth=min_depth, max_depth=max_depth,
                    )  # fmt: skip
                except EmptyMaskError:
                    skipped.append(key)
                    continue
                records.append({**m, "ratio": ratio})
                keys.append(key)
                if key in keep:
                    predictions[key] = clip_depth(pred * ratio, min_depth, max_depth).astype(np.float32)

    if nonfinite["pixels"]:
        log.warning("7-Scenes: %d ground-truth pixels in %d frame(s) are NaN or inf and count as missing "
                    "depth (first frame: %s)", nonfinite["pixels"], nonfinite["frames"], nonfinite["first"])
    report_skipped("7-Scenes", skipped, len(records))
    per_image = stack_per_image(records)
    scene_names = [k[0] for k in keys]
    scenes: dict[str, Summary] = {}
    for s in sorted(set(scene_names)):
        sel = np.array([n == s for n in scene_names])
        scenes[s] = aggregate({n: per_image[n][sel] for n in METRIC_NAMES})
    return SevenScenesResult(
        scenes=scenes, average=mean_of_rows([v.mean for v in scenes.values()]),
        frame_weighted=aggregate(per_image), per_image=per_image, scene=scene_names,
        seq=[k[1] for k in keys], frame=[k[2] for k in keys], skipped=skipped, settings=settings,
        predictions=predictions,
    )  # fmt: skip
