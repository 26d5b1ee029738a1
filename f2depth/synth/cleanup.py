"""Removing what a previous generation wrote, so that a smaller or different configuration leaves no
stale scenes behind (the DVC stage keeps its outputs in place: they may be a user's real data).

Only files that the previous run's side-car ground truth vouches for are deleted: for every
``synth_gt/<dataset>/.../<stem>.npz`` the dataset files of that frame, then ``synth_gt`` itself, the
split/points files of the listed scenes and the folders left empty. Nothing happens without a
``synth_gt/manifest.json`` written by this generator.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from f2depth.synth.config import OutputPaths


def _frame_files(paths: OutputPaths, dataset: str, rel: Path) -> list[Path]:
    """Dataset files of the frame whose side-car is ``synth_gt/<dataset>/<rel>``."""
    stem, parent = rel.stem, rel.parent
    if dataset == "nyu_raw":
        return [paths.nyu_raw / parent / f"{stem}.ppm"]
    if dataset == "sevenscenes":
        return [paths.sevenscenes / parent / f"{stem}.{e}" for e in ("color.png", "depth.png", "pose.txt")]
    if dataset == "campus":
        return [paths.campus / parent / f"{stem}.jpg"]
    if dataset == "animated":
        t = paths.animated / "training"
        return [t / "clean" / parent / f"{stem}.png", t / "final" / parent / f"{stem}.png",
                t / "flow" / parent / f"{stem}.flo", t / "occlusions" / parent / f"{stem}.png"]
    return []  # nyu_labeled lives in one .mat file, rewritten as a whole


def _prune_empty(root: Path) -> None:
    if not root.is_dir():
        return
    for d in sorted((p for p in root.rglob("*") if p.is_dir()), key=lambda p: -len(p.parts)):
        if not any(d.iterdir()):
            d.rmdir()


def remove_previous(paths: OutputPaths) -> int:
    """Delete the outputs of the previous generation recorded under ``paths.synth_gt``; returns the
    number of dataset files removed."""
    manifest_file = paths.synth_gt / "manifest.json"
    if not manifest_file.is_file():
        return 0
    manifest = json.loads(manifest_file.read_text())
    if manifest.get("generator") != "f2depth.synth":
        raise RuntimeError(f"{manifest_file}: not written by f2depth.synth; refusing to clean "
                           f"{paths.synth_gt} (point data.synth_gt at the generator's own folder)")
    removed = 0
    for dataset in manifest.get("datasets", {}):
        root = paths.synth_gt / dataset
        for gt in root.rglob("*.npz") if root.is_dir() else []:
            for f in _frame_files(paths, dataset, gt.relative_to(root)):
                if f.is_file():
                    f.unlink()
                    removed += 1
    for scene in manifest.get("datasets", {}).get("sevenscenes", {}).get("scenes", {}):
        for name in ("TestSplit.txt", "TrainSplit.txt"):
            (paths.sevenscenes / Path(scene).parts[0] / name).unlink(missing_ok=True)
    if manifest.get("datasets", {}).get("campus"):
        (paths.campus / "points.csv").unlink(missing_ok=True)
    shutil.rmtree(paths.synth_gt)
    for root in (paths.nyu_raw, paths.sevenscenes, paths.campus, paths.animated):
        _prune_empty(root)
    return removed
