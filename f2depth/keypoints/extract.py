"""The ``keypoints`` stage's work: select keypoints on every prepared frame, in worker processes.

``source`` is the image the selector sees:

* ``full_resolution`` (default, as P²Net's ``datasets/nyu_dataset.py``): the frame's NYU raw file
  (``data.nyu_raw`` / frames.csv ``raw_file``), undistorted and cropped by prepare's own functions with
  camera.json's ``crop`` — the 448×608 full-resolution crop —, converted to grey. The preset's working
  size (P²Net: 640×480, bilinear) applies to it and the points are mapped to the training size with
  P²Net's integer arithmetic. Each raw frame is also re-prepared and compared with the prepared image, so a
  ``data.nyu_raw`` that is not the data prepare read fails loudly instead of giving misplaced points.
* ``prepared``: the prepared image at the training size (the behaviour before the full-resolution
  source; upsampling lowers the gradients, so a different set of pixels passes DSO's thresholds).

Frame ids in the output are the rows of frames.csv (``PreparedSet.frame_index``). With ``sequence``
the selector's cell size carries over from frame to frame within a scene (DSO's persistent selector;
one task per scene); otherwise every frame gets a fresh selector (P²Net).
"""

from __future__ import annotations

import os
import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from f2depth.camera import NYU_RAW_CAMERA, RawCamera
from f2depth.errors import DataError
from f2depth.formats.images import read_image
from f2depth.formats.nyu_raw import read_frame
from f2depth.formats.prepared import PreparedSet, resize_image, undistort_crop
from f2depth.io import write_rgb
from f2depth.keypoints.api import KeypointSelector
from f2depth.keypoints.overlay import draw_keypoints
from f2depth.keypoints.presets import get_preset
from f2depth.keypoints.store import save_keypoints
from f2depth.workers import map_jobs

CHUNK = 8  # frames per task without ``sequence``
SOURCES = ("full_resolution", "prepared")
#: Largest mean |Δ| (grey levels) between a prepared image and its raw frame prepared again; more means
#: the raw file is not the one prepare read (OpenCV versions differ by far less than one level).
MATCH_TOLERANCE = 1.0
_RAW_FIX = ("data.nyu_raw must be the NYU raw folder data.prepared was made from: fix it or re-run "
            "`dvc repro prepare`")


def full_resolution_gray(raw_path: str | os.PathLike, crop: int, camera: RawCamera = NYU_RAW_CAMERA
                         ) -> tuple[np.ndarray, np.ndarray]:
    """A raw frame of ``camera`` → (grey uint8 (H−2·crop, W−2·crop) of the undistorted crop, its RGB; NYU:
    (448, 608) for crop 16).

    The grey conversion is P²Net's ``cv2.cvtColor(RGB2GRAY)`` on the full-resolution crop (P²Net's
    ``datasets/nyu_dataset.py``).
    """
    path = Path(raw_path)
    if not path.is_file():
        raise DataError(path, "raw frame not found (frames.csv raw_file under data.nyu_raw)",
                        f"{_RAW_FIX}, or set keypoints.source: prepared")
    rgb = undistort_crop(read_frame(path, camera.hw), crop, camera)
    return cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY), rgb


def raw_mismatch(full_rgb: np.ndarray, prepared_rgb: np.ndarray, interpolation: str = "area") -> float:
    """Mean |Δ| (grey levels) between a prepared image (H, W, 3) and the full-resolution crop resized as
    prepare resizes it (with its ``interpolation``)."""
    again = resize_image(full_rgb, prepared_rgb.shape[:2], interpolation=interpolation)
    return float(np.abs(again.astype(np.int16) - prepared_rgb.astype(np.int16)).mean())


@dataclass(frozen=True)
class _Task:
    images: list[str]  # prepared images
    raws: list[str]  # their raw frames ("" with source ``prepared``)
    hw: tuple[int, int]
    crop: int
    preset: str
    options: dict[str, Any]
    carry: bool
    source: str
    interpolation: str = "area"  # prepare's filter (camera.json), for the raw-vs-prepared check
    camera: RawCamera = NYU_RAW_CAMERA  # of the raw frames (camera.json source_*)


def _select_task(task: _Task) -> list[tuple[np.ndarray, float | None]]:
    """(keypoints (n, 3) int16 at the training size, raw-vs-prepared mismatch or None) of each frame."""
    selector = KeypointSelector(task.preset, **task.options)
    out = []
    for image, raw in zip(task.images, task.raws):
        prepared = read_image(image, task.hw)
        mismatch = None
        if task.source == "full_resolution":
            gray, full = full_resolution_gray(raw, task.crop, task.camera)
            mismatch = raw_mismatch(full, prepared, task.interpolation)
            if mismatch > MATCH_TOLERANCE:
                raise DataError(raw, f"prepared again it differs from {image} by {mismatch:.1f} grey levels "
                                "on average: not the frame prepare read", _RAW_FIX)
        else:
            gray = cv2.cvtColor(prepared, cv2.COLOR_RGB2GRAY)
        if not task.carry:
            selector.pot = selector.preset.pot
        out.append((selector(gray, task.hw).astype(np.int16), mismatch))
    return out


def _summary(counts: np.ndarray, points: list[np.ndarray]) -> dict[str, Any]:
    total = int(counts.sum())
    levels = np.zeros(3, np.int64)
    if total:
        levels = np.bincount(np.concatenate([p[:, 2] for p in points]).astype(np.int64), minlength=3)
    duplicates = sum(len(p) - len(np.unique(p[:, :2], axis=0)) for p in points if len(p))
    return {
        "points_per_image": {"mean": float(counts.mean()) if len(counts) else 0.0,
                             "min": int(counts.min()) if len(counts) else 0,
                             "max": int(counts.max()) if len(counts) else 0},
        "share_below_100": float((counts < 100).mean()) if len(counts) else 0.0,
        "empty_frames": int((counts == 0).sum()),
        "level_shares": [float(v / total) if total else 0.0 for v in levels[:3]],
        "duplicate_share": float(duplicates / total) if total else 0.0,
    }


def extract_keypoints(prepared: str | os.PathLike, out_file: str | os.PathLike,
                      overlay_dir: str | os.PathLike | None, preset: str,
                      options: Mapping[str, Any] | None = None, workers: int = 1, sequence: bool = False,
                      overlays: int = 0, progress: bool = True, source: str = "full_resolution",
                      nyu_raw: str | os.PathLike | None = None) -> dict[str, Any]:
    """Select keypoints on every frame of ``prepared``, write ``out_file`` and overlays; return metrics.

    ``source`` ``full_resolution`` (needs ``nyu_raw``, the folder frames.csv's ``raw_file`` is relative
    to) or ``prepared``; see the module docstring.
    """
    start = time.perf_counter()
    if source not in SOURCES:
        raise ValueError(f"unknown keypoint source {source!r}; choose one of {', '.join(SOURCES)}")
    if source == "full_resolution" and nyu_raw is None:
        raise ValueError("source 'full_resolution' needs nyu_raw, the NYU raw folder of the prepared set")
    options = dict(options or {})
    config = get_preset(preset, **options)  # validates the options before any work
    data = PreparedSet(prepared)
    frames = data.frames
    paths = [str(data.root / f.image) for f in frames]
    full = source == "full_resolution"
    crop = data.crop if full else 0
    raws = [str(data.raw_path(f.frame_id, nyu_raw)) if full else "" for f in frames]
    if sequence:
        groups: dict[str, list[int]] = {}
        for i, f in enumerate(frames):
            groups.setdefault(f.scene, []).append(i)
        index_groups = list(groups.values())
    else:
        index_groups = [list(range(i, min(i + CHUNK, len(frames)))) for i in range(0, len(frames), CHUNK)]
    tasks = [_Task([paths[i] for i in g], [raws[i] for i in g], data.hw, crop, preset, options, sequence,
                   source, data.interpolation, data.source_camera) for g in index_groups]
    points = [np.zeros((0, 3), np.int16)] * len(frames)
    mismatch: list[float | None] = [None] * len(frames)
    results = map_jobs(_select_task, tasks, workers, f"keypoints ({preset})", progress,
                       size=lambda t: len(t.images))
    for group, res in zip(index_groups, results):
        for i, (p, m) in zip(group, res):
            points[i], mismatch[i] = p, m
    frame_ids = [data.frame_index(f.frame_id) for f in frames]
    save_keypoints(out_file, frame_ids, points)
    written = []
    if overlay_dir is not None:
        Path(overlay_dir).mkdir(parents=True, exist_ok=True)  # a DVC out even with no overlays
    if overlay_dir is not None and overlays > 0 and frames:
        picks = np.linspace(0, len(frames) - 1, min(overlays, len(frames)))
        for i in sorted({int(round(v)) for v in picks}):
            picture = draw_keypoints(read_image(paths[i], data.hw), points[i])
            target = Path(overlay_dir) / f"{frames[i].frame_id}.png"
            write_rgb(target, picture)
            written.append(str(target))
    counts = np.array([len(p) for p in points], np.int64)
    checked = [m for m in mismatch if m is not None]
    return {"preset": preset, "options": {k: v for k, v in vars(config).items() if k != "name"},
            "source": source,
            "selector_input": ([data.source_camera.hw[0] - 2 * crop, data.source_camera.hw[1] - 2 * crop]
                               if full else list(data.hw)),
            "sequence": bool(sequence), "frames": len(frames), "size": list(data.hw),
            **_summary(counts, points),
            "raw_vs_prepared_max_diff": round(max(checked), 4) if checked else None, "overlays": len(written),
            "workers": int(workers), "seconds": round(time.perf_counter() - start, 3)}
