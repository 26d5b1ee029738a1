"""Depth of arbitrary images: resize to the network's size, predict (optionally with Monodepth's flip
post-processing), resize the disparity back to the input size, invert.

The networks are self-supervised, so their depth is *relative*: it lies in the network's nominal range
(``[min_depth, max_depth]`` metres) but the true scale of a scene is unknown. ``run_predict`` makes it
metric with a fixed factor (``scale``) or with the median ratio against a reference depth map of the
first frame (``scale_from``), and applies that one factor to every frame.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

from f2depth import threads
from f2depth.data.errors import DataError
from f2depth.data.writable import check_output_folder
from f2depth.eval.inputs import batched, to_input
from f2depth.eval.metrics import depth_from_disparity, predict_disparity, resize_disparity
from f2depth.inference.backends import DepthBackend
from f2depth.inference.outputs import SUFFIXES, intrinsics, write_frame
from f2depth.inference.scaling import median_ratio, read_reference_depth
from f2depth.inference.sources import Frame
from f2depth.io import write_json

UPSAMPLE_MODES = ("bilinear", "nearest")


class Predictor:
    """Relative depth of RGB images of any size with a :class:`DepthBackend`.

    ``post_process``: Monodepth's flip post-processing (the batch is run twice, plain and flipped, and
    the disparities blended, ``f2depth.eval.metrics.flip_post_process``); ``upsample``: how the disparity
    is resized back to the input size (bilinear or nearest).
    """

    def __init__(self, backend: DepthBackend, post_process: bool = False, upsample: str = "bilinear") -> None:
        if upsample not in UPSAMPLE_MODES:
            raise ValueError(f"upsample must be one of {UPSAMPLE_MODES}, got {upsample!r}")
        self.backend = backend
        self.post_process = post_process
        self.upsample = upsample

    def disparity(self, rgbs: Sequence[np.ndarray]) -> torch.Tensor:
        """RGB uint8 images (H_i,W_i,3) → disparity (B,1,h,w) at the network size (CPU)."""
        x = torch.stack([to_input(np.asarray(r), self.backend.input_hw) for r in rgbs])
        with torch.inference_mode():  # the backend's scaled disparity is 1/depth
            return predict_disparity(lambda img: 1.0 / self.backend.depth(img), x,
                                     post_process=self.post_process)

    def predict(self, rgbs: Sequence[np.ndarray], origins: Sequence[str] | None = None) -> list[np.ndarray]:
        """RGB uint8 images (H_i,W_i,3), sizes may differ → depth (H_i,W_i) float32 per image (relative).

        Every depth map is checked to be finite and positive: a broken model (NaN weights, a damaged
        export) → DataError naming the image (``origins[i]``, else its position) and the model.
        """
        if not rgbs:
            return []
        disp = self.disparity(rgbs)
        out = []
        for i, (d, rgb) in enumerate(zip(disp, rgbs)):
            full = resize_disparity(d[None], tuple(np.asarray(rgb).shape[:2]), self.upsample)
            depth = depth_from_disparity(full[0, 0]).astype(np.float32)
            bad = int(np.count_nonzero(~(np.isfinite(depth) & (depth > 0))))
            if bad:
                where = origins[i] if origins is not None else f"image {i} of the batch"
                raise DataError(where, f"the network predicted {bad} non-finite or non-positive depth "
                                       f"value(s) of {depth.size}; nothing is written for this frame",
                                f"the model {self.backend.source or self.backend.name} is broken (NaN "
                                "weights or a damaged export): retrain or re-export it")
            out.append(depth)
        return out


@dataclass
class PredictSettings:
    """What ``run_predict`` writes. ``scale`` and ``scale_from`` exclude each other; ``ply`` writes point
    clouds with ``K_args`` (fx, fy, cx, cy; None entries take defaults, see outputs.intrinsics)."""

    output_dir: Path
    batch_size: int = 4
    scale: float | None = None
    scale_from: Path | None = None
    ply: bool = False
    K_args: dict[str, float | None] = field(default_factory=dict)
    progress: bool | None = None  # None: a bar only when stderr is a terminal (tqdm's rule)


def run_predict(frames: Iterable[Frame], predictor: Predictor, settings: PredictSettings,
                total: int | None = None, input_desc: str = "",
                renamed: dict[str, str] | None = None) -> dict[str, Any]:
    """Predict every frame and write its files (outputs module) as soon as its batch is done, so an
    interrupted run leaves complete files only; finally ``predict.json`` (the run's summary). Returns it.

    The output folder is created and checked to be writable before anything is predicted. ``total``:
    the number of frames the source announces; fewer decoded frames (a truncated video) are reported in
    the summary's ``warnings``. ``renamed``: input → output stem where inputs share a stem (a.png, a.jpg;
    the source's ``renamed``), recorded in the summary and said in one warning.
    """
    if settings.scale is not None and settings.scale_from is not None:
        raise ValueError("give scale or scale_from, not both")
    if settings.scale is not None and not (math.isfinite(settings.scale) and settings.scale > 0):
        raise ValueError(f"scale must be finite and > 0, got {settings.scale}")
    reference = read_reference_depth(settings.scale_from) if settings.scale_from is not None else None
    scale = settings.scale if settings.scale is not None else 1.0
    out_dir = check_output_folder(settings.output_dir)
    count, sizes, first_origin = 0, set(), None
    disable = None if settings.progress is None else not settings.progress
    bar = tqdm(total=total or None, desc="predict", unit="frame", disable=disable)
    try:
        for batch in batched(frames, settings.batch_size):
            threads.adapt()
            depths = predictor.predict([f.rgb for f in batch], [f.origin for f in batch])
            if reference is not None and first_origin is None:
                scale = median_ratio(depths[0], reference, str(settings.scale_from))
            for frame, depth in zip(batch, depths):
                first_origin = first_origin or frame.origin
                K = intrinsics(*depth.shape, **settings.K_args) if settings.ply else None
                write_frame(out_dir, frame.name, depth * np.float32(scale), frame.rgb, K)
                sizes.add(depth.shape)
                count += 1
            bar.update(len(batch))
    finally:
        bar.close()
    warnings = []
    if renamed:
        first = next(iter(renamed.items()))
        warnings.append(f"{len(renamed)} input(s) share a file stem with another, so their outputs are "
                        f"named <stem>_<extension> (e.g. {first[0]} → {first[1]}_depth.npy); predict.json "
                        "lists them under 'renamed'")
    if total and count < total:  # a video whose container announces more frames than decode
        warnings.append(f"{input_desc or 'the input'}: only {count} of the {total} frames its container "
                        f"announces could be decoded (a truncated or damaged file?); wrote those {count}")
    summary = {
        "input": input_desc, "frames": count, "frames_expected": total, "backend": predictor.backend.name,
        "model": predictor.backend.source, "network_hw": list(predictor.backend.input_hw),
        "post_process": predictor.post_process, "upsample": predictor.upsample, "scale": scale,
        "scale_source": ("median ratio to " + str(settings.scale_from) + " on " + str(first_origin)
                         if reference is not None else "--scale" if settings.scale is not None else "none"),
        "metric": reference is not None or settings.scale is not None,
        "intrinsics": ({f"{h}x{w}": intrinsics(h, w, **settings.K_args).tolist() for h, w in sorted(sizes)}
                       if settings.ply else None),
        "files": {k: "<name>" + v for k, v in SUFFIXES.items() if k != "ply" or settings.ply},
        "renamed": dict(renamed or {}),
        "orientation": "EXIF orientation applied (OpenCV): depth maps are in the orientation images are "
                       "shown in; a video's rotation metadata as OpenCV applies it",
        "warnings": warnings,
    }
    write_json(out_dir / "predict.json", summary)
    return summary

