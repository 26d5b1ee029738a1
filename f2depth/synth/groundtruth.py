"""Exact ground truth of a static scene: rigid optical flow and occlusion from depth and poses, and
Kinect-like holes for the NYU ``rawDepths``.

Pixel (u, v) = (column, row), centres at integers; depth is z-depth in metres; ``tgt_T_src`` maps points
of the source camera frame into the target camera frame — the pose convention of :mod:`f2depth.geometry`
(its ``relative_pose`` and ``rigid_flow`` give the same matrices and flows, a test holds them together).
The ground truth keeps its own float64 numpy projection on purpose: it divides by the exact z, where the
training projection adds Monodepth2's ``PROJ_EPS`` to z (up to 7e-5 px off at NYU's size), and it runs in
the synth's numpy worker processes without torch tensors.
"""

from __future__ import annotations

import cv2
import numpy as np

from f2depth.synth.textures import value_noise


def relative_pose(world_T_src: np.ndarray, world_T_tgt: np.ndarray) -> np.ndarray:
    """tgt_T_src (4, 4) = inv(world_T_tgt) · world_T_src."""
    return np.linalg.inv(world_T_tgt) @ world_T_src


def rigid_flow(depth: np.ndarray, K: np.ndarray, tgt_T_src: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Flow of every source pixel into the target view.

    depth (H, W) metres of the source view; K (3, 3); tgt_T_src (4, 4).
    Returns flow (H, W, 2) float32 pixels (x first) and the points' z-depth in the target (H, W) float32.
    """
    h, w = depth.shape
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    z = depth.astype(np.float64)
    x = (u - K[0, 2]) / K[0, 0] * z
    y = (v - K[1, 2]) / K[1, 1] * z
    R, t = tgt_T_src[:3, :3], tgt_T_src[:3, 3]
    xt = R[0, 0] * x + R[0, 1] * y + R[0, 2] * z + t[0]
    yt = R[1, 0] * x + R[1, 1] * y + R[1, 2] * z + t[1]
    zt = R[2, 0] * x + R[2, 1] * y + R[2, 2] * z + t[2]
    zs = np.where(np.abs(zt) > 1e-9, zt, 1e-9)
    ut = K[0, 0] * xt / zs + K[0, 2]
    vt = K[1, 1] * yt / zs + K[1, 2]
    flow = np.stack([ut - u, vt - v], axis=-1).astype(np.float32)
    return flow, zt.astype(np.float32)


def occlusion(flow: np.ndarray, z_tgt: np.ndarray, depth_tgt: np.ndarray,
              rel_tol: float = 0.02) -> np.ndarray:
    """Pixels of the source that are not visible at their flow target: (H, W) bool.

    A pixel is visible when it lands inside the target image in front of the camera and its predicted
    depth ``z_tgt`` agrees with the target's depth there within ``rel_tol``: either the bilinearly
    interpolated inverse depth (exact inside a plane) or, at depth edges, some depth of the 3×3
    neighbourhood is at least as far (nothing in front of the point) and some is at most as far.
    """
    h, w = depth_tgt.shape
    gu, gv = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    x, y = gu + flow[..., 0], gv + flow[..., 1]
    inside = (x >= 0) & (x <= w - 1) & (y >= 0) & (y <= h - 1) & (z_tgt > 0)
    d = depth_tgt.astype(np.float32)
    inv = cv2.remap(1.0 / np.maximum(d, 1e-6), x, y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    kernel = np.ones((3, 3), np.uint8)
    far = cv2.remap(cv2.dilate(d, kernel), x, y, cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE)
    near = cv2.remap(cv2.erode(d, kernel), x, y, cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE)
    tol = rel_tol * np.abs(z_tgt)
    match = np.abs(1.0 / np.maximum(inv, 1e-9) - z_tgt) < tol
    match |= (far >= z_tgt - tol) & (near <= z_tgt + tol)
    return ~(inside & match)


def kinect_raw_depth(depth: np.ndarray, rgb: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A Kinect-like raw depth map from exact depth (H, W) and the RGB image (H, W, 3) uint8.

    Disparity quantisation (Δz ≈ 2.85e-3 · z² m), zero holes in the shadow band on the far side of
    depth edges, on dark surfaces, in a few random 'specular' blobs, beyond 10 m and in a thin band at
    the left border (where the depth camera does not overlap the RGB one).
    """
    h, w = depth.shape
    step = 2.85e-3
    disp = np.round(1.0 / np.maximum(depth, 1e-3) / step) * step
    raw = (1.0 / np.maximum(disp, 1e-6)).astype(np.float32)
    holes = depth > 10.0
    logd = np.log(np.maximum(depth, 1e-3))
    edge = np.zeros((h, w), bool)
    edge[:, 1:] |= np.abs(np.diff(logd, axis=1)) > 0.05
    edge[1:, :] |= np.abs(np.diff(logd, axis=0)) > 0.05
    k = int(rng.integers(2, 5))
    kernel = np.ones((2 * k + 1, 2 * k + 1), np.uint8)
    near_edge = cv2.dilate(edge.astype(np.uint8), kernel) > 0
    local_min = cv2.erode(depth.astype(np.float32), kernel)
    holes |= near_edge & (depth > 1.03 * local_min)
    lum = rgb.astype(np.float32).mean(axis=2)
    blob = value_noise(rng, h, w, cells=12.0)
    holes |= (lum < 22) & (blob > -0.3)
    holes |= blob > np.quantile(blob, 0.985)
    holes[:, : int(rng.integers(4, 12))] = True
    raw[holes] = 0.0
    return raw
