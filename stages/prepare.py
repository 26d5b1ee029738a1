"""DVC stage `prepare`: NYU raw video → data/prepared (usage: python stages/prepare.py [params.yaml])."""

from __future__ import annotations

import sys

from f2depth import params as P
from f2depth import tracking
from f2depth.data.prepare import PrepareConfig, SuperpixelParams, prepare
from f2depth.io import write_json
from f2depth.stage import run_stage

METRICS = "metrics/prepare.json"


def main(argv: list[str]) -> None:
    p = P.load(argv[1] if len(argv) > 1 else P.DEFAULT_PARAMS)
    config = PrepareConfig(
        height=int(P.get(p, "prepare.height")),
        width=int(P.get(p, "prepare.width")),
        frame_step=int(P.get(p, "prepare.frame_step")),
        crop=int(P.get(p, "prepare.crop")),
        p2net_cxcy_bug=bool(P.get(p, "prepare.p2net_cxcy_bug")),
        superpixels=SuperpixelParams(
            scale=float(P.get(p, "prepare.superpixels.scale")),
            sigma=float(P.get(p, "prepare.superpixels.sigma")),
            min_size=int(P.get(p, "prepare.superpixels.min_size")),
        ),
        workers=int(P.get(p, "prepare.workers")),
        interpolation=str(P.get(p, "prepare.interpolation")),
    )
    metrics = prepare(
        nyu_raw=P.get(p, "data.nyu_raw"),
        nyu_labeled=P.get(p, "data.nyu_labeled"),
        nyu_splits=P.get(p, "data.nyu_splits"),
        out_dir=P.get(p, "data.prepared"),
        config=config,
        synth_gt=P.get(p, "data.synth_gt", None),
        train_scenes_file=P.get(p, "prepare.train_scenes_file", None),
    )
    write_json(METRICS, metrics)
    tracking.mirror_stage("prepare", p, metrics)
    print(f"prepare: {metrics['scenes']} scenes, {metrics['frames']} frames, {metrics['tuples']} tuples, "
          f"{metrics['pairs']} pairs in {metrics['seconds']} s → {P.get(p, 'data.prepared')}")


if __name__ == "__main__":
    run_stage("prepare", main, sys.argv)
