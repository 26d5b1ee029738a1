"""Small ray-traced scenes for the depth/loss tests: a textured plane seen by two cameras.

The renderer is independent of f2depth.geometry (ray–plane intersection in numpy), so comparing
the library's rigid flow or warps with it is a real check.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

# Plane nᵀX = 1 in the target camera frame: depth from ~2.0 m (top left) to ~3.0 m (bottom right).
PLANE_N = np.array([0.06, 0.08, 0.4])
FREQS = np.array(
    [
        [9.0, 4.0, 0.0],
        [-5.0, 13.0, 1.0],
        [17.0, -8.0, 2.0],
        [3.0, 21.0, 0.5],
        [25.0, 6.0, 0.0],
        [-11.0, -15.0, 1.5],
    ]
)
PHASES = np.array([0.3, 1.1, 2.0, 0.7, 2.9, 1.6])


def intrinsics(h: int, w: int) -> np.ndarray:
    f = 0.85 * w
    return np.array([[f, 0.0, (w - 1) / 2 + 0.3], [0.0, f * 1.02, (h - 1) / 2 - 0.2], [0.0, 0.0, 1.0]])


def rotation(aa: np.ndarray) -> np.ndarray:
    theta = np.linalg.norm(aa)
    if theta < 1e-12:
        return np.eye(3)
    k = aa / theta
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(theta) * kx + (1 - np.cos(theta)) * kx @ kx


def texture(X: np.ndarray) -> np.ndarray:
    """RGB in [0, 1] of points X (..., 3) in the target frame: smooth sums of sinusoids."""
    phase = X @ FREQS.T + PHASES  # (..., 6)
    s = np.sin(phase)
    rgb = np.stack(
        (
            s[..., 0] + 0.6 * s[..., 2] + 0.4 * s[..., 4],
            s[..., 1] + 0.5 * s[..., 3] + 0.3 * s[..., 5],
            s[..., 0] * 0.5 + s[..., 3] * 0.7 + 0.4 * s[..., 5],
        ),
        axis=-1,
    )
    return 0.5 + 0.22 * rgb


@dataclass
class PlaneScene:
    """Target and source views of the plane (numpy, float64)."""

    K: np.ndarray  # (3,3)
    src_T_tgt: np.ndarray  # (4,4)
    depth_t: np.ndarray  # (H,W) target z-depth
    depth_s: np.ndarray  # (H,W) source z-depth
    img_t: np.ndarray  # (H,W,3)
    img_s: np.ndarray  # (H,W,3)
    flow: np.ndarray  # (H,W,2) target → source, from ray tracing

    def torch(self, dtype=torch.float64) -> dict[str, torch.Tensor]:
        """Batched tensors: K (1,3,3), T (1,4,4), depth_t/depth_s (1,1,H,W), img_t/img_s (1,3,H,W), flow."""

        def t(a):
            return torch.from_numpy(np.ascontiguousarray(a)).to(dtype)

        return {
            "K": t(self.K)[None],
            "T": t(self.src_T_tgt)[None],
            "depth_t": t(self.depth_t)[None, None],
            "depth_s": t(self.depth_s)[None, None],
            "img_t": t(self.img_t).permute(2, 0, 1)[None],
            "img_s": t(self.img_s).permute(2, 0, 1)[None],
            "flow": t(self.flow).permute(2, 0, 1)[None],
        }


def _rays(K: np.ndarray, h: int, w: int) -> np.ndarray:
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    pix = np.stack((u, v, np.ones_like(u)), axis=-1)
    return pix @ np.linalg.inv(K).T  # (H,W,3), z = 1


def plane_scene(h: int = 64, w: int = 96, aa=(0.01, -0.03, 0.015), t=(0.2, -0.05, 0.08)) -> PlaneScene:
    K = intrinsics(h, w)
    R = rotation(np.asarray(aa, dtype=np.float64))
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    tgt_T_src = np.linalg.inv(T)
    rays = _rays(K, h, w)
    # Target: z = 1 / (nᵀ ray) since rays have z = 1.
    depth_t = 1.0 / (rays @ PLANE_N)
    X_t = rays * depth_t[..., None]
    img_t = texture(X_t)
    # Source view: ray λ·r in the source frame → target frame R'λr + t'; intersect the plane.
    Rp, tp = tgt_T_src[:3, :3], tgt_T_src[:3, 3]
    lam = (1.0 - PLANE_N @ tp) / ((rays @ Rp.T) @ PLANE_N)
    depth_s = lam
    X_s_in_t = (rays * lam[..., None]) @ Rp.T + tp
    img_s = texture(X_s_in_t)
    # Ground-truth flow: target points into the source camera.
    X_s = X_t @ R.T + T[:3, 3]
    proj = X_s @ K.T
    grid = np.stack(np.meshgrid(np.arange(w), np.arange(h)), axis=-1).astype(np.float64)
    flow = proj[..., :2] / proj[..., 2:3] - grid
    return PlaneScene(K, T, depth_t, depth_s, img_t, img_s, flow)
