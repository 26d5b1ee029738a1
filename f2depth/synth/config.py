"""Generator settings (the ``synth`` section of params.yaml) and output paths (the ``data`` section)."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from f2depth.params import ParamsError


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

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_params(cls, synth: dict[str, Any], source: str = "params.yaml") -> SynthConfig:
        """Read the ``synth`` section; a missing or bad key raises :class:`ParamsError` naming it."""

        def get(dotted: str, kind: type, minimum: float | None = None):
            node: Any = synth
            for part in dotted.split("."):
                if not isinstance(node, dict) or part not in node:
                    raise ParamsError(f"{source}: missing parameter 'synth.{dotted}'")
                node = node[part]
            try:
                value = kind(node)
            except (TypeError, ValueError):
                raise ParamsError(f"{source}: 'synth.{dotted}' = {node!r} is not a {kind.__name__}") from None
            if minimum is not None and value < minimum:
                raise ParamsError(f"{source}: 'synth.{dotted}' = {value} must be >= {minimum}")
            return value

        fraction = get("nyu_labeled.test_fraction", float, 0.0)
        if fraction >= 1.0:
            raise ParamsError(f"{source}: 'synth.nyu_labeled.test_fraction' must be < 1 (some train images)")
        scenes7 = get("sevenscenes.scenes", int, 1)
        if scenes7 > 7:
            raise ParamsError(f"{source}: 'synth.sevenscenes.scenes' = {scenes7}: 7-Scenes has 7 scenes")
        return cls(
            seed=get("seed", int),
            workers=get("workers", int, 0),
            supersample=get("supersample", int, 1),
            nyu_raw_scenes=get("nyu_raw.scenes", int, 1),
            nyu_raw_frames=get("nyu_raw.frames", int, 2),
            labeled_images=get("nyu_labeled.images", int, 2),
            labeled_test_fraction=fraction,
            sevenscenes_scenes=scenes7,
            sevenscenes_frames=get("sevenscenes.frames_per_sequence", int, 2),
            campus_scenes=get("campus.scenes", int, 1),
            campus_images=get("campus.images_per_scene", int, 1),
            campus_hw=(get("campus.height", int, 32), get("campus.width", int, 32)),
            campus_focal=get("campus.focal", float, 1.0),
            animated_sequences=get("animated.sequences", int, 1),
            animated_frames=get("animated.frames", int, 2),
            animated_hw=(get("animated.height", int, 32), get("animated.width", int, 32)),
            compress_gt=get("compress_gt", bool),
            flow_gt=get("flow_gt", bool),
        )


@dataclass(frozen=True)
class OutputPaths:
    """Where each dataset goes (the ``data.*`` entries of params.yaml)."""

    nyu_raw: Path
    nyu_labeled: Path  # the .mat file
    nyu_splits: Path  # splits.mat
    sevenscenes: Path
    campus: Path
    animated: Path
    synth_gt: Path

    @classmethod
    def from_params(cls, data: dict[str, Any], source: str = "params.yaml") -> OutputPaths:
        keys = {
            "nyu_raw": "nyu_raw",
            "nyu_labeled": "nyu_labeled",
            "nyu_splits": "nyu_splits",
            "sevenscenes": "sevenscenes",
            "campus": "campus",
            "animated": "sintel",
            "synth_gt": "synth_gt",
        }
        out = {}
        for field, key in keys.items():
            if not isinstance(data, dict) or not data.get(key):
                raise ParamsError(f"{source}: missing parameter 'data.{key}'")
            out[field] = Path(data[key])
        return cls(**out)

    @classmethod
    def under(cls, root: str | Path) -> OutputPaths:
        """The standard layout below one folder (tests, ad-hoc runs)."""
        r = Path(root)
        return cls(
            nyu_raw=r / "nyu_raw",
            nyu_labeled=r / "nyu_labeled" / "nyu_depth_v2_labeled.mat",
            nyu_splits=r / "nyu_labeled" / "splits.mat",
            sevenscenes=r / "7scenes",
            campus=r / "campus",
            animated=r / "animated",
            synth_gt=r / "synth_gt",
        )

    def all(self) -> list[Path]:
        return [
            self.nyu_raw,
            self.nyu_labeled,
            self.nyu_splits,
            self.sevenscenes,
            self.campus,
            self.animated,
            self.synth_gt,
        ]
