"""The embedded "own video": each synthetic NYU-raw scene encoded as an MP4 clip, as a phone would hand
it over, for the video route (``train_source: video``, the ``ingest`` stage, docs/ingest.md).

A clip is ``<clips>/<scene>.mp4`` (MPEG-4 Part 2, OpenCV's ``mp4v``, ``fps`` frames a second, 640×480,
still lens-distorted like the raw frames): ``static_frames`` copies of the scene's first frame (a camera
that has not started moving: the ingest filter must drop them), then the scene's frames in time order, the
last ``fast_share`` of them only every ``fast_step``-th (a stretch of fast motion).
``<clips>/camera.json`` is the camera file of the clips (NYU Depth V2's RGB calibration with its lens
distortion, the format of docs/ingest.md), ``<clips>/clips.json`` what each clip holds (the raw frame of
each clip frame).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import cv2

from f2depth.camera import NYU_RAW_CAMERA
from f2depth.formats.nyu_raw import list_frames, read_frame
from f2depth.io import atomic_path, write_json

CAMERA_FILE = "camera.json"
REPORT = "clips.json"
FOURCC = "mp4v"


@dataclass(frozen=True)
class ClipsParams:
    """The ``synth.clips`` section."""

    static_frames: int = field(metadata={"min": 0})  # copies of the first frame before the camera moves
    fast_share: float = field(metadata={"min": 0, "max": 1})  # the last share of the frames ...
    fast_step: int = field(metadata={"min": 1})  # ... taken only every fast_step-th
    fps: float = field(metadata={"gt": 0})


def clip_frames(n: int, clips: ClipsParams) -> tuple[list[int], int]:
    """Indices into a scene's ``n`` frames in clip order (the static copies of frame 0 included), and the
    clip index where the fast stretch starts."""
    slow = n - int(round(n * clips.fast_share))
    start = clips.static_frames + slow
    return [0] * clips.static_frames + list(range(slow)) + list(range(slow, n, clips.fast_step)), start


def camera_file_json() -> dict:
    """The clips' camera file: NYU's RGB calibration (fx fy cx cy at 640×480, OpenCV k1 k2 p1 p2 k3)."""
    K, dist, (h, w) = NYU_RAW_CAMERA.K, NYU_RAW_CAMERA.dist, NYU_RAW_CAMERA.hw
    return {"fx": float(K[0, 0]), "fy": float(K[1, 1]), "cx": float(K[0, 2]), "cy": float(K[1, 2]),
            "width": w, "height": h, "dist": [float(d) for d in dist]}


def write_clips(nyu_raw: str | Path, scenes: list[str], out_dir: str | Path, clips: ClipsParams) -> dict:
    """Encode the generated ``scenes`` under ``nyu_raw`` into ``out_dir`` (module docstring) → what was
    written. Clips an earlier generation listed in its clips.json and this one has not are removed; other
    files are left alone."""
    out = Path(out_dir)
    report: dict[str, dict] = {}
    try:
        earlier = set(json.loads((out / REPORT).read_text())["clips"])
    except (OSError, ValueError, KeyError, TypeError):
        earlier = set()
    for stale in sorted(earlier - set(scenes)):
        (out / f"{stale}.mp4").unlink(missing_ok=True)
    for scene in scenes:
        frames = list_frames(nyu_raw, scene)
        order, fast_from = clip_frames(len(frames), clips)
        target = out / f"{scene}.mp4"
        with atomic_path(target) as tmp:
            h, w = NYU_RAW_CAMERA.hw
            writer = cv2.VideoWriter(str(tmp), cv2.VideoWriter_fourcc(*FOURCC), clips.fps, (w, h))
            if not writer.isOpened():
                raise RuntimeError(f"{target}: OpenCV cannot write {FOURCC} video here")
            try:
                for i in order:
                    writer.write(cv2.cvtColor(read_frame(frames[i].path), cv2.COLOR_RGB2BGR))
            finally:
                writer.release()
        report[scene] = {"frames": len(order), "static_frames": clips.static_frames, "fast_from": fast_from,
                         "raw_frames": [frames[i].stem for i in order]}
    write_json(out / CAMERA_FILE, camera_file_json())
    write_json(out / REPORT, {"fourcc": FOURCC, "fps": clips.fps, "camera": CAMERA_FILE,
                                    "clips": report})
    return report
