"""DVC stage `keypoints`: DSO keypoints of every prepared frame.

Usage: python stages/keypoints.py [params.yaml]

Selects on the full-resolution crop of each frame's raw file (keypoints.source: full_resolution, as P²Net's
datasets/nyu_dataset.py; the raw frames of `train_source`) or on the prepared image (keypoints.source:
prepared).
Writes <data.keypoints>/train.npz (docs/formats.md), metrics/keypoints.json and overlay PNGs of a few frames
into keypoints.overlay_dir. Bad data or parameters end the stage with one line naming the file and the fix.
"""

import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from f2depth import params as P
from f2depth import threads, tracking
from f2depth.data.training_video import training_video
from f2depth.io import write_json
from f2depth.keypoints.extract import SOURCES, extract_keypoints
from f2depth.keypoints.presets import PRESETS, get_preset
from f2depth.stage import run_stage

METRICS = "metrics/keypoints.json"


@dataclass(frozen=True)
class KeypointsParams:
    """The ``keypoints`` section."""

    source: Literal[SOURCES]
    preset: Literal[tuple(PRESETS)]
    options: dict  # overrides of the preset's fields
    sequence: bool
    workers: int = field(metadata={"min": 0})
    overlays: int = field(metadata={"min": 0})
    overlay_dir: str

    def __post_init__(self) -> None:
        get_preset(self.preset, **self.options)  # unknown or out-of-range options fail here, before any work


def config_from_params(p: dict) -> KeypointsParams:
    return P.section(p, "keypoints", KeypointsParams)


def main(argv: list[str]) -> None:
    p = P.load(argv[1] if len(argv) > 1 else P.DEFAULT_PARAMS)
    threads.use(P.threads(p))
    cfg = config_from_params(p)
    out_file = Path(P.get(p, "data.keypoints")) / "train.npz"
    source = cfg.source
    metrics = extract_keypoints(
        prepared=P.get(p, "data.prepared"), out_file=out_file, overlay_dir=cfg.overlay_dir, preset=cfg.preset,
        options=cfg.options, workers=cfg.workers, sequence=cfg.sequence, overlays=cfg.overlays, source=source,
        nyu_raw=training_video(p).root if source == "full_resolution" else None)
    write_json(METRICS, metrics)
    tracking.mirror_stage("keypoints", p, metrics, artifacts=(cfg.overlay_dir,))
    per = metrics["points_per_image"]
    print(f"keypoints: {metrics['frames']} frames selected on the {source} image, {per['mean']:.0f} points "
          f"per image (min {per['min']}, max {per['max']}), {metrics['share_below_100']:.1%} below 100, "
          f"{metrics['seconds']} s → {out_file}")


if __name__ == "__main__":
    run_stage("keypoints", main, sys.argv)
