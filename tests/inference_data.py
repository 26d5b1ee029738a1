"""Small inputs for the f2depth.inference / CLI tests, written into tmp folders by the tests.

Import from a test module as ``import inference_data``.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import fakes
import numpy as np
import torch

from f2depth.depth import DepthModel, DepthModelConfig, save_checkpoint
from f2depth.inference.outputs import _PLY_DTYPE
from f2depth.io import write_rgb
from f2depth.synth import writers

NET_HW = (64, 96)


def make_checkpoint(path: Path, seed: int = 0, hw: tuple[int, int] = NET_HW) -> Path:
    """A randomly initialised DepthModel at ``hw`` saved with ``save_checkpoint``."""
    torch.manual_seed(seed)
    save_checkpoint(path, DepthModel(DepthModelConfig(*hw)))
    return path


def write_images(folder: Path, count: int, hw: tuple[int, int] = (60, 80), seed: int = 0) -> list[Path]:
    """``img_00.png`` … smooth random RGB images; returns their paths."""
    paths = []
    for i in range(count):
        p = folder / f"img_{i:02d}.png"
        fakes.write_rgb(p, fakes.smooth_image(hw, seed + i))
        paths.append(p)
    return paths


def write_video(path: Path, count: int, hw: tuple[int, int] = (60, 80), seed: int = 0) -> list[np.ndarray]:
    """An MJPG .avi of ``count`` smooth RGB frames (no extra codecs needed); returns the RGB frames."""
    path.parent.mkdir(parents=True, exist_ok=True)
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10, (hw[1], hw[0]))
    assert writer.isOpened()
    frames = [fakes.smooth_image(hw, seed + i) for i in range(count)]
    for rgb in frames:
        writer.write(np.ascontiguousarray(rgb[..., ::-1]))
    writer.release()
    return frames


# ---- a posed sequence inside a box room -------------------------------------------------------------

ROOM_LO = np.array([-2.0, -1.5, -2.0])
ROOM_HI = np.array([2.0, 1.5, 2.0])


def yaw_pose(yaw: float, t: tuple[float, float, float]) -> np.ndarray:
    """world_T_cam rotating about the (downward) y axis by ``yaw`` rad, camera at ``t``."""
    c, s = np.cos(yaw), np.sin(yaw)
    T = np.eye(4)
    T[:3, :3] = [[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]]
    T[:3, 3] = t
    return T


def render_box(world_T_cam: np.ndarray, K: np.ndarray, hw: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Ray-cast the inside of the box room: (rgb (H,W,3) uint8 checker per wall, z-depth (H,W) float32)."""
    h, w = hw
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1)  # z = 1
    R, o = world_T_cam[:3, :3], world_T_cam[:3, 3]
    d = rays @ R.T
    with np.errstate(divide="ignore", invalid="ignore"):
        t_axes = np.where(d > 0, (ROOM_HI - o) / d, (ROOM_LO - o) / d)
    t_axes = np.where(np.isfinite(t_axes) & (t_axes > 0), t_axes, np.inf)
    t = t_axes.min(-1)
    X = o + d * t[..., None]
    cells = np.floor(X / 0.5).astype(int).sum(-1) % 2
    wall = t_axes.argmin(-1)
    palette = np.array([[200, 80, 60], [60, 160, 90], [70, 90, 200]], np.float64)
    rgb = palette[wall] * (0.6 + 0.4 * cells[..., None])
    return rgb.astype(np.uint8), t.astype(np.float32)


def box_distance(points: np.ndarray) -> np.ndarray:
    """Distance (N,) of points (N,3) inside the room to its nearest wall."""
    return np.minimum(points - ROOM_LO, ROOM_HI - points).min(-1)


def write_box_sequence(images: Path, gt: Path, count: int = 6, hw: tuple[int, int] = (96, 128),
                       sevenscenes: bool = False) -> list[np.ndarray]:
    """A turning camera in the box room. Images ``frame-XXXXXX.color.png`` in ``images`` and side-car
    ground truth ``frame-XXXXXX.npz`` in ``gt``; with ``sevenscenes`` also the 7-Scenes ``.pose.txt``
    and ``.depth.png`` beside the images (use hw=(480, 640): the 7-Scenes K is fixed). Returns poses."""
    if sevenscenes:
        K = np.array([[585.0, 0.0, 320.0], [0.0, 585.0, 240.0], [0.0, 0.0, 1.0]])
    else:
        f = 0.8 * hw[1]
        K = np.array([[f, 0.0, (hw[1] - 1) / 2], [0.0, f, (hw[0] - 1) / 2], [0.0, 0.0, 1.0]])
    poses = []
    for k in range(count):
        T = yaw_pose(2 * np.pi * k / count, (0.3 * np.cos(k), 0.1, 0.3 * np.sin(k)))
        rgb, depth = render_box(T, K, hw)
        stem = f"frame-{k:06d}"
        write_rgb(images / f"{stem}.color.png", rgb)
        writers.write_gt(gt / f"{stem}.npz", depth, T, K)
        if sevenscenes:
            writers.write_pose_txt(images / f"{stem}.pose.txt", T)
            writers.write_depth_mm(images / f"{stem}.depth.png", depth)
        poses.append(T)
    return poses


def read_ply_points(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Read a point cloud written by ``f2depth.inference.outputs.encode_ply`` → (points (N,3) float32,
    colours (N,3) uint8)."""
    data = Path(path).read_bytes()
    end = data.find(b"end_header\n")
    assert data.startswith(b"ply\n") and end >= 0, f"{path}: not a PLY file"
    header = data[:end].decode("ascii").splitlines()
    assert "format binary_little_endian 1.0" in header
    n = next(int(line.split()[2]) for line in header if line.startswith("element vertex"))
    verts = np.frombuffer(data, _PLY_DTYPE, count=n, offset=end + len(b"end_header\n"))
    return np.stack([verts[a] for a in "xyz"], 1), np.stack([verts[c] for c in ("red", "green", "blue")], 1)
