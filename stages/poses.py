"""DVC stage `poses`: camera poses of every raw frame of the training scenes from multi-view geometry, and
the pose prior of every training pair (train_depth.pose_prior: geometric).

Usage: python stages/poses.py [params.yaml]

Reads `poses`, data.nyu_raw and data.prepared; writes <data.poses>/priors.json and cameras/<scene>.csv
(docs/formats.md) and metrics/poses.json (accuracy against the synthetic ground truth when the prepared set
has it).
"""

from __future__ import annotations

import dataclasses
import sys
import time
from typing import Any

from f2depth import params as P
from f2depth import tracking
from f2depth.data.prepared import PreparedSet
from f2depth.io import write_json
from f2depth.poses.estimate import PosesConfig, estimate_scenes, tuple_priors
from f2depth.poses.metrics import prior_metrics
from f2depth.poses.reconstruct import ReconstructConfig
from f2depth.poses.store import write_poses
from f2depth.poses.tracks import TrackerConfig
from f2depth.stage import run_stage

METRICS = "metrics/poses.json"


def _section(cls: type, values: Any, key: str, path: str) -> Any:
    """A config dataclass from a params sub-section; unknown keys are a ParamsError naming them."""
    values = values or {}
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(values) - names)
    if not isinstance(values, dict) or unknown:
        raise P.ParamsError(f"{path}: {key}: unknown keys {unknown}; known: {sorted(names)}")
    try:
        return cls(**values)
    except (TypeError, ValueError) as exc:
        raise P.ParamsError(f"{path}: {key}: {exc}") from None


def config_from_params(p: dict[str, Any]) -> PosesConfig:
    path = p.get("_file", "params.yaml")
    try:
        return PosesConfig(
            tracker=_section(TrackerConfig, P.get(p, "poses.tracker"), "poses.tracker", path),
            reconstruct=_section(ReconstructConfig, P.get(p, "poses.reconstruct"), "poses.reconstruct", path),
            median_depth=float(P.get(p, "poses.median_depth")),
            min_registered_share=float(P.get(p, "poses.min_registered_share")),
            min_scene_points=int(P.get(p, "poses.min_scene_points")),
            min_shared_points=int(P.get(p, "poses.min_shared_points")),
            workers=int(P.get(p, "poses.workers")),
        )  # fmt: skip
    except ValueError as exc:
        raise P.ParamsError(f"{path}: poses: {exc}") from None


def main(argv: list[str]) -> None:
    p = P.load(argv[1] if len(argv) > 1 else P.DEFAULT_PARAMS)
    config = config_from_params(p)
    t0 = time.perf_counter()
    prepared = PreparedSet(P.get(p, "data.prepared"))
    scene_names = sorted({t.scene for t in prepared.tuples})
    scenes = estimate_scenes(P.get(p, "data.nyu_raw"), scene_names, config)
    priors = tuple_priors(prepared, scenes, config)
    out = P.get(p, "data.poses")
    write_poses(out, scenes, priors, {t.tuple_id: t.scene for t in prepared.tuples}, config)
    metrics = {"median_depth": config.median_depth, "min_registered_share": config.min_registered_share,
               "min_scene_points": config.min_scene_points, "min_shared_points": config.min_shared_points,
               **prior_metrics(prepared, scenes, priors), "seconds": round(time.perf_counter() - t0, 2)}
    write_json(METRICS, metrics)
    tracking.mirror_stage("poses", p, metrics)
    rel = metrics["reliable"]
    print(f"poses: {metrics['frames_registered_share']:.0%} of {metrics['frames']} raw frames registered, "
          f"{metrics['pairs_reliable_share']:.0%} of {metrics['pairs']} training pairs reliable; on those "
          f"rotation error {rel['rotation_error_deg']['median']}° median, translation direction "
          f"{rel['translation_direction_error_deg']['median']}°, scale spread "
          f"{rel['scale_ratio_spread']['median']} (ground truth) in {metrics['seconds']} s → {out}")


if __name__ == "__main__":
    run_stage("poses", main, sys.argv)
