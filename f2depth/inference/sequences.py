"""Posed RGB sequences for ``f2depth reconstruct``: 7-Scenes folders or images with the synthetic ground
truth's side-car ``.npz`` (docs/formats.md). Frames are listed eagerly (poses read and checked) and their
images and reference depths read on demand."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from f2depth.errors import DataError
from f2depth.formats.sevenscenes import SEVENSCENES_K, read_depth_mm, read_pose
from f2depth.ingest.sources import list_images, read_input_image

COLOR_SUFFIX = ".color.png"
_FIX_GT = "regenerate it with `dvc repro synth`"


@dataclass(frozen=True)
class SequenceFrame:
    """One posed frame: ``image`` path, ``world_T_cam`` (4,4) float64, ``K`` (3,3) float64 at the image's
    size, and where its reference depth is (a 7-Scenes ``.depth.png``, a ground-truth ``.npz``, or None)."""

    key: str
    image: Path
    world_T_cam: np.ndarray
    K: np.ndarray
    reference: Path | None

    def rgb(self) -> np.ndarray:
        """RGB uint8 (H,W,3)."""
        return read_input_image(self.image)

    def reference_depth(self, hw: tuple[int, int] | None = None) -> np.ndarray | None:
        """Reference depth (H,W) float32 metres, 0 = invalid (None without one); ``hw`` checks its size."""
        if self.reference is None:
            return None
        if self.reference.suffix == ".npz":
            depth = read_gt_npz(self.reference)[0]
        else:
            depth = read_depth_mm(self.reference, expect_hw=None)
        if hw is not None and depth.shape != tuple(hw):
            raise DataError(self.reference, f"depth is {depth.shape[0]}×{depth.shape[1]} but its image "
                                            f"{self.image.name} is {hw[0]}×{hw[1]}",
                            "the images must lie on the ground truth's pinhole grid (undistort NYU raw "
                            "frames first)")
        return depth


def read_gt_npz(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Side-car ground truth → (depth (H,W) float32 m, 0 = none, world_T_cam (4,4) float64, K (3,3)
    float64). NaN, infinite or negative depth → DataError with their count."""
    p = Path(path)
    if not p.is_file():
        raise DataError(p, "ground-truth .npz not found", _FIX_GT)
    try:
        with np.load(p) as z:
            arrays = {k: z[k] for k in ("depth", "world_T_cam", "K") if k in z.files}
    except (OSError, ValueError, EOFError) as exc:
        raise DataError(p, f"unreadable .npz ({exc})", _FIX_GT) from None
    missing = [k for k in ("depth", "world_T_cam", "K") if k not in arrays]
    if missing:
        raise DataError(p, f"no {missing} arrays", _FIX_GT)
    depth, T, K = arrays["depth"], arrays["world_T_cam"], arrays["K"]
    if depth.ndim != 2 or T.shape != (4, 4) or K.shape != (3, 3):
        raise DataError(p, f"bad shapes: depth {depth.shape}, world_T_cam {T.shape}, K {K.shape}", _FIX_GT)
    if not (np.all(np.isfinite(T)) and np.all(np.isfinite(K))):
        raise DataError(p, "non-finite pose or intrinsics", _FIX_GT)
    bad = int(np.count_nonzero(~np.isfinite(depth) | (depth < 0)))
    if bad:  # the format marks missing depth with 0; NaN or a negative depth is damage
        raise DataError(p, f"depth has {bad} non-finite or negative value(s) of {depth.size} (missing depth "
                           "is 0)", _FIX_GT)
    return depth.astype(np.float32), T.astype(np.float64), K.astype(np.float64)


def _colour_frames(folder: Path) -> list[tuple[str, Path]]:
    """(key, image) of ``frame-XXXXXX.color.png`` files, or of plain images when there are none."""
    colour = sorted(p for p in folder.iterdir() if p.name.endswith(COLOR_SUFFIX))
    if colour:
        return [(p.name[: -len(COLOR_SUFFIX)], p) for p in colour]
    return [(p.stem, p) for p in list_images(folder)]


def _subsample(items: list, stride: int, max_frames: int | None) -> list:
    if stride < 1:
        raise ValueError(f"stride must be ≥ 1, got {stride}")
    items = items[::stride]
    return items[:max_frames] if max_frames is not None else items


def sevenscenes_sequence(seq_dir: str | os.PathLike, stride: int = 1,
                         max_frames: int | None = None) -> list[SequenceFrame]:
    """A 7-Scenes sequence folder (``<scene>/seq-XX``): colour frames, ``.pose.txt`` poses (world_T_cam),
    the nominal 7-Scenes K, and the Kinect ``.depth.png`` as reference depth where present."""
    folder = Path(seq_dir)
    if not folder.is_dir():
        raise DataError(folder, "sequence folder not found", "give a 7-Scenes <scene>/seq-XX folder")
    colour = sorted(p for p in folder.iterdir() if p.name.endswith(COLOR_SUFFIX))
    if not colour:
        raise DataError(folder, f"no frame-XXXXXX{COLOR_SUFFIX} files",
                        "give a 7-Scenes <scene>/seq-XX folder")
    frames = []
    for image in _subsample(colour, stride, max_frames):
        key = image.name[: -len(COLOR_SUFFIX)]
        depth = folder / f"{key}.depth.png"
        frames.append(SequenceFrame(key, image, read_pose(folder / f"{key}.pose.txt"), SEVENSCENES_K.copy(),
                                    depth if depth.is_file() else None))
    return frames


def synth_sequence(image_dir: str | os.PathLike, gt_dir: str | os.PathLike, stride: int = 1,
                   max_frames: int | None = None) -> list[SequenceFrame]:
    """Images (``*.color.png`` or any supported image) with side-car ground truth ``<gt_dir>/<key>.npz``
    (key: file name without ``.color.png`` or the extension) for pose, K and reference depth."""
    folder, gt = Path(image_dir), Path(gt_dir)
    if not folder.is_dir():
        raise DataError(folder, "sequence folder not found", "give the folder of the sequence's images")
    if not gt.is_dir():
        raise DataError(gt, "ground-truth folder not found",
                        "give data/raw/synth_gt/<dataset>/<scene>[/<seq>]")
    frames = []
    for key, image in _subsample(_colour_frames(folder), stride, max_frames):
        npz = gt / f"{key}.npz"
        _, T, K = read_gt_npz(npz)
        frames.append(SequenceFrame(key, image, T, K, npz))
    return frames
