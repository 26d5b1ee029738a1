"""Generator settings (the ``synth`` section of params.yaml) and output paths (below ``synth.root``)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from f2depth import params as P
from f2depth.synth.clips import ClipsParams


@dataclass(frozen=True)
class SynthConfig:
    """Sizes of the generated sets. Defaults mirror params.yaml. ``compress_gt`` stores the side-car
    ground truth deflated on fine dyadic grids (2.6x smaller, slower to write; see
    :mod:`f2depth.synth.writers`). ``flow_gt`` also stores each video frame's flow to the next frame and
    its occlusion in the side-cars of ``nyu_raw`` and ``sevenscenes`` (the pipeline derives the flow of a
    pair from depth and pose; the ``animated`` set always has its flow). ``sensor_effects`` False renders
    without noise, vignetting and exposure changes (tests of the ground truth)."""

    seed: int = 0
    workers: int = 2
    supersample: int = 2
    nyu_raw_scenes: int = 6
    nyu_raw_frames: int = 51
    labeled_images: int = 40
    labeled_test_fraction: float = 0.5
    sevenscenes_scenes: int = 7
    sevenscenes_frames: int = 6
    campus_scenes: int = 18
    campus_images: int = 2
    campus_hw: tuple[int, int] = (480, 360)
    campus_focal: float = 400.0
    animated_sequences: int = 4
    animated_frames: int = 8
    animated_hw: tuple[int, int] = (256, 320)
    compress_gt: bool = False
    flow_gt: bool = False
    sensor_effects: bool = True
    clips: ClipsParams = ClipsParams(static_frames=8, fast_share=0.3, fast_step=3, fps=30.0)

    @classmethod
    def from_params(cls, synth: dict[str, Any], source: str = "params.yaml") -> SynthConfig:
        """Read the ``synth`` section (:class:`SynthParams`); a missing or bad key raises
        :class:`f2depth.params.ParamsError` naming it."""
        s = P.section({"synth": synth, "_file": source}, "synth", SynthParams)
        return cls(seed=s.seed, workers=s.workers, supersample=s.supersample, nyu_raw_scenes=s.nyu_raw.scenes,
                   nyu_raw_frames=s.nyu_raw.frames, labeled_images=s.nyu_labeled.images,
                   labeled_test_fraction=s.nyu_labeled.test_fraction, sevenscenes_scenes=s.sevenscenes.scenes,
                   sevenscenes_frames=s.sevenscenes.frames_per_sequence, campus_scenes=s.campus.scenes,
                   campus_images=s.campus.images_per_scene, campus_hw=(s.campus.height, s.campus.width),
                   campus_focal=s.campus.focal, animated_sequences=s.animated.sequences,
                   animated_frames=s.animated.frames, animated_hw=(s.animated.height, s.animated.width),
                   compress_gt=s.compress_gt, flow_gt=s.flow_gt, clips=s.clips)


def _at_least(low: float) -> Any:
    return field(metadata={"min": low})


@dataclass(frozen=True)
class NyuRawParams:
    scenes: int = _at_least(1)
    frames: int = _at_least(2)


@dataclass(frozen=True)
class NyuLabeledParams:
    images: int = _at_least(2)
    test_fraction: float = _at_least(0)

    def __post_init__(self) -> None:
        if self.test_fraction >= 1:
            raise ValueError(f"test_fraction must be < 1 (some train images), got {self.test_fraction}")


@dataclass(frozen=True)
class SevenScenesParams:
    scenes: int = field(metadata={"min": 1, "max": 7})  # 7-Scenes has 7 scenes
    frames_per_sequence: int = _at_least(2)


@dataclass(frozen=True)
class CampusParams:
    scenes: int = _at_least(1)
    images_per_scene: int = _at_least(1)
    height: int = _at_least(32)
    width: int = _at_least(32)
    focal: float = _at_least(1)


@dataclass(frozen=True)
class AnimatedParams:
    sequences: int = _at_least(1)
    frames: int = _at_least(2)
    height: int = _at_least(32)
    width: int = _at_least(32)


@dataclass(frozen=True)
class SynthParams:
    """The ``synth`` section as params.yaml nests it (read by f2depth.params.section)."""

    root: str
    seed: int
    workers: int = _at_least(0)
    supersample: int = _at_least(1)
    compress_gt: bool
    flow_gt: bool
    nyu_raw: NyuRawParams
    nyu_labeled: NyuLabeledParams
    sevenscenes: SevenScenesParams
    campus: CampusParams
    animated: AnimatedParams
    clips: ClipsParams


@dataclass(frozen=True)
class OutputPaths:
    """Where each dataset goes: the standard layout below ``synth.root``, which the default ``data.*`` entries
    of params.yaml point at."""

    nyu_raw: Path
    nyu_labeled: Path  # the .mat file
    nyu_splits: Path  # splits.mat
    sevenscenes: Path
    campus: Path
    animated: Path
    synth_gt: Path
    clips: Path  # the NYU-raw scenes as MP4 clips (f2depth.synth.clips)

    @classmethod
    def under(cls, root: str | Path) -> OutputPaths:
        """The standard layout below one folder."""
        r = Path(root)
        return cls(nyu_raw=r / "nyu_raw", nyu_labeled=r / "nyu_labeled" / "nyu_depth_v2_labeled.mat",
                   nyu_splits=r / "nyu_labeled" / "splits.mat", sevenscenes=r / "7scenes",
                   campus=r / "campus", animated=r / "animated", synth_gt=r / "synth_gt", clips=r / "clips")
