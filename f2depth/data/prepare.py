"""The ``prepare`` stage: NYU raw video → the prepared training set (``docs/formats.md``).

Per training scene: raw RGB frames sorted by timestamp → every ``frame_step``-th → undistorted with the raw
folder's camera (:func:`f2depth.formats.nyu_raw.raw_camera`: NYU's RGB calibration, or an ingested video's
``camera.json``; ``cv2.undistort``, same K) → ``crop`` px cut from every side → resized to the training size
(``interpolation``: ``lanczos`` = PIL's LANCZOS as P²Net, or ``area`` = INTER_AREA when shrinking; see
``f2depth.formats.images.INTERPOLATIONS``; the per-image steps are
:func:`f2depth.formats.prepared.prepare_image`). Frame tuples (target, prev, next) and pairs (t, t+1) are
consecutive *sampled* frames of one scene. Felzenszwalb superpixels of every tuple target are computed on the
prepared image as P²Net does (float image in [0, 1]; the colour distance is Euclidean, so RGB and P²Net's BGR
give the same labels). Synthetic side-car ground truth, when present, is cropped like the image and resized
with exact nearest-neighbour sampling.

With ``val_share`` > 0 the last ``val_share`` of each training scene's sampled frames (at least 3) are held
out: their tuples go to ``val_tuples.csv`` (the photometric validation of ``train_depth``, for scenes without
ground-truth depth), and no training tuple or pair uses them. The held-out stretch is contiguous and at the
end, as a later part of the same video, so neighbouring frames leak as little as a single video allows.

Training scenes are the raw scenes whose room is not among the rooms of the labeled test images
(``testNdxs``), or those listed in an explicit file. Rooms are compared without the trailing letter
of split recordings (``bedroom_0076a`` and ``bedroom_0076b`` are the same room).

The whole set is built in a temporary sibling folder and swapped into place at the end, and every file
is written atomically, so an interrupted run leaves the previous set untouched.
"""

from __future__ import annotations

import json
import os
import re
import time
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from f2depth.camera import NYU_RAW_CAMERA, RawCamera, crop_resize_intrinsics
from f2depth.errors import DataError
from f2depth.formats.images import INTERPOLATIONS
from f2depth.formats.nyu_labeled import scenes_of_test_images
from f2depth.formats.nyu_raw import RawFrame, list_frames, list_scenes, raw_camera, read_frame
from f2depth.formats.prepared import (
    FRAMES_HEADER,
    PAIRS_HEADER,
    TUPLES_HEADER,
    VAL_TUPLES,
    crop_border,
    prepare_image,
    resize_image,
)
from f2depth.io import atomic_dir, csv_text, imwrite, save_npz, write_json, write_rgb, write_text
from f2depth.superpixels import MIN_AREA, scaled_min_area
from f2depth.workers import map_jobs

_ROOM_SUFFIX = re.compile(r"(_\d+)[a-z]$")


@dataclass(frozen=True)
class SuperpixelParams:
    """``skimage.segmentation.felzenszwalb`` arguments (P²Net: 100, 0.5, 50)."""

    scale: float = 100.0
    sigma: float = 0.5
    min_size: int = 50


@dataclass(frozen=True)
class PrepareConfig:
    """The ``prepare`` section (its ranges checked by f2depth.params.section). The depth network's encoder
    halves the image five times (P²Net's ResNet-18), so a training size must be a multiple of 32."""

    height: int = field(metadata={"min": 32, "multiple_of": 32})
    width: int = field(metadata={"min": 32, "multiple_of": 32})
    frame_step: int = field(default=10, metadata={"min": 1})
    crop: int = field(default=16, metadata={"min": 0})
    p2net_cxcy_bug: bool = False
    superpixels: SuperpixelParams = field(default_factory=SuperpixelParams)
    workers: int = field(default=2, metadata={"min": 0})
    interpolation: str = "lanczos"  # shrinking filter of the images (f2depth.formats.images.INTERPOLATIONS)
    val_share: float = field(default=0.0, metadata={"min": 0, "max": 0.5})  # held-out end of each scene

    def __post_init__(self) -> None:
        if self.interpolation not in INTERPOLATIONS:
            raise ValueError(f"prepare.interpolation must be one of {list(INTERPOLATIONS)}, "
                             f"got {self.interpolation!r}")

    @property
    def hw(self) -> tuple[int, int]:
        return self.height, self.width


# ---- per-image operations ---------------------------------------------------------------------------

def crop_and_resize(image: np.ndarray, crop: int, hw: tuple[int, int], nearest: bool = False) -> np.ndarray:
    """Cut ``crop`` px from every side of an (H, W[, C]) array, then :func:`resize_image` it to ``hw``."""
    return resize_image(crop_border(image, crop), hw, nearest)


def superpixels(rgb: np.ndarray, params: SuperpixelParams) -> np.ndarray:
    """Felzenszwalb labels (H, W) uint16, 0-based, of an RGB uint8 image."""
    from skimage.segmentation import felzenszwalb
    from skimage.util import img_as_float

    labels = felzenszwalb(img_as_float(rgb), scale=params.scale, sigma=params.sigma, min_size=params.min_size)
    if labels.max() > np.iinfo(np.uint16).max:
        raise ValueError(f"{labels.max() + 1} superpixels do not fit uint16; raise superpixels.min_size")
    return labels.astype(np.uint16)


def superpixel_stats(labels: np.ndarray, min_area: float = MIN_AREA) -> tuple[int, float]:
    """(number of superpixels, share of pixels in superpixels larger than ``min_area`` px)."""
    counts = np.bincount(labels.ravel().astype(np.int64))
    counts = counts[counts > 0]
    return int(counts.size), float(counts[counts > min_area].sum() / labels.size)


def read_synth_gt(path: Path, camera: RawCamera = NYU_RAW_CAMERA) -> tuple[np.ndarray, np.ndarray]:
    """Side-car ground truth of a raw frame → (depth float32 ``camera.hw`` m, world_T_cam (4, 4)), validated
    (its K must be the camera's)."""
    expect_hw = camera.hw
    try:
        with np.load(path) as z:
            arrays = {k: z[k] for k in ("depth", "world_T_cam", "K") if k in z.files}
    except (OSError, ValueError, EOFError) as exc:
        raise DataError(path, f"unreadable .npz ({exc})", "regenerate it with `dvc repro synth`") from exc
    for key in ("depth", "world_T_cam", "K"):
        if key not in arrays:
            raise DataError(path, f"no '{key}' array", "regenerate it with `dvc repro synth`")
    depth, T, K = arrays["depth"], arrays["world_T_cam"], arrays["K"]
    if depth.shape != tuple(expect_hw) or not np.all(np.isfinite(depth)) or depth.min() < 0:
        raise DataError(path, f"depth must be finite, ≥ 0 and {expect_hw}, found {depth.shape}")
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise DataError(path, f"world_T_cam must be a finite 4×4 matrix, found {T.shape}")
    if K.shape != (3, 3) or not np.allclose(K, camera.K, rtol=1e-6, atol=1e-6):
        raise DataError(path, f"K differs from the camera the frames are undistorted with ({camera.source})",
                        "the side-car depth would not align with the undistorted image")
    return depth.astype(np.float32), T.astype(np.float64)


# ---- planning ---------------------------------------------------------------------------------------

def room_of(scene: str) -> str:
    """``bedroom_0076b`` → ``bedroom_0076``: recordings of one room split into parts a, b, …"""
    return _ROOM_SUFFIX.sub(r"\1", scene)


def read_scene_list(path: str | os.PathLike, raw_scenes: Sequence[str]) -> list[str]:
    """An explicit training-scene file (one name a line; blank lines and ``#`` comments allowed)."""
    p = Path(path)
    if not p.is_file():
        raise DataError(p, "training scene list not found", "fix prepare.train_scenes_file in params.yaml")
    known, names = set(raw_scenes), []
    for lineno, line in enumerate(p.read_text().splitlines(), 1):
        name = line.split("#", 1)[0].strip()
        if not name:
            continue
        if name not in known:
            raise DataError(p, f"line {lineno}: scene {name!r} is not a folder of the NYU raw data",
                            "fix the name or remove the line")
        if name in names:
            raise DataError(p, f"line {lineno}: scene {name!r} is listed twice")
        names.append(name)
    if not names:
        raise DataError(p, "lists no scenes")
    return sorted(names)


def select_train_scenes(raw_scenes: Sequence[str], test_scenes: set[str]) -> list[str]:
    """Raw scenes whose room holds no labeled test image."""
    test_rooms = {room_of(s) for s in test_scenes}
    return [s for s in raw_scenes if room_of(s) not in test_rooms]


#: A held-out stretch needs three frames to hold one tuple.
MIN_HELD_OUT = 3


def held_out_count(n: int, share: float) -> int:
    """How many of a scene's ``n`` sampled frames (its last ones) are held out for validation: 0 for
    ``share`` 0, else ``ceil(share·n)`` but at least :data:`MIN_HELD_OUT`; 0 when the frames left would
    not hold a training tuple (three frames)."""
    if share <= 0:
        return 0
    k = max(MIN_HELD_OUT, int(np.ceil(share * n - 1e-9)))
    return k if n - k >= 3 else 0


@dataclass(frozen=True)
class FrameTask:
    frame_id: str
    raw: RawFrame
    gt_src: Path | None
    target: bool  # a tuple's target: gets superpixels
    held_out: bool = False  # in the scene's validation stretch (val_tuples.csv), in no training tuple or pair


def frame_id(frame: RawFrame) -> str:
    return f"{frame.scene}_{frame.index:05d}"


def clip_stems(synth_gt: Path) -> dict[str, list[str]]:
    """Scene → the raw frame stem of every frame of its embedded clip (``synth_gt/manifest.json`` ``clips``;
    empty without one): an ingested clip's frame ``r-<seconds>-<n>`` shows raw frame ``stems[n]``."""
    try:
        clips = json.loads((synth_gt / "manifest.json").read_text()).get("clips", {})
    except (OSError, ValueError):
        return {}
    return clips if isinstance(clips, dict) else {}


def plan_scene(raw_root: Path, scene: str, step: int, synth_gt: Path | None,
               val_share: float = 0.0, stems: list[str] | None = None) -> list[FrameTask]:
    """The sampled frames of a scene, the held-out stretch (:func:`held_out_count`) last; the first and
    last frame of the training and of the held-out stretch are sources only. Ground truth: the side-car
    file of each frame's stem, or with ``stems`` (an ingested clip, :func:`clip_stems`) of ``stems[n]``."""
    sampled = list_frames(raw_root, scene)[::step]
    n_train = len(sampled) - held_out_count(len(sampled), val_share)
    gt_dir = synth_gt / "nyu_raw" / scene if synth_gt is not None else None
    has_gt = gt_dir is not None and gt_dir.is_dir()

    def stem(f: RawFrame) -> str | None:
        if stems is None:
            return f.stem
        return stems[f.counter] if 0 <= f.counter < len(stems) else None

    tasks = []
    for k, f in enumerate(sampled):
        name = stem(f) if has_gt else None
        gt = gt_dir / f"{name}.npz" if name is not None else None
        if gt is not None and not gt.is_file():
            raise DataError(gt, "missing side-car ground truth (its scene has some)",
                            "re-run `dvc repro synth`")
        held_out = k >= n_train
        first, last = (n_train, len(sampled) - 1) if held_out else (0, n_train - 1)
        tasks.append(FrameTask(frame_id(f), f, gt, first < k < last, held_out))
    return tasks


# ---- work done in worker processes ------------------------------------------------------------------

@dataclass(frozen=True)
class _Job:
    task: FrameTask
    out: Path
    config: PrepareConfig
    camera: RawCamera


def _run_job(job: _Job) -> tuple[str, int, float, float] | None:
    t, cfg, out = job.task, job.config, job.out
    raw = read_frame(t.raw.path, job.camera.hw)
    img = prepare_image(raw, cfg.crop, cfg.hw, cfg.interpolation, job.camera)
    write_rgb(out / image_rel(t), img)
    if t.gt_src is not None:
        depth, pose = read_synth_gt(t.gt_src, job.camera)
        depth = crop_and_resize(depth, cfg.crop, cfg.hw, nearest=True)
        save_npz(out / gt_rel(t), depth=depth.astype(np.float32), world_T_cam=pose)
    if not t.target:
        return None
    labels = superpixels(img, cfg.superpixels)
    imwrite(out / segments_rel(t.frame_id), labels)
    n, share = superpixel_stats(labels)
    _, share_scaled = superpixel_stats(labels, scaled_min_area(*cfg.hw))
    return t.frame_id, n, share, share_scaled


def image_rel(t: FrameTask) -> str:
    return f"images/{t.raw.scene}/{t.frame_id}.png"


def gt_rel(t: FrameTask) -> str:
    return f"gt/{t.raw.scene}/{t.frame_id}.npz" if t.gt_src is not None else ""


def segments_rel(tuple_id: str) -> str:
    return f"segments/{tuple_id}.png"


# ---- the stage --------------------------------------------------------------------------------------

def _write_tables(out: Path, per_scene: dict[str, list[FrameTask]], config: PrepareConfig,
                  camera: RawCamera) -> tuple[int, int, int]:
    frames, tuples, val_tuples, pairs = [], [], [], []
    for scene, tasks in per_scene.items():
        for k, t in enumerate(tasks):
            frames.append([t.frame_id, scene, f"{scene}/{t.raw.path.name}", image_rel(t), gt_rel(t)])
            if t.target:
                (val_tuples if t.held_out else tuples).append(
                    [t.frame_id, scene, t.frame_id, tasks[k - 1].frame_id, tasks[k + 1].frame_id,
                     segments_rel(t.frame_id)])
            if k + 1 < len(tasks) and not t.held_out and not tasks[k + 1].held_out:
                pairs.append([t.frame_id, scene, t.frame_id, tasks[k + 1].frame_id])
    write_text(out / "frames.csv", csv_text(FRAMES_HEADER, frames))
    write_text(out / "tuples.csv", csv_text(TUPLES_HEADER, tuples))
    write_text(out / VAL_TUPLES, csv_text(TUPLES_HEADER, val_tuples))
    write_text(out / "pairs.csv", csv_text(PAIRS_HEADER, pairs))
    K = crop_resize_intrinsics(camera.K, camera.hw, config.crop, config.hw, config.p2net_cxcy_bug)
    write_json(out / "camera.json", {
        "K": K, "height": config.height, "width": config.width, "p2net_cxcy_bug": config.p2net_cxcy_bug,
        "source_K": camera.K, "source_dist": camera.dist, "source_height": camera.hw[0],
        "source_width": camera.hw[1], "intrinsics_source": camera.source, "crop": config.crop,
        "frame_step": config.frame_step, "interpolation": config.interpolation,
    })
    return len(tuples), len(val_tuples), len(pairs)


def prepare(nyu_raw: str | os.PathLike, nyu_labeled: str | os.PathLike, nyu_splits: str | os.PathLike,
            out_dir: str | os.PathLike, config: PrepareConfig, synth_gt: str | os.PathLike | None = None,
            train_scenes_file: str | os.PathLike | None = None, progress: bool = True) -> dict:
    """Build ``out_dir`` (``data/prepared``) and return the stage metrics."""
    start = time.perf_counter()
    raw_root, out = Path(nyu_raw), Path(out_dir)
    raw_scenes = list_scenes(raw_root)
    camera = raw_camera(raw_root)
    if train_scenes_file is not None:
        scenes = read_scene_list(train_scenes_file, raw_scenes)
    else:
        scenes = select_train_scenes(raw_scenes, scenes_of_test_images(nyu_labeled, nyu_splits))
        if not scenes:
            raise DataError(raw_root, f"all {len(raw_scenes)} raw scenes are rooms of labeled test images",
                            "add other scenes or set prepare.train_scenes_file")
    # side-car ground truth belongs to the synthetic NYU raw frames and, through the manifest's clip index,
    # to the embedded clips ingested with their camera file (the camera they were rendered with); another
    # video has none, even where its scene names match the synthetic ones
    gt_root = Path(synth_gt) if synth_gt is not None else None
    stems: dict[str, list[str]] | None = None
    if gt_root is not None and camera is not NYU_RAW_CAMERA:
        stems = clip_stems(gt_root)
        if not (camera.hw == NYU_RAW_CAMERA.hw and np.allclose(camera.K, NYU_RAW_CAMERA.K, rtol=1e-6)):
            stems = {}  # e.g. a self-calibrated K: the side-car depth would not align
    per_scene = {s: plan_scene(raw_root, s, config.frame_step,
                               gt_root if stems is None or s in stems else None, config.val_share,
                               None if stems is None else stems.get(s)) for s in scenes}
    short = [s for s, tasks in per_scene.items() if len(tasks) < 3]
    if short:
        warnings.warn(f"{len(short)} scene(s) have fewer than 3 sampled frames and give no frame tuple: "
                      f"{', '.join(short[:5])}", stacklevel=2)
    whole = [s for s, tasks in per_scene.items() if len(tasks) >= 3 and not any(t.held_out for t in tasks)]
    if config.val_share > 0 and whole:
        warnings.warn(f"prepare.val_share {config.val_share}: {len(whole)} scene(s) are too short to hold "
                      f"out {MIN_HELD_OUT} frames and keep a training tuple, all their frames train: "
                      f"{', '.join(whole[:5])}", stacklevel=2)

    with atomic_dir(out, "prepare", owned=True) as tmp:  # DVC's output (data.prepared)
        jobs = [_Job(t, tmp, config, camera) for tasks in per_scene.values() for t in tasks]
        results = [r for r in map_jobs(_run_job, jobs, config.workers, "prepare", progress) if r is not None]
        n_tuples, n_val, n_pairs = _write_tables(tmp, per_scene, config, camera)
    stats = np.array([r[1:] for r in results], dtype=np.float64).reshape(-1, 3)
    mean = stats.mean(axis=0) if len(stats) else np.zeros(3)
    return {"raw_scenes": len(raw_scenes), "scenes": len(scenes), "scenes_without_tuples": len(short),
            "frames": len(jobs), "frames_with_gt": sum(j.task.gt_src is not None for j in jobs),
            "tuples": n_tuples, "val_tuples": n_val,
            "held_out_frames": sum(j.task.held_out for j in jobs), "pairs": n_pairs,
            "superpixels_per_target": float(mean[0]),
            "superpixel_share_over_1000px": float(mean[1]), "superpixel_share_over_scaled_px": float(mean[2]),
            "superpixel_scaled_px": round(scaled_min_area(*config.hw), 1), "height": config.height,
            "width": config.width, "seconds": round(time.perf_counter() - start, 2)}

