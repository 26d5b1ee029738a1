"""DVC stage `keypoints`: DSO keypoints of every prepared frame.

Usage: python stages/keypoints.py [params.yaml]

Selects on the full-resolution crop of each frame's NYU raw file (keypoints.source: full_resolution, as
P²Net's datasets/nyu_dataset.py; reads data.nyu_raw) or on the prepared image (keypoints.source: prepared).
Writes <data.keypoints>/train.npz (docs/formats.md), metrics/keypoints.json and overlay PNGs of a few frames
into keypoints.overlay_dir. Bad data or parameters end the stage with one line naming the file and the fix.
"""

from __future__ import annotations

import sys
from pathlib import Path

from f2depth import params as P
from f2depth import tracking
from f2depth.data.errors import DataError
from f2depth.io import write_json
from f2depth.keypoints.extract import SOURCES, extract_keypoints
from f2depth.stage import run_stage

METRICS = "metrics/keypoints.json"


def main(argv: list[str]) -> None:
    p = P.load(argv[1] if len(argv) > 1 else P.DEFAULT_PARAMS)
    out_file = Path(P.get(p, "data.keypoints")) / "train.npz"
    source = str(P.get(p, "keypoints.source"))
    if source not in SOURCES:
        raise SystemExit(f"{p.get('_file', 'params.yaml')}: keypoints.source is {source!r}; "
                         f"set it to one of {', '.join(SOURCES)}")
    try:
        metrics = extract_keypoints(
            prepared=P.get(p, "data.prepared"),
            out_file=out_file,
            overlay_dir=P.get(p, "keypoints.overlay_dir"),
            preset=str(P.get(p, "keypoints.preset")),
            options=P.get(p, "keypoints.options", None) or {},
            workers=int(P.get(p, "keypoints.workers")),
            sequence=bool(P.get(p, "keypoints.sequence", False)),
            overlays=int(P.get(p, "keypoints.overlays")),
            source=source,
            nyu_raw=P.get(p, "data.nyu_raw") if source == "full_resolution" else None,
        )
    except DataError as exc:
        raise SystemExit(f"keypoints: {exc}") from None
    write_json(METRICS, metrics)
    tracking.mirror_stage("keypoints", p, metrics, artifacts=(P.get(p, "keypoints.overlay_dir"),))
    per = metrics["points_per_image"]
    print(f"keypoints: {metrics['frames']} frames selected on the {source} image, {per['mean']:.0f} points "
          f"per image (min {per['min']}, max {per['max']}), {metrics['share_below_100']:.1%} below 100, "
          f"{metrics['seconds']} s → {out_file}")


if __name__ == "__main__":
    run_stage("keypoints", main, sys.argv)
