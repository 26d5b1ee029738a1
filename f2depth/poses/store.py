"""The pose-prior folder (``data.poses``, written by the ``poses`` stage; docs/formats.md).

``priors.json``: ``{"format": "f2depth.poses", "version": 1, "median_depth", "min_registered_share",
"min_scene_points", "min_shared_points", "scenes": {scene: summary}, "tuples": {tuple_id: {"scene",
"prev": pair, "next": pair}}}`` with
``pair = {"reliable": bool, "shared_points": int, "src_T_tgt": 4×4 list or null}`` — ``prev.src_T_tgt`` is
``prev_T_target``, ``next.src_T_tgt`` is ``next_T_target``; null where a frame is not registered.
``cameras/<scene>.csv``: ``raw_file,registered,r00,r01,r02,tx,r10,r11,r12,ty,r20,r21,r22,tz`` — the
``world_T_cam`` of every raw frame of the scene (scene-normalised scale; empty numbers when not registered).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from f2depth.errors import DataError
from f2depth.io import atomic_dir, csv_text, write_json, write_text

if TYPE_CHECKING:  # annotations only: reading the priors (train_depth) never loads the estimation code
    from f2depth.poses.estimate import PairPrior, PosesConfig, ScenePoses

FORMAT = "f2depth.poses"
VERSION = 1
CAMERA_HEADER = ["raw_file", "registered", "r00", "r01", "r02", "tx", "r10", "r11", "r12", "ty", "r20", "r21",
                 "r22", "tz"]
_FIX = "re-run `dvc repro poses`"


def _pair(p: PairPrior) -> dict[str, Any]:
    T = p.src_T_tgt if np.all(np.isfinite(p.src_T_tgt)) else None
    return {"reliable": p.reliable, "shared_points": p.shared_points, "src_T_tgt": T}


def _cameras_csv(s: ScenePoses) -> str:
    rows = [[name, int(reg), *([f"{v:.9g}" for v in T[:3].ravel()] if reg else [""] * 12)]
            for name, reg, T in zip(s.raw_files, s.registered, s.world_T_cam)]
    return csv_text(CAMERA_HEADER, rows)


def write_poses(out_dir: str | os.PathLike, scenes: dict[str, ScenePoses],
                priors: dict[str, tuple[PairPrior, PairPrior]], scene_of: dict[str, str],
                config: PosesConfig) -> None:
    """Write the folder in a temporary sibling and swap it into place (the old one stays until then). No
    timing goes in (metrics/poses.json has it), so the same inputs give the same bytes and DVC does not
    re-run the stages downstream after an identical re-run."""
    with atomic_dir(out_dir, "poses", owned=True) as tmp:  # DVC's output (data.poses)
        for name, s in scenes.items():
            write_text(tmp / "cameras" / f"{name}.csv", _cameras_csv(s))
        write_json(tmp / "priors.json", {
            "format": FORMAT, "version": VERSION, "median_depth": config.median_depth,
            "min_registered_share": config.min_registered_share, "min_scene_points": config.min_scene_points,
            "min_shared_points": config.min_shared_points,
            "scenes": {name: {"frames": len(s.raw_files), "registered": int(s.registered.sum()),
                              "points": s.points, "tracks": s.tracks,
                              "sound": s.sound(config.min_registered_share, config.min_scene_points)}
                       for name, s in scenes.items()},
            "tuples": {tid: {"scene": scene_of[tid], "prev": _pair(prev), "next": _pair(nxt)}
                       for tid, (prev, nxt) in priors.items()},
        })  # fmt: skip


@dataclass(frozen=True)
class TuplePrior:
    """prev_T_target, next_T_target (4,4) float32 (identity where not reliable) and their flags."""

    T_prev: np.ndarray
    T_next: np.ndarray
    prev_ok: bool
    next_ok: bool


class PosePriors:
    """Reader of ``priors.json`` (validated at construction)."""

    def __init__(self, root: str | os.PathLike) -> None:
        self.root = Path(root)
        path = self.root / "priors.json"
        if not path.is_file():
            raise DataError(path, "pose priors not found", "run `dvc repro poses` (data.poses)")
        try:
            data = json.loads(path.read_text())
        except json.JSONDecodeError as exc:
            raise DataError(path, f"not valid JSON ({exc})", _FIX) from None
        if not isinstance(data, dict) or data.get("format") != FORMAT or data.get("version") != VERSION:
            raise DataError(path, f"not an {FORMAT} version {VERSION} file", _FIX)
        self.median_depth = float(data["median_depth"])
        self.scenes = dict(data.get("scenes", {}))
        self._tuples: dict[str, TuplePrior] = {}
        for tid, entry in data.get("tuples", {}).items():
            try:
                pairs = [self._matrix(entry[k]) for k in ("prev", "next")]
            except (KeyError, TypeError, ValueError) as exc:
                raise DataError(path, f"tuple {tid}: malformed entry ({exc})", _FIX) from None
            self._tuples[tid] = TuplePrior(pairs[0][0], pairs[1][0], pairs[0][1], pairs[1][1])

    @staticmethod
    def _matrix(pair: dict[str, Any]) -> tuple[np.ndarray, bool]:
        T = pair["src_T_tgt"]
        ok = bool(pair["reliable"]) and T is not None
        M = np.asarray(T, dtype=np.float64) if ok else np.eye(4)
        if M.shape != (4, 4) or not np.all(np.isfinite(M)):
            raise ValueError("src_T_tgt must be a finite 4×4 matrix")
        return M.astype(np.float32), ok

    def __len__(self) -> int:
        return len(self._tuples)

    def __contains__(self, tuple_id: str) -> bool:
        return tuple_id in self._tuples

    def __getitem__(self, tuple_id: str) -> TuplePrior:
        try:
            return self._tuples[tuple_id]
        except KeyError:
            raise KeyError(f"{self.root / 'priors.json'}: no prior for tuple {tuple_id!r}") from None

    def check_covers(self, tuple_ids: list[str]) -> None:
        """DataError when a tuple of the training set has no entry (the file belongs to another set)."""
        missing = [t for t in tuple_ids if t not in self._tuples]
        if missing:
            raise DataError(self.root / "priors.json", f"no prior for {len(missing)} training tuple(s) "
                            f"(first: {missing[0]}); it was made from another prepared set", _FIX)

    @property
    def reliable_share(self) -> float:
        flags = [f for t in self._tuples.values() for f in (t.prev_ok, t.next_ok)]
        return float(np.mean(flags)) if flags else 0.0
