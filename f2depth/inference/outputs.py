"""Per-frame output files of ``f2depth predict``, each written atomically (f2depth.io):

- ``<name>_depth_mm.png``: uint16 depth in millimetres, 0 = no depth; a depth is clipped to [1, 65534] mm,
  so that none reads back as missing (0, or the 65535 of 7-Scenes' convention),
- ``<name>_depth.npy``: float32 (H, W) depth in metres,
- ``<name>_depth_color.png``: the disparity (1/depth) colour-mapped with magma (minimum → black,
  95th percentile → white),
- ``<name>_points.ply`` (optional): binary little-endian PLY, one vertex per pixel (row-major order) with
  float ``x y z`` (metres, camera frame: x right, y down, z forward) and uchar ``red green blue``.
"""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np
import torch

from f2depth.geometry import backproject
from f2depth.io import imwrite, save_npy, write_bytes

SUFFIXES = {"mm": "_depth_mm.png", "npy": "_depth.npy", "color": "_depth_color.png", "ply": "_points.ply"}
#: the largest depth a ``_depth_mm.png`` holds: 65535 is the "no depth" code of Kinect-style depth PNGs
MM_MAX = 65534
_PLY_DTYPE = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"), ("green", "u1"),
                       ("blue", "u1")])


def depth_to_mm(depth: np.ndarray) -> np.ndarray:
    """depth (H,W) metres → uint16 millimetres, rounded; a positive depth is clipped to [1, MM_MAX], so that
    it never becomes a "no depth" code (0 or 65535); 0, negative and NaN depth → 0."""
    d = np.asarray(depth, np.float64)
    valid = d > 0
    mm = np.clip(np.rint(np.where(valid, d, 0.0) * 1000.0), 1, MM_MAX)
    return np.where(valid, mm, 0).astype(np.uint16)


def mm_clipped(depth: np.ndarray) -> int:
    """How many positive depths (H,W metres) :func:`depth_to_mm` clips: beyond MM_MAX mm, or below 0.5 mm."""
    mm = np.rint(np.asarray(depth, np.float64) * 1000.0)
    return int(np.count_nonzero((np.asarray(depth) > 0) & ((mm > MM_MAX) | (mm < 1))))


def colorize_depth(depth: np.ndarray, percentile: float = 95.0) -> np.ndarray:
    """depth (H,W) metres → BGR uint8 (H,W,3): disparity mapped from its minimum to its ``percentile``
    (Monodepth2's display) through magma; near is bright, far is dark, invalid (≤ 0) is black."""
    valid = depth > 0
    disp = np.where(valid, 1.0 / np.where(valid, depth, 1.0), 0.0)
    vmin = float(disp[valid].min()) if valid.any() else 0.0
    vmax = float(np.percentile(disp[valid], percentile)) if valid.any() else 1.0
    grey = np.clip((disp - vmin) / max(vmax - vmin, 1e-12) * 255.0, 0, 255).astype(np.uint8)
    out = cv2.applyColorMap(grey, cv2.COLORMAP_MAGMA)
    out[~valid] = 0
    return out


def point_cloud(depth: np.ndarray, rgb: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Back-project every pixel with depth > 0: depth (H,W) metres, rgb (H,W,3) uint8, K (3,3) →
    (points (N,3) float32 metres in the camera frame, colours (N,3) uint8), pixels in row-major order."""
    d = torch.from_numpy(np.ascontiguousarray(depth, np.float64))[None, None]
    k_inv = torch.linalg.inv(torch.from_numpy(np.asarray(K, np.float64)))[None]
    pts = backproject(d, k_inv)[0].permute(1, 2, 0).reshape(-1, 3).numpy()
    valid = (np.asarray(depth) > 0).reshape(-1)
    return pts[valid].astype(np.float32), np.asarray(rgb, np.uint8).reshape(-1, 3)[valid]


def encode_ply(points: np.ndarray, colours: np.ndarray) -> bytes:
    """Binary little-endian PLY of coloured points: points (N,3) float, colours (N,3) uint8."""
    n = len(points)
    verts = np.empty(n, _PLY_DTYPE)
    for i, axis in enumerate("xyz"):
        verts[axis] = points[:, i]
    for i, channel in enumerate(("red", "green", "blue")):
        verts[channel] = colours[:, i]
    header = ("ply\nformat binary_little_endian 1.0\ncomment written by f2depth predict\n"
              f"element vertex {n}\nproperty float x\nproperty float y\nproperty float z\n"
              "property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n")
    return header.encode("ascii") + verts.tobytes()


def write_frame(out_dir: str | os.PathLike, name: str, depth: np.ndarray, rgb: np.ndarray,
                K: np.ndarray | None = None) -> list[Path]:
    """Write the outputs of one frame (module docstring); the PLY only when ``K`` is given. depth (H,W)
    metres, rgb (H,W,3) uint8. Returns the paths written: all of them, or none when one fails (each file
    atomically, and the ones already written removed)."""
    out = Path(out_dir)
    depth = np.asarray(depth, np.float32)
    paths = [out / f"{name}{SUFFIXES[k]}" for k in ("mm", "npy", "color")]
    writers = [lambda p: imwrite(p, depth_to_mm(depth)), lambda p: save_npy(p, depth),
               lambda p: imwrite(p, colorize_depth(depth))]
    if K is not None:
        paths.append(out / f"{name}{SUFFIXES['ply']}")
        writers.append(lambda p: write_bytes(p, encode_ply(*point_cloud(depth, rgb, K))))
    written: list[Path] = []
    try:  # all of a frame's files or none: a failure (a full disk) removes the ones already written
        for path, write in zip(paths, writers):
            write(path)
            written.append(path)
    except BaseException:
        for path in written:
            path.unlink(missing_ok=True)
        raise
    return paths
