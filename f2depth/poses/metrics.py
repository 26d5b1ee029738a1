"""Accuracy of the pose priors against the synthetic default's ground truth (the ``poses`` stage's metrics).

For every training pair with a prior (target → prev and target → next of each tuple) against the true
``src_T_tgt`` of the prepared ground truth: the rotation error (degrees, angle of R_est·R_trueᵀ), the
translation direction error (degrees between the two translations) and the scale ratio |t_est| / |t_true|.
Each scene has one free scale, so the ratio is divided by its scene's median: the spread
|ratio / scene median − 1| says how consistent the scale is from pair to pair within a scene (0 = exactly
one scale per scene). Reported over the reliable pairs and over every pair whose frames are registered.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from f2depth.formats.prepared import PreparedSet
from f2depth.poses.estimate import PairPrior, ScenePoses


def rotation_error_deg(R_est: np.ndarray, R_true: np.ndarray) -> float:
    c = (np.trace(R_est @ R_true.T) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def direction_error_deg(t_est: np.ndarray, t_true: np.ndarray) -> float:
    c = float(t_est @ t_true) / max(float(np.linalg.norm(t_est) * np.linalg.norm(t_true)), 1e-300)
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def _summary(values: list[float]) -> dict[str, float | None]:
    if not values:
        return {"median": None, "p90": None, "max": None}
    v = np.asarray(values, dtype=np.float64)
    return {"median": round(float(np.median(v)), 4), "p90": round(float(np.percentile(v, 90)), 4),
            "max": round(float(v.max()), 4)}


def _errors(rows: list[dict[str, Any]]) -> dict[str, Any]:
    spread = []
    for scene in {r["scene"] for r in rows}:
        ratios = np.array([r["ratio"] for r in rows if r["scene"] == scene])
        spread += list(np.abs(ratios / np.median(ratios) - 1.0))
    return {"pairs": len(rows), "rotation_error_deg": _summary([r["rot"] for r in rows]),
            "translation_direction_error_deg": _summary([r["dir"] for r in rows]),
            "scale_ratio_spread": _summary(spread)}


def prior_metrics(prepared: PreparedSet, scenes: dict[str, ScenePoses],
                  priors: dict[str, tuple[PairPrior, PairPrior]]) -> dict[str, Any]:
    """The stage metrics (module docstring); the error blocks are empty without ground truth."""
    rows = []
    n_pairs = 0
    for t in prepared.tuples:
        for src, prior in zip((t.prev, t.next), priors[t.tuple_id]):
            n_pairs += 1
            known = prepared.has_gt(t.target) and prepared.has_gt(src)
            if not known or not np.all(np.isfinite(prior.src_T_tgt)):
                continue
            world_tgt, world_src = prepared.gt(t.target)[1], prepared.gt(src)[1]
            true = np.linalg.inv(world_src) @ world_tgt
            est = prior.src_T_tgt
            length = max(float(np.linalg.norm(true[:3, 3])), 1e-12)
            rows.append({"scene": t.scene, "reliable": prior.reliable,
                         "rot": rotation_error_deg(est[:3, :3], true[:3, :3]),
                         "dir": direction_error_deg(est[:3, 3], true[:3, 3]),
                         "ratio": float(np.linalg.norm(est[:3, 3])) / length})
    frames = sum(len(s.raw_files) for s in scenes.values())
    registered = sum(int(s.registered.sum()) for s in scenes.values())
    reliable = sum(p.reliable for t in prepared.tuples for p in priors[t.tuple_id])  # the training pairs
    per_scene = {}
    for name, s in scenes.items():
        mine = [r for r in rows if r["scene"] == name and r["reliable"]]
        per_scene[name] = {
            "frames": len(s.raw_files), "registered": int(s.registered.sum()), "points": s.points,
            "tracks": s.tracks, "seconds": s.seconds,
            "reliable_pairs": sum(p.reliable for t in prepared.tuples if t.scene == name
                                  for p in priors[t.tuple_id]),
            "rotation_error_deg_median": _summary([r["rot"] for r in mine])["median"],
            "translation_direction_error_deg_median": _summary([r["dir"] for r in mine])["median"],
            "scale_to_metric": round(float(np.median([r["ratio"] for r in mine])), 4) if mine else None,
        }  # fmt: skip
    return {"scenes": len(scenes), "frames": frames,
            "frames_registered_share": round(registered / max(frames, 1), 4), "pairs": n_pairs,
            "pairs_reliable_share": round(reliable / max(n_pairs, 1), 4),
            "reliable": _errors([r for r in rows if r["reliable"]]), "registered": _errors(rows),
            "per_scene": per_scene}
