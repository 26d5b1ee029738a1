"""DVC stage `prepare`: the training video (`train_source`: NYU raw, or the ingested video) → data/prepared
(usage: python stages/prepare.py [params.yaml])."""

import sys
from dataclasses import dataclass

from f2depth import params as P
from f2depth import threads, tracking
from f2depth.data.prepare import PrepareConfig, prepare
from f2depth.data.training_video import training_video
from f2depth.io import write_json
from f2depth.stage import run_stage

METRICS = "metrics/prepare.json"


@dataclass(frozen=True)
class SceneList:
    """The ``prepare`` key that is no part of PrepareConfig."""

    train_scenes_file: str | None  # one raw scene name a line; null: the scenes not in the test set


def config_from_params(p: dict) -> tuple[PrepareConfig, SceneList]:
    return P.section(p, "prepare", PrepareConfig, SceneList)


def main(argv: list[str]) -> None:
    p = P.load(argv[1] if len(argv) > 1 else P.DEFAULT_PARAMS)
    threads.use(P.threads(p))
    config, scenes = config_from_params(p)
    video = training_video(p)
    metrics = prepare(
        nyu_raw=video.root,
        nyu_labeled=P.get(p, "data.nyu_labeled"),
        nyu_splits=P.get(p, "data.nyu_splits"),
        out_dir=P.get(p, "data.prepared"),
        config=config,
        synth_gt=P.get(p, "data.synth_gt", None),
        train_scenes_file=scenes.train_scenes_file or video.scenes_file,
    )
    write_json(METRICS, metrics)
    tracking.mirror_stage("prepare", p, metrics)
    print(f"prepare: {metrics['scenes']} scenes, {metrics['frames']} frames, {metrics['tuples']} tuples, "
          f"{metrics['pairs']} pairs in {metrics['seconds']} s → {P.get(p, 'data.prepared')}")


if __name__ == "__main__":
    run_stage("prepare", main, sys.argv)
