"""``f2depth ingest``: videos and image folders → a raw frame folder in the NYU-raw layout (docs/ingest.md).

Every input is one scene: a video (any frame rate; OpenCV applies its rotation metadata) or a folder of
images (sorted by name). Frames are streamed, never held together: sampled every ``frame_step``-th (a
video with ``rate``: every round(fps / rate)-th), filtered (:class:`f2depth.ingest.select.FrameFilter`:
static camera, optional blur), undistorted with the camera (:mod:`f2depth.ingest.camera_files`: camera
file → ``fov`` → EXIF → self-calibration from the inputs themselves, :mod:`f2depth.ingest.selfcal`, a
first pass over them), shrunk to at most ``max_side`` px on the long side and written as
``<out>/<scene>/r-<seconds>-<index>.png``. ``<out>/camera.json`` holds the intrinsics of those frames
(no distortion left; :func:`f2depth.formats.nyu_raw.raw_camera` reads it), ``<out>/scenes.txt`` the scenes
(``prepare.train_scenes_file``), ``<out>/ingest.json`` what was kept and dropped per scene. The folder is
built aside and swapped in at the end: a failed ingest leaves nothing that looks valid. The output may not
be, hold or lie inside an input, and replaces only a folder that is empty or an earlier ingest's (its
marker, :func:`f2depth.io.check_replaceable`): nothing of the user's is ever deleted.
"""

from __future__ import annotations

import os
import re
import time
import warnings
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

import numpy as np
from tqdm import tqdm

from f2depth.camera import RawCamera, crop_resize_intrinsics
from f2depth.errors import DataError
from f2depth.formats.nyu_raw import CAMERA_FILE
from f2depth.formats.prepared import prepare_image
from f2depth.formats.writable import check_apart
from f2depth.ingest.camera_files import choose_camera
from f2depth.ingest.select import FrameFilter
from f2depth.ingest.selfcal import FocalEstimate, estimate_focal
from f2depth.ingest.sources import (
    VIDEO_EXTENSIONS,
    Frame,
    decode_shortfall,
    image_files,
    open_source,
)
from f2depth.io import atomic_dir, write_json, write_rgb, write_text

MIN_KEPT = 3  # a scene gives a frame tuple (target, prev, next) from three kept frames


@dataclass(frozen=True)
class IngestConfig:
    """The ``ingest`` section of params.yaml (``f2depth ingest`` flags override it)."""

    frame_step: int = field(metadata={"min": 1})        # every N-th frame is a candidate ...
    rate: float | None = field(metadata={"gt": 0})      # ... or, for a video, about this many per second
    min_motion: float = field(metadata={"min": 0})      # median tracked motion ÷ diagonal to keep a frame
    min_sharpness: float = field(metadata={"min": 0})   # Laplacian variance at 320 px; 0 = no blur filter
    max_side: int = field(metadata={"min": 32})         # px, long side of the written frames


@dataclass(frozen=True)
class _Input:
    path: Path
    scene: str


def scene_name(path: Path, taken: set[str]) -> str:
    """A scene folder name from an input's stem: letters, digits, '_' and '-' only, unique."""
    base = re.sub(r"[^A-Za-z0-9_\-]+", "_", path.stem if path.is_file() else path.name).strip("_-") or "scene"
    name, k = base, 2
    while name in taken:
        name, k = f"{base}_{k}", k + 1
    taken.add(name)
    return name


def collect_inputs(paths: Sequence[str | os.PathLike]) -> list[_Input]:
    """The scenes of the given paths: each video, each image folder. A folder without images of its own
    gives one scene per video in it and one per subfolder of images (``data.video``: clips and image
    folders side by side). A folder that mixes images with videos or with folders of images → DataError."""
    found: list[Path] = []
    for raw in paths:
        p = Path(raw)
        if not p.exists():
            raise DataError(p, "input not found", "give videos or folders of images")
        if p.is_dir():
            entries = [e for e in sorted(p.iterdir()) if not e.name.startswith(".")]
            videos = [e for e in entries if e.is_file() and e.suffix.lower() in VIDEO_EXTENSIONS]
            images = image_files(p)
            folders = [e for e in entries if e.is_dir() and image_files(e)]
            if images and (videos or folders):
                raise DataError(p, f"a folder with {len(images)} images and {len(videos)} videos, "
                                f"{len(folders)} folders of images", "one scene per input: move the images "
                                "into a folder of their own, or give the videos separately")
            found.extend(sorted(videos + folders) if videos or folders else [p])
        elif p.suffix.lower() in VIDEO_EXTENSIONS:
            found.append(p)
        else:
            raise DataError(p, "not a video or a folder of images",
                            f"videos: {' '.join(VIDEO_EXTENSIONS)}; or a folder of images")
    seen: dict[Path, Path] = {}
    for p in found:  # one input twice (also through a folder, a link or another spelling): one scene
        first = seen.setdefault(p.resolve(), p)
        if first is not p:
            raise DataError(p, f"is given twice (also as {first}), which would make two identical training "
                            "scenes", "give each video or folder of images once")
    taken: set[str] = set()
    return [_Input(p, scene_name(p, taken)) for p in found]


def earlier_ingest(folder: Path) -> bool:
    """Whether ``folder`` looks like an ingest written before the output marker existed: ingest.json, and
    nothing but camera.json, scenes.txt and scene folders of ``r-*.png`` frames beside it."""
    if not (folder / "ingest.json").is_file():
        return False
    for entry in folder.iterdir():
        if entry.is_dir():
            frames = (f.is_file() and f.name.startswith("r-") and f.suffix == ".png" for f in entry.iterdir())
            if not all(frames):
                return False
        elif entry.name not in ("ingest.json", CAMERA_FILE, "scenes.txt"):
            return False
    return True


class _Candidates:
    """Every ``step``-th frame of ``frames`` as (index, frame); ``decoded`` counts every frame read."""

    def __init__(self, frames: Iterator[Frame], step: int) -> None:
        self.frames, self.step, self.decoded = frames, step, 0

    def __iter__(self) -> Iterator[tuple[int, Frame]]:
        for index, frame in enumerate(self.frames):
            self.decoded = index + 1
            if index % self.step == 0:
                yield index, frame


def too_few_kept(path: Path, counts: dict[str, int], sampled: int, decoded: int, step: int, which: str,
                 config: IngestConfig, names: Mapping[str, str]) -> DataError:
    """The error of a scene that kept fewer than MIN_KEPT frames, blaming what dropped them: too few
    candidates (the step), the blur filter, or a camera that hardly moves (the motion threshold).
    ``which``: the setting that chose the ``step`` (``frame_step`` or ``rate``); ``names``: how each setting
    was given (``--frame-step``, or ``ingest.frame_step``)."""
    kept = counts["kept"]
    if sampled < MIN_KEPT:
        return DataError(path, f"only {sampled} frame(s) sampled: every {step}-th of {decoded} decoded "
                         f"frames ({names[which]} = {getattr(config, which):g})",
                         f"lower {names[which]} to sample at least {MIN_KEPT} frames")
    if counts["blur"] >= counts["static"]:
        return DataError(path, f"only {kept} of {sampled} sampled frames kept: {counts['blur']} are less "
                         f"sharp (variance of the Laplacian) than {names['min_sharpness']} = "
                         f"{config.min_sharpness:g}", f"lower {names['min_sharpness']} (0 turns the blur "
                         "filter off)")
    return DataError(path, f"only {kept} of {sampled} sampled frames kept ({counts['static']} static, "
                     f"{counts['blur']} blurred): the camera hardly moves (median motion below "
                     f"{names['min_motion']} = {config.min_motion:g} of the diagonal)",
                     f"record with the camera moving, or lower {names['min_motion']}")


def working_camera(camera: RawCamera, max_side: int) -> RawCamera:
    """The camera of the written frames: undistorted, shrunk to at most ``max_side`` px on the long side."""
    h, w = camera.hw
    scale = min(1.0, max_side / max(h, w))
    hw = (max(round(h * scale), 1), max(round(w * scale), 1))
    K = crop_resize_intrinsics(camera.K, camera.hw, 0, hw)
    source = f"{camera.source}; undistorted and resized to {hw[1]}×{hw[0]} by f2depth ingest"
    return RawCamera(K, np.zeros(5), hw, source)


def ingest(inputs: Sequence[str | os.PathLike], out_dir: str | os.PathLike, config: IngestConfig,
           camera_file: str | os.PathLike | None = None, fov: float | None = None,
           progress: bool = True, option: str = "--out", owned: bool = False,
           names: Mapping[str, str] | None = None) -> dict:
    """Ingest ``inputs`` into ``out_dir`` (module docstring) → the report written to ``ingest.json``.
    ``option`` names the setting of ``out_dir`` in errors; ``owned``: a DVC stage's output, replaced
    whatever it holds (:func:`f2depth.io.atomic_dir`). ``names``: how settings given elsewhere are named in
    errors (e.g. ``{"frame_step": "--frame-step"}``; default ``ingest.<key>``)."""
    names = {f.name: f"ingest.{f.name}" for f in fields(IngestConfig)} | dict(names or {})
    start = time.perf_counter()
    scenes = collect_inputs(inputs)
    out = Path(out_dir)
    check_apart([*inputs, camera_file], out, option)
    camera: RawCamera | None = None
    written: RawCamera | None = None
    report: dict[str, dict] = {}
    notes: list[str] = []  # warnings, one line each (ingest.json's "warnings")
    estimated: list[FocalEstimate] = []

    def frames(item: _Input) -> Iterator[np.ndarray]:
        source = open_source(item.path)
        for frame in tqdm(source, total=len(source) or None, desc=f"self-calibrate {item.scene}",
                          unit="frame", disable=not progress, leave=False):
            yield frame.rgb

    def self_calibrate() -> RawCamera:  # no camera file, --fov or EXIF: a first pass over every input
        estimated.append(estimate_focal((frames(item) for item in scenes), scenes[0].path))
        return estimated[0].camera()

    with atomic_dir(out, "ingest", owned=owned, option=option, previous=earlier_ingest) as tmp:
        for item in scenes:
            source = open_source(item.path)
            video = source.kind == "video"
            if video and source.rotation_deg and not source.rotation_applied:
                warnings.warn(f"ingest: {item.path} says it is rotated by {source.rotation_deg:g}° but this "
                              "OpenCV does not turn its frames: they are ingested as stored (sideways); "
                              "turn the video first (e.g. ffmpeg -i in.mp4 out.mp4)", stacklevel=2)
            fps = source.fps if video else 0.0
            step = max(round(fps / config.rate), 1) if config.rate and fps else config.frame_step
            keep = FrameFilter(config.min_motion, config.min_sharpness)
            folder = tmp / item.scene
            folder.mkdir()
            read, candidates = 0, _Candidates(iter(source), step)
            bar = tqdm(total=-(-len(source) // step) or None, desc=f"ingest {item.scene}", unit="frame",
                       disable=not progress, leave=False)
            with bar:
                for index, frame in candidates:
                    bar.update()
                    read += 1
                    hw = frame.rgb.shape[:2]
                    if camera is None:
                        first = Path(frame.origin.split("#")[0])
                        camera = choose_camera(hw, first, camera_file, fov, self_calibrate)
                        written = working_camera(camera, config.max_side)
                    if hw != tuple(camera.hw):
                        raise DataError(Path(frame.origin), f"a {hw[1]}×{hw[0]} frame, but the camera "
                                        f"({camera.source}) is {camera.hw[1]}×{camera.hw[0]}",
                                        "one camera and one frame size per ingest: resize the frames or "
                                        "ingest this input on its own")
                    if keep.offer(frame.rgb) == "kept":
                        seconds = index / fps if fps else float(index)
                        write_rgb(folder / f"r-{seconds:.6f}-{index:06d}.png",
                                  prepare_image(frame.rgb, 0, written.hw, camera=camera))
            if keep.counts["kept"] < MIN_KEPT:
                raise too_few_kept(item.path, keep.counts, read, candidates.decoded, step,
                                   "rate" if config.rate and fps else "frame_step", config, names)
            short = decode_shortfall(item.path, candidates.decoded, len(source), "ingested from those")
            if short is not None:
                notes.append(short)
            report[item.scene] = {"input": str(item.path), "kind": source.kind, "fps": fps or None,
                                  "rotation_deg": source.rotation_deg if video else 0.0, "step": step,
                                  "sampled": read,
                                  "rotation_applied": source.rotation_applied if video else False,
                                  "decoded": candidates.decoded, "frames_expected": len(source) or None,
                                  **keep.counts}
        assert written is not None  # every scene kept frames
        write_json(tmp / CAMERA_FILE, written.to_json())
        write_text(tmp / "scenes.txt", "".join(f"{s}\n" for s in report))
        summary = {"scenes": report, "camera": written.to_json(), "input_camera": camera.to_json(),
                   "self_calibration": estimated[0].to_json() if estimated else None,
                   "settings": asdict(config), "warnings": notes}
        write_json(tmp / "ingest.json", summary)  # no timings: the same inputs give the same bytes
    return {**summary, "seconds": round(time.perf_counter() - start, 2)}
