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
from f2depth.camera import intrinsics
from f2depth.depth.predict import depth_from_disparity, predict_disparity, resize_disparity
from f2depth.errors import DataError
from f2depth.formats.writable import check_output_folder
from f2depth.inference.backends import DepthBackend, size_mismatch
from f2depth.inference.outputs import MM_MAX, SUFFIXES, mm_clipped, write_frame
from f2depth.inference.scaling import median_ratio, read_reference_depth
from f2depth.ingest.sources import Frame, decode_shortfall
from f2depth.io import atomic_dir, folder_lock, write_json
from f2depth.protocols.inputs import batched, to_input

UPSAMPLE_MODES = ("bilinear", "nearest")
#: The factors a depth may be multiplied by: the network's depth lies in 0.1–10 "metres", so a metric scale
#: outside these bounds is a mistake (units) and would make float32 depth infinite or zero.
MIN_SCALE, MAX_SCALE = 1e-6, 1e6


def check_scale(scale: float, source: str = "--scale") -> None:
    """DataError naming ``source`` unless ``scale`` is finite and within MIN_SCALE..MAX_SCALE."""
    if not (math.isfinite(scale) and MIN_SCALE <= scale <= MAX_SCALE):
        raise DataError(source, f"depth scale {scale:.4g} is outside {MIN_SCALE:g}..{MAX_SCALE:g} (the "
                                "network's depth lies in 0.1–10 m; a factor beyond these is a unit mistake "
                                "and makes float32 depth infinite or zero)",
                        "give a factor within those bounds")


class Predictor:
    """Relative depth of RGB images of any size with a :class:`DepthBackend`.

    ``post_process``: Monodepth's flip post-processing (the batch is run twice, plain and flipped, and
    the disparities blended, ``f2depth.depth.predict.flip_post_process``); ``upsample``: how the disparity
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
    clouds with ``K_args`` (fx, fy, cx, cy; None entries take defaults, see f2depth.camera.intrinsics)."""

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

    The output folder holds one run's files only: it is created and checked to be writable before
    anything is predicted, locked against a second run into it (:func:`f2depth.io.folder_lock`), built
    aside and swapped in at the end — or, when the run stops early, as soon as it stops, with the frames
    completed so far and no ``predict.json`` — and it replaces only an empty folder or an earlier
    predict's (:func:`f2depth.io.check_replaceable`; one of before the marker: :func:`earlier_predict`).
    ``total``: the number of frames the source announces; fewer decoded frames (a truncated video) are
    reported in the summary's ``warnings``. ``renamed``: input → output stem where inputs share a stem
    (a.png, a.jpg; the source's ``renamed``), recorded in the summary and said in one warning.
    """
    if settings.scale is not None and settings.scale_from is not None:
        raise ValueError("give scale or scale_from, not both")
    if settings.scale is not None and not (math.isfinite(settings.scale) and settings.scale > 0):
        raise ValueError(f"scale must be finite and > 0, got {settings.scale}")
    if settings.scale is not None:
        check_scale(settings.scale)
    reference = read_reference_depth(settings.scale_from) if settings.scale_from is not None else None
    scale = settings.scale if settings.scale is not None else 1.0
    out_dir = check_output_folder(settings.output_dir)
    if out_dir.is_symlink():  # one lock and one swap for every spelling of the folder
        out_dir = out_dir.resolve()
    with (folder_lock(out_dir),
          atomic_dir(out_dir, "predict", previous=earlier_predict, keep_partial=True) as building):
        return _predict_into(building, frames, predictor, settings, reference, scale, total, input_desc,
                             renamed)


def earlier_predict(folder: Path) -> bool:
    """Whether ``folder`` looks like a predict output written before the output marker existed: files named
    ``predict.json`` or ``<name>_depth.npy`` (and the other outputs' suffixes) only."""
    ends = tuple(SUFFIXES.values())
    return all(e.is_file() and (e.name == "predict.json" or e.name.endswith(ends)) for e in folder.iterdir())


def _predict_into(out_dir: Path, frames: Iterable[Frame], predictor: Predictor, settings: PredictSettings,
                  reference: np.ndarray | None, scale: float, total: int | None, input_desc: str,
                  renamed: dict[str, str] | None) -> dict[str, Any]:
    """:func:`run_predict`'s work, writing into ``out_dir`` (the folder being built)."""
    count, sizes, first_origin, clipped = 0, set(), None, 0
    disable = None if settings.progress is None else not settings.progress
    bar = tqdm(total=total or None, desc="predict", unit="frame", disable=disable)
    try:
        for batch in batched(frames, settings.batch_size):
            threads.adapt()
            depths = predictor.predict([f.rgb for f in batch], [f.origin for f in batch])
            if reference is not None and first_origin is None:
                scale = median_ratio(depths[0], reference, str(settings.scale_from))
                check_scale(scale, f"the median ratio to {settings.scale_from}")
            for frame, depth in zip(batch, depths):
                first_origin = first_origin or frame.origin
                K = intrinsics(*depth.shape, **settings.K_args) if settings.ply else None
                metric = depth * np.float32(scale)
                bad = int(np.count_nonzero(~(np.isfinite(metric) & (metric > 0))))
                if bad:  # float32 holds 1.2e-38 .. 3.4e38: an extreme factor gives inf or 0
                    raise DataError(frame.origin, f"depth × scale {scale:.4g} leaves {bad} of {metric.size} "
                                    "depth values infinite or zero in float32; nothing is written for this "
                                    "frame", f"give a scale within {MIN_SCALE:g}..{MAX_SCALE:g}")
                write_frame(out_dir, frame.name, metric, frame.rgb, K)
                clipped += mm_clipped(metric)
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
    short = decode_shortfall(input_desc or "the input", count, total or 0)  # a truncated video
    if short is not None:
        warnings.append(short)
    mismatch = size_mismatch(predictor.backend)  # an export at another size than the model's
    if mismatch is not None:
        warnings.append(mismatch)
    if clipped:
        warnings.append(f"{clipped} pixel(s) lie beyond {MM_MAX / 1000:g} m or below 1 mm: their value in "
                        f"<name>{SUFFIXES['mm']} is clipped to {MM_MAX} or 1 mm (65535 and 0 mean no depth); "
                        "<name>_depth.npy holds the metres")
    summary = {
        "input": input_desc, "frames": count, "frames_expected": total, "backend": predictor.backend.name,
        "model": predictor.backend.source, "network_hw": list(predictor.backend.input_hw),
        "trained_hw": list(getattr(predictor.backend, "trained_hw", None) or []) or None,
        "post_process": predictor.post_process, "upsample": predictor.upsample, "scale": scale,
        "scale_source": ("median ratio to " + str(settings.scale_from) + " on " + str(first_origin)
                         if reference is not None else "--scale" if settings.scale is not None else "none"),
        "metric": reference is not None or settings.scale is not None,
        "intrinsics": ({f"{h}x{w}": intrinsics(h, w, **settings.K_args).tolist() for h, w in sorted(sizes)}
                       if settings.ply else None),
        "files": {k: "<name>" + v for k, v in SUFFIXES.items() if k != "ply" or settings.ply},
        "depth_mm": {"no_depth": 0, "min": 1, "max": MM_MAX, "clipped_pixels": clipped,
                     "note": f"uint16 millimetres; depth beyond {MM_MAX} mm is written as {MM_MAX} and below "
                             "1 mm as 1, so that no depth is ever read back as missing (0, or 65535 in "
                             "7-Scenes' convention)"},
        "renamed": dict(renamed or {}),
        "orientation": "EXIF orientation applied (OpenCV): depth maps are in the orientation images are "
                       "shown in; a video's rotation metadata as OpenCV applies it",
        "warnings": warnings,
    }
    write_json(out_dir / "predict.json", summary)
    return summary

