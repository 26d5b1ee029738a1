"""Camera poses of the training scenes and the pose prior of every training pair (the ``poses`` stage).

Per training scene of the prepared set: all its NYU raw frames (not only every ``frame_step``-th: the
frames in between make the tracks long and the geometry stiff), undistorted at full resolution with the
prepared set's source camera (NYU's RGB calibration or an ingested video's; ``cv2.undistort``, same K, as
``prepare``) → corner tracks (``tracks``) → incremental
structure from motion with the intrinsics held fixed (``reconstruct``) → one scale per scene: the median
depth of the scene's images as its triangulated points sample them (``Reconstruction.image_median_depth``:
each point weighted by the image area it is the nearest point to) is set to ``median_depth``, the depth
the untrained DepthCNN predicts with ``train_depth.init_depth``.

For each prepared tuple (target, prev, next) the prior is the pair of relative poses ``prev_T_target`` and
``next_T_target`` (docs/formats.md: ``tgt_T_src`` maps points of camera src into camera tgt, here the
target camera into each source camera, the transforms the photometric loss warps with). A pair is
*reliable* when its scene's reconstruction is sound — at least ``min_registered_share`` of the scene's
frames registered and ``min_scene_points`` points triangulated — and both frames are registered and see
at least ``min_shared_points`` common points; the others carry no prior and training gives them PoseCNN's
pose alone. A scene without an initial pair (textureless) registers no frame and gives no prior at all.
"""

from __future__ import annotations

import functools
import time
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from f2depth.camera import NYU_RAW_CAMERA, RawCamera, undistort_image
from f2depth.errors import DataError
from f2depth.formats.nyu_raw import list_frames, read_frame
from f2depth.formats.prepared import PreparedSet
from f2depth.poses.reconstruct import ReconstructConfig, reconstruct
from f2depth.poses.tracks import TrackerConfig, track_corners, valid_region
from f2depth.workers import map_jobs


@dataclass(frozen=True)
class PosesConfig:
    """The ``poses`` section (ranges checked by f2depth.params.section)."""

    tracker: TrackerConfig = field(default_factory=TrackerConfig)
    reconstruct: ReconstructConfig = field(default_factory=ReconstructConfig)
    # the scale of every scene: median depth of its images (image_median_depth)
    median_depth: float = field(default=2.0, metadata={"gt": 0})
    # a scene is sound with this share of its frames registered ...
    min_registered_share: float = field(default=0.9, metadata={"min": 0, "max": 1})
    min_scene_points: int = field(default=10, metadata={"min": 0})  # ... and this many points
    # a pair is reliable when both frames see this many common points
    min_shared_points: int = field(default=10, metadata={"min": 1})
    workers: int = field(default=2, metadata={"min": 0})


@dataclass(frozen=True)
class ScenePoses:
    """One scene: raw_files (N,) names under data.nyu_raw in time order, world_T_cam (N,4,4) float64 in the
    scene's normalised scale (NaN where not registered), registered (N,) bool, shared (N,N) int points seen
    by both frames, points (number triangulated), tracks, seconds."""

    scene: str
    raw_files: list[str]
    world_T_cam: np.ndarray
    registered: np.ndarray
    shared: np.ndarray
    points: int
    tracks: int
    seconds: float

    def sound(self, min_registered_share: float, min_points: int) -> bool:
        """Enough of the scene registered, with enough points, for its priors to be trusted."""
        if not len(self.registered):
            return False
        return bool(self.registered.mean() >= min_registered_share and self.points >= min_points)

    def index(self, raw_file: str) -> int:
        try:
            return self.raw_files.index(raw_file)
        except ValueError:
            raise KeyError(f"{raw_file} is not a raw frame of scene {self.scene}") from None

    def relative(self, target: int, source: int) -> np.ndarray:
        """source_T_target (4,4) = (world_T_source)⁻¹ · world_T_target (NaN unless both registered)."""
        if not self.registered[[target, source]].all():
            return np.full((4, 4), np.nan)
        return np.linalg.inv(self.world_T_cam[source]) @ self.world_T_cam[target]


def load_grey_frames(paths: list[Path], camera: RawCamera = NYU_RAW_CAMERA) -> list[np.ndarray]:
    """Raw frames of ``camera`` → undistorted (same K) uint8 grey images ``camera.hw`` (NYU: 480×640)."""
    return [cv2.cvtColor(undistort_image(read_frame(p, camera.hw), camera.K, camera.dist), cv2.COLOR_RGB2GRAY)
            for p in paths]


def estimate_scene(nyu_raw: str | Path, scene: str, config: PosesConfig,
                   camera: RawCamera = NYU_RAW_CAMERA) -> ScenePoses:
    """Poses of every raw frame of ``scene`` taken by ``camera`` (module docstring)."""
    t0 = time.perf_counter()
    frames = list_frames(nyu_raw, scene)
    grays = load_grey_frames([f.path for f in frames], camera)
    tracks = track_corners(grays, valid_region(camera.K, camera.dist, camera.hw), config.tracker)
    rec = reconstruct(tracks, camera.K, config.reconstruct).normalised(config.median_depth, camera.hw)
    world_T_cam = np.full_like(rec.cam_T_world, np.nan)
    world_T_cam[rec.registered] = np.linalg.inv(rec.cam_T_world[rec.registered])
    return ScenePoses(scene=scene, raw_files=[f"{scene}/{f.path.name}" for f in frames],
                      world_T_cam=world_T_cam, registered=rec.registered, shared=rec.shared_points(),
                      points=int((~np.isnan(rec.points[:, 0])).sum()), tracks=tracks.n_tracks,
                      seconds=round(time.perf_counter() - t0, 2))  # fmt: skip


@dataclass(frozen=True)
class PairPrior:
    """The prior of one training pair: src_T_tgt (4,4) (NaN when unregistered), reliable, shared points."""

    src_T_tgt: np.ndarray
    reliable: bool
    shared_points: int


def pair_prior(scene: ScenePoses, target: int, source: int, config: PosesConfig) -> PairPrior:
    """The prior ``source_T_target`` of a pair of raw frames and whether it is reliable (module docstring)."""
    T = scene.relative(target, source)
    shared = int(scene.shared[target, source])
    sound = scene.sound(config.min_registered_share, config.min_scene_points)
    return PairPrior(T, bool(sound and np.all(np.isfinite(T)) and shared >= config.min_shared_points), shared)


def tuple_priors(prepared: PreparedSet, scenes: dict[str, ScenePoses],
                 config: PosesConfig) -> dict[str, tuple[PairPrior, PairPrior]]:
    """{tuple_id: (prior of prev_T_target, prior of next_T_target)} for every tuple of ``prepared``, the
    held-out ones (val_tuples.csv) after the training ones."""
    out = {}
    for t in prepared.tuples + prepared.val_tuples:
        s = scenes[t.scene]
        idx = {f: s.index(prepared.frame(f).raw_file) for f in (t.target, t.prev, t.next)}
        out[t.tuple_id] = (pair_prior(s, idx[t.target], idx[t.prev], config),
                           pair_prior(s, idx[t.target], idx[t.next], config))
    return out


def estimate_scenes(nyu_raw: str | Path, scenes: list[str], config: PosesConfig,
                    camera: RawCamera = NYU_RAW_CAMERA) -> dict[str, ScenePoses]:
    """``estimate_scene`` for every scene, in ``config.workers`` processes (≤ 1: in this one)."""
    for scene in scenes:
        if not (Path(nyu_raw) / scene).is_dir():
            raise DataError(Path(nyu_raw) / scene, "raw scene of the prepared set not found",
                            "point data.nyu_raw at the raw frames the prepared set was made from")
    job = functools.partial(estimate_scene, str(nyu_raw), config=config, camera=camera)
    poses = map_jobs(job, scenes, config.workers)
    return dict(zip(scenes, poses))
