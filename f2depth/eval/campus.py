"""Campus Indoor protocol: sparse laser-measured points (the paper §4.1, §4.2.3; Tables 3 and 4).

Per image: the full image resized to the network size (288×384; a portrait image uses 384×288 when
``keep_orientation``, so it is not squashed), predict (optionally with flip post-processing, blended at
the network resolution), sample the disparity at the points' pixel positions with bilinear
interpolation, depth = 1/disp, valid points gt > 0 (and ≤ ``max_gt_depth`` if given), median-scale over
the points, clip to [0.1, 10] m, eight metrics over the points. Scene row = mean over its images;
``average`` = mean over the scene rows (the paper's Table 3 "average results of 18 scenes" equals the
mean of its Table 4 scene rows). Also reported: the mean over images and the metrics pooled over all
points (after each image's own scaling), since ~15 points per image make these differ.

Sampling: a point (u, v) of a W×H image (pixel centres at integer coordinates) is read from the
network-resolution map at x = (u + 0.5)·w/W − 0.5, y = (v + 0.5)·h/H − 0.5, bilinearly, clamped at the
border. That is exactly the value the bilinearly upsampled map (``align_corners=False``) has at integer
(u, v), without building a full-resolution map (camera photos can be 6240×4160).

Samples (from ``f2depth.data``), read by attribute, mapping key or plain-tuple position: ``scene`` (0),
``image`` (1; alias ``name``), ``rgb`` (2) (H,W,3) uint8, ``points`` (3) (K,3) float = u, v, depth_m.
"""

from __future__ import annotations

from collections.abc import Collection, Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from tqdm import tqdm

from f2depth.eval.inputs import check_finite_gt, check_rgb, report_skipped, run_batch, to_input
from f2depth.eval.inputs import field as sample_field
from f2depth.eval.metrics import (
    METRIC_NAMES,
    EmptyMaskError,
    PredictDisp,
    Summary,
    aggregate,
    clip_depth,
    compute_errors,
    depth_from_disparity,
    image_metrics,
    mean_of_rows,
    stack_per_image,
)


def sample_at_points(disp: Any, uv: np.ndarray, image_hw: tuple[int, int]) -> np.ndarray:
    """Bilinear sample of a low-resolution map at pixel positions of the full image.

    disp: (h,w) map (NumPy or torch) covering the same view as the image; uv: (K,2) pixel coordinates
    (u = column, v = row) in an image of ``image_hw = (H, W)``. Returns (K,) float64.
    """
    d = torch.as_tensor(np.asarray(disp, dtype=np.float64) if not isinstance(disp, torch.Tensor) else disp)
    d = d.to(torch.float64).reshape(1, 1, *d.shape[-2:])
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    H, W = image_hw
    gx = (2.0 * uv[:, 0] + 1.0) / W - 1.0
    gy = (2.0 * uv[:, 1] + 1.0) / H - 1.0
    grid = torch.from_numpy(np.stack([gx, gy], -1)).reshape(1, 1, -1, 2)
    out = F.grid_sample(d, grid, mode="bilinear", padding_mode="border", align_corners=False)
    return out.reshape(-1).numpy()


def network_size(
    image_hw: tuple[int, int], height: int, width: int, keep_orientation: bool
) -> tuple[int, int]:
    """(height, width), swapped for a portrait image when ``keep_orientation`` and the size is landscape."""
    portrait = image_hw[0] > image_hw[1]
    if keep_orientation and portrait != (height > width) and height != width:
        return width, height
    return height, width


def _scene_key(s: str) -> tuple[int, int | str]:
    return (0, int(s)) if s.isdigit() else (1, s)


@dataclass
class CampusResult:
    scenes: dict[str, Summary]  # scene → mean/std over its images (numeric scene names in numeric order)
    average: dict[str, float]  # unweighted mean of the scene rows (the paper's number)
    image_mean: Summary  # mean over all images
    pooled: dict[str, float]  # metrics over all points of all images at once
    per_image: dict[str, np.ndarray]  # metric name, "ratio", "points" → (N,)
    scene: list[str]
    image: list[str]
    skipped: list[tuple[str, str]] = field(default_factory=list)  # images without a valid point
    settings: dict[str, Any] = field(default_factory=dict)
    predictions: dict[tuple[str, str], np.ndarray] = field(default_factory=dict)  # network-size depth maps

    def rows(self) -> list[dict[str, Any]]:
        """``{"scene", "images", <metrics>}`` per scene, then ``Average`` (mean of the scene rows)."""
        out: list[dict[str, Any]] = [
            {"scene": s, "images": v.count, **v.mean} for s, v in self.scenes.items()
        ]
        out.append({"scene": "Average", "images": self.image_mean.count, **self.average})
        return out

    def to_json(self) -> dict[str, Any]:
        return {
            "average": dict(self.average),
            "image_mean": self.image_mean.as_dict(),
            "pooled": dict(self.pooled),
            "points": int(self.per_image["points"].sum()) if "points" in self.per_image else 0,
            "scenes": {s: v.as_dict() for s, v in self.scenes.items()},
            "skipped": [list(k) for k in self.skipped],
            "settings": dict(self.settings),
        }


def evaluate_campus(
    samples: Iterable[Any],
    predict_disp: PredictDisp,
    *,
    height: int = 288,
    width: int = 384,
    keep_orientation: bool = True,
    interpolation: str = "area",
    post_process: bool = False,
    median_scaling: bool = True,
    min_depth: float = 0.1,
    max_depth: float = 10.0,
    max_gt_depth: float | None = None,
    device: str = "cpu",
    keep: Collection[tuple[str, str]] = (),
    progress: bool = False,
) -> CampusResult:
    """Evaluate ``predict_disp`` on Campus Indoor images at their points (module docstring).

    predict_disp: ``img (1,3,h,w) in [0,1] → disp (1,1,h,w)``; images run one at a time (sizes differ).
    keep: ``(scene, image)`` keys whose scaled, clipped network-size depth map goes to ``predictions``.
    """
    settings = {
        "height": height, "width": width, "keep_orientation": keep_orientation,
        "interpolation": interpolation, "post_process": post_process, "median_scaling": median_scaling,
        "min_depth": min_depth, "max_depth": max_depth, "max_gt_depth": max_gt_depth,
    }  # fmt: skip
    keep = set(keep)
    records: list[dict[str, float]] = []
    keys: list[tuple[str, str]] = []
    skipped: list[tuple[str, str]] = []
    pooled_gt: list[np.ndarray] = []
    pooled_pred: list[np.ndarray] = []
    predictions: dict[tuple[str, str], np.ndarray] = {}

    for sample in tqdm(samples, desc="Campus", disable=not progress):
        key = (
            str(sample_field(sample, "scene", 0)),
            str(sample_field(sample, "image", 1, aliases=("name",))),
        )
        rgb = check_rgb(sample_field(sample, "rgb", 2), f"Campus {key}")
        pts = np.asarray(sample_field(sample, "points", 3), dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise ValueError(f"Campus {key}: points must be (K,3) = u, v, depth_m, got {pts.shape}")
        check_finite_gt(pts, f"Campus {key}")
        H, W = rgb.shape[:2]
        outside = (pts[:, 0] < -0.5) | (pts[:, 0] > W - 0.5) | (pts[:, 1] < -0.5) | (pts[:, 1] > H - 0.5)
        if np.any(outside):
            raise ValueError(
                f"Campus {key}: {int(outside.sum())} point(s) lie outside the {W}×{H} image; "
                "u is the column and v the row in pixels of this image (check points.csv)"
            )
        hw = network_size((H, W), height, width, keep_orientation)
        disp = run_batch(
            predict_disp, [to_input(rgb, hw, interpolation)], device=device, post_process=post_process
        )[0]
        pred = depth_from_disparity(sample_at_points(disp, pts[:, :2], (H, W)))
        gt = pts[:, 2]
        mask = gt > 0 if max_gt_depth is None else (gt > 0) & (gt <= max_gt_depth)
        try:
            m, ratio = image_metrics(
                gt, pred, mask, median_scaling=median_scaling, min_depth=min_depth, max_depth=max_depth
            )
        except EmptyMaskError:
            skipped.append(key)
            continue
        records.append({**m, "ratio": ratio, "points": float(mask.sum())})
        keys.append(key)
        pooled_gt.append(gt[mask])
        pooled_pred.append(clip_depth(pred[mask] * ratio, min_depth, max_depth))
        if key in keep:
            predictions[key] = clip_depth(depth_from_disparity(disp) * ratio, min_depth, max_depth).astype(
                np.float32
            )

    report_skipped("Campus", skipped, len(records))
    per_image = stack_per_image(records)
    scene_names = [k[0] for k in keys]
    scenes: dict[str, Summary] = {}
    for s in sorted(set(scene_names), key=_scene_key):
        sel = np.array([n == s for n in scene_names])
        scenes[s] = aggregate({n: per_image[n][sel] for n in METRIC_NAMES})
    pooled = compute_errors(np.concatenate(pooled_gt), np.concatenate(pooled_pred)) if pooled_gt else {}
    return CampusResult(
        scenes=scenes, average=mean_of_rows([v.mean for v in scenes.values()]),
        image_mean=aggregate(per_image), pooled=pooled, per_image=per_image, scene=scene_names,
        image=[k[1] for k in keys], skipped=skipped, settings=settings, predictions=predictions,
    )  # fmt: skip
