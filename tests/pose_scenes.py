"""A ray-cast textured room seen by a moving camera of known poses, for the pose-estimation tests.

The renderer (ray–plane intersection in numpy, 2×2 supersampling) is independent of f2depth.poses. The
walls carry a piecewise-constant texture of random grey cells (corners at the cell junctions); a
``textureless`` room has one grey level everywhere (plus sensor noise), where no geometry can be found.
"""

from __future__ import annotations

import numpy as np
from depth_scenes import rotation

HW = (240, 320)
#: Room x ∈ [−2, 2] (right), y ∈ [−1.2, 1.3] (down), z ∈ [−1, 4] (forward); (normal axis, offset).
WALLS = ((0, -2.0), (0, 2.0), (1, -1.2), (1, 1.3), (2, 4.0))
CELL = 0.12  # m


def intrinsics(hw: tuple[int, int] = HW) -> np.ndarray:
    h, w = hw
    return np.array([[0.8 * w, 0.0, (w - 1) / 2 + 1.5], [0.0, 0.8 * w, (h - 1) / 2 - 1.0], [0.0, 0.0, 1.0]])


def camera_path(n: int, step: float = 0.01, yaw_deg: float = 0.15) -> np.ndarray:
    """world_T_cam (n,4,4) of a camera moving sideways and forward while it turns and nods."""
    poses = np.tile(np.eye(4), (n, 1, 1))
    for k in range(n):
        a = np.radians([0.3 * np.sin(0.2 * k), yaw_deg * k, 0.2 * np.cos(0.15 * k)])
        poses[k, :3, :3] = rotation(a)
        poses[k, :3, 3] = [step * k, 0.002 * np.sin(0.3 * k), 0.5 * step * k]
    return poses


def _cells(u: np.ndarray, v: np.ndarray, wall: int) -> np.ndarray:
    iu, iv = np.floor(u / CELL).astype(np.int64), np.floor(v / CELL).astype(np.int64)
    h = (iu * 73856093) ^ (iv * 19349663) ^ (wall * 83492791)
    return ((h % 1000) / 1000.0) * 0.7 + 0.15


def render(world_T_cam: np.ndarray, K: np.ndarray, hw: tuple[int, int] = HW, textureless: bool = False,
           noise: float = 1.0, seed: int = 0) -> np.ndarray:
    """One grey uint8 frame (H, W) of the room; ``noise``: std of the sensor noise in grey levels."""
    h, w = hw
    ss = 2
    sub_pixel = (np.arange(h * ss) + 0.5) / ss - 0.5, (np.arange(w * ss) + 0.5) / ss - 0.5
    v, u = np.meshgrid(*sub_pixel, indexing="ij")
    rays = np.stack([u, v, np.ones_like(u)], -1) @ np.linalg.inv(K).T @ world_T_cam[:3, :3].T
    origin = world_T_cam[:3, 3]
    best = np.full(u.shape, np.inf)
    grey = np.zeros(u.shape)
    for k, (axis, offset) in enumerate(WALLS):
        d = rays[..., axis]
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (offset - origin[axis]) / d
        hit = (s > 0) & (s < best)
        X = origin + s[..., None] * rays
        a, b = [i for i in range(3) if i != axis]
        value = np.full(u.shape, 0.5) if textureless else _cells(X[..., a], X[..., b], k)
        grey = np.where(hit, value, grey)
        best = np.where(hit, s, best)
    img = grey.reshape(h, ss, w, ss).mean(axis=(1, 3)) * 255.0
    img += np.random.default_rng(seed).normal(0.0, noise, img.shape)
    return np.clip(np.round(img), 0, 255).astype(np.uint8)


def sequence(n: int = 21, textureless: bool = False,
             hw: tuple[int, int] = HW) -> tuple[list, np.ndarray, np.ndarray]:
    """(frames, world_T_cam (n,4,4), K) of a room video."""
    K = intrinsics(hw)
    poses = camera_path(n)
    return [render(T, K, hw, textureless, seed=k) for k, T in enumerate(poses)], poses, K
