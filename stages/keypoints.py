"""DVC stage `keypoints`: DSO keypoints of every prepared frame.

Usage: python stages/keypoints.py [params.yaml]

Writes <data.keypoints>/train.npz (docs/formats.md), metrics/keypoints.json and overlay PNGs of a few
frames into keypoints.overlay_dir.
"""

from __future__ import annotations

import sys
from pathlib import Path

from f2depth import params as P
from f2depth import tracking
from f2depth.io import write_json
from f2depth.keypoints.extract import extract_keypoints

METRICS = "metrics/keypoints.json"


def main(argv: list[str]) -> None:
    p = P.load(argv[1] if len(argv) > 1 else P.DEFAULT_PARAMS)
    out_file = Path(P.get(p, "data.keypoints")) / "train.npz"
    metrics = extract_keypoints(
        prepared=P.get(p, "data.prepared"),
        out_file=out_file,
        overlay_dir=P.get(p, "keypoints.overlay_dir"),
        preset=str(P.get(p, "keypoints.preset")),
        options=P.get(p, "keypoints.options", None) or {},
        workers=int(P.get(p, "keypoints.workers")),
        sequence=bool(P.get(p, "keypoints.sequence", False)),
        overlays=int(P.get(p, "keypoints.overlays")),
    )
    write_json(METRICS, metrics)
    tracking.mirror_stage("keypoints", p, metrics, artifacts=(P.get(p, "keypoints.overlay_dir"),))
    per = metrics["points_per_image"]
    print(f"keypoints: {metrics['frames']} frames, {per['mean']:.0f} points per image "
          f"(min {per['min']}, max {per['max']}), {metrics['share_below_100']:.1%} below 100, "
          f"{metrics['seconds']} s → {out_file}")


if __name__ == "__main__":
    main(sys.argv)
