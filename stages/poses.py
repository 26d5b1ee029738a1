"""DVC stage `poses`: camera poses of every raw frame of the training scenes from multi-view geometry, and
the pose prior of every training pair (train_depth.pose_prior: geometric).

Usage: python stages/poses.py [params.yaml]

Reads `poses`, the training video (`train_source`: data.nyu_raw or data.ingested) and data.prepared;
writes <data.poses>/priors.json and cameras/<scene>.csv (docs/formats.md) and metrics/poses.json (accuracy
against the synthetic ground truth when the prepared set has it).
"""

from __future__ import annotations

import sys
import time
from typing import Any

from f2depth import params as P
from f2depth import threads, tracking
from f2depth.data.training_video import training_video
from f2depth.formats.prepared import PreparedSet
from f2depth.io import write_json
from f2depth.poses.estimate import PosesConfig, estimate_scenes, tuple_priors
from f2depth.poses.metrics import prior_metrics
from f2depth.poses.store import write_poses
from f2depth.stage import run_stage

METRICS = "metrics/poses.json"


def config_from_params(p: dict[str, Any]) -> PosesConfig:
    return P.section(p, "poses", PosesConfig)


def main(argv: list[str]) -> None:
    p = P.load(argv[1] if len(argv) > 1 else P.DEFAULT_PARAMS)
    threads.use(P.threads(p))
    config = config_from_params(p)
    t0 = time.perf_counter()
    prepared = PreparedSet(P.get(p, "data.prepared"))
    scene_names = sorted({t.scene for t in prepared.tuples})
    scenes = estimate_scenes(training_video(p).root, scene_names, config, prepared.source_camera)
    priors = tuple_priors(prepared, scenes, config)
    out = P.get(p, "data.poses")
    write_poses(out, scenes, priors, {t.tuple_id: t.scene for t in prepared.tuples + prepared.val_tuples},
                config)
    metrics = {"median_depth": config.median_depth, "min_registered_share": config.min_registered_share,
               "min_scene_points": config.min_scene_points, "min_shared_points": config.min_shared_points,
               **prior_metrics(prepared, scenes, priors), "seconds": round(time.perf_counter() - t0, 2)}
    write_json(METRICS, metrics)
    tracking.mirror_stage("poses", p, metrics)
    rel = metrics["reliable"]
    truth = ("no ground truth to score them against" if rel['rotation_error_deg']['median'] is None else
             f"on those rotation error {rel['rotation_error_deg']['median']}° median, translation direction "
             f"{rel['translation_direction_error_deg']['median']}°, scale spread "
             f"{rel['scale_ratio_spread']['median']} (ground truth)")
    print(f"poses: {metrics['frames_registered_share']:.0%} of {metrics['frames']} raw frames registered, "
          f"{metrics['pairs_reliable_share']:.0%} of {metrics['pairs']} training pairs reliable; {truth} in "
          f"{metrics['seconds']} s → {out}")


if __name__ == "__main__":
    run_stage("poses", main, sys.argv)
