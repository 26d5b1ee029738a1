"""The ``keypoints`` stage's work: select keypoints on every prepared frame, in worker processes.

Frame ids in the output are the rows of frames.csv (``PreparedSet.frame_index``). With ``sequence``
the selector's cell size carries over from frame to frame within a scene (DSO's persistent selector;
one task per scene); otherwise every frame gets a fresh selector (P²Net).
"""

from __future__ import annotations

import multiprocessing
import os
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from tqdm import tqdm

from f2depth.data.images import read_image
from f2depth.data.prepared import PreparedSet
from f2depth.io import imwrite
from f2depth.keypoints.api import KeypointSelector
from f2depth.keypoints.overlay import draw_keypoints
from f2depth.keypoints.presets import get_preset
from f2depth.keypoints.store import save_keypoints

CHUNK = 8  # frames per task without ``sequence``


def _init_worker() -> None:
    cv2.setNumThreads(1)


def _select_task(task: tuple[list[str], tuple[int, int], str, dict[str, Any], bool]) -> list[np.ndarray]:
    """Keypoints (n, 3) int16 of each image file of a task (a chunk of frames or one scene)."""
    paths, hw, preset, options, carry = task
    selector = KeypointSelector(preset, **options)
    out = []
    for path in paths:
        gray = cv2.cvtColor(read_image(path, hw), cv2.COLOR_RGB2GRAY)
        if not carry:
            selector.pot = selector.preset.pot
        out.append(selector(gray).astype(np.int16))
    return out


def _summary(counts: np.ndarray, points: list[np.ndarray]) -> dict[str, Any]:
    total = int(counts.sum())
    levels = np.zeros(3, np.int64)
    if total:
        levels = np.bincount(np.concatenate([p[:, 2] for p in points]).astype(np.int64), minlength=3)
    duplicates = sum(len(p) - len(np.unique(p[:, :2], axis=0)) for p in points if len(p))
    return {
        "points_per_image": {
            "mean": float(counts.mean()) if len(counts) else 0.0,
            "min": int(counts.min()) if len(counts) else 0,
            "max": int(counts.max()) if len(counts) else 0,
        },
        "share_below_100": float((counts < 100).mean()) if len(counts) else 0.0,
        "empty_frames": int((counts == 0).sum()),
        "level_shares": [float(v / total) if total else 0.0 for v in levels[:3]],
        "duplicate_share": float(duplicates / total) if total else 0.0,
    }


def extract_keypoints(
    prepared: str | os.PathLike,
    out_file: str | os.PathLike,
    overlay_dir: str | os.PathLike | None,
    preset: str,
    options: Mapping[str, Any] | None = None,
    workers: int = 1,
    sequence: bool = False,
    overlays: int = 0,
    progress: bool = True,
) -> dict[str, Any]:
    """Select keypoints on every frame of ``prepared``, write ``out_file`` and overlays; return metrics."""
    start = time.perf_counter()
    options = dict(options or {})
    config = get_preset(preset, **options)  # validates the options before any work
    data = PreparedSet(prepared)
    frames = data.frames
    paths = [str(data.root / f.image) for f in frames]
    if sequence:
        groups: dict[str, list[int]] = {}
        for i, f in enumerate(frames):
            groups.setdefault(f.scene, []).append(i)
        index_groups = list(groups.values())
    else:
        index_groups = [list(range(i, min(i + CHUNK, len(frames)))) for i in range(0, len(frames), CHUNK)]
    tasks = [([paths[i] for i in g], data.hw, preset, options, sequence) for g in index_groups]
    points = [np.zeros((0, 3), np.int16)] * len(frames)
    with tqdm(total=len(frames), desc=f"keypoints ({preset})", unit="frame", disable=not progress) as bar:
        if workers > 1 and len(tasks) > 1:
            n_proc = min(workers, len(tasks))
            with multiprocessing.get_context().Pool(n_proc, initializer=_init_worker) as pool:
                for group, pts in zip(index_groups, pool.imap(_select_task, tasks)):
                    for i, p in zip(group, pts):
                        points[i] = p
                    bar.update(len(group))
        else:
            for group, task in zip(index_groups, tasks):
                for i, p in zip(group, _select_task(task)):
                    points[i] = p
                bar.update(len(group))
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
            imwrite(target, cv2.cvtColor(picture, cv2.COLOR_RGB2BGR))
            written.append(str(target))
    counts = np.array([len(p) for p in points], np.int64)
    return {
        "preset": preset,
        "options": {k: v for k, v in vars(config).items() if k != "name"},
        "sequence": bool(sequence),
        "frames": len(frames),
        "size": list(data.hw),
        **_summary(counts, points),
        "overlays": len(written),
        "workers": int(workers),
        "seconds": round(time.perf_counter() - start, 3),
    }
