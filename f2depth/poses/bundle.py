"""Bundle adjustment: Levenberg–Marquardt over camera poses and 3-D points with the Schur complement.

Pinhole cameras with known intrinsics ``K`` (3, 3); camera ``c`` maps world points into its frame with
``X_c = R_c · X + t_c`` (``cam_T_world``, the inverse of the ``world_T_cam`` poses used elsewhere). The cost
is the Huber-robust sum of squared reprojection errors (pixels); the Huber weights are re-computed every
iteration (iteratively re-weighted least squares). A pose update is ``R ← exp([δω]×)·R``, ``t ← exp([δω]×)·t
+ δt``. The camera block of the normal equations is solved densely after eliminating the points
(Triggs et al., "Bundle adjustment — a modern synthesis", §6.1); a few hundred points and fifty cameras
take milliseconds per iteration. The gauge: the cameras in ``fixed`` do not move; the global scale is
left free (Marquardt's damping keeps the system regular) and is set by the caller afterwards.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def so3_exp(w: np.ndarray) -> np.ndarray:
    """Rodrigues: rotation vectors (..., 3) (radians) → rotation matrices (..., 3, 3)."""
    theta = np.linalg.norm(w, axis=-1)[..., None, None]
    k = w / np.maximum(np.linalg.norm(w, axis=-1, keepdims=True), 1e-300)
    S = skew(k)
    return np.eye(3) + np.sin(theta) * S + (1.0 - np.cos(theta)) * (S @ S)


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrices of vectors (..., 3) → (..., 3, 3)."""
    S = np.zeros(v.shape[:-1] + (3, 3))
    S[..., 0, 1], S[..., 0, 2] = -v[..., 2], v[..., 1]
    S[..., 1, 0], S[..., 1, 2] = v[..., 2], -v[..., 0]
    S[..., 2, 0], S[..., 2, 1] = -v[..., 1], v[..., 0]
    return S


def segment_sum(index: np.ndarray, values: np.ndarray, n: int) -> np.ndarray:
    """Sum ``values`` (M, ...) into ``n`` bins by ``index`` (M,) → (n, ...) (one bincount, no Python loop)."""
    shape = values.shape[1:]
    d = int(np.prod(shape)) if shape else 1
    flat = (index[:, None] * d + np.arange(d)).ravel()
    return np.bincount(flat, weights=values.reshape(-1), minlength=n * d).reshape((n,) + shape)


def project(K: np.ndarray, R: np.ndarray, t: np.ndarray, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Points X (M,3) seen by cameras R (M,3,3), t (M,3) → (pixels (M,2), camera-frame points (M,3))."""
    Xc = np.einsum("mij,mj->mi", R, X) + t
    z = Xc[:, 2]
    uv = np.stack([K[0, 0] * Xc[:, 0] / z + K[0, 2], K[1, 1] * Xc[:, 1] / z + K[1, 2]], axis=1)
    return uv, Xc


def huber_cost(r: np.ndarray, delta: float) -> float:
    n = np.linalg.norm(r, axis=1)
    return float(np.where(n <= delta, 0.5 * n * n, delta * (n - 0.5 * delta)).sum())


@dataclass(frozen=True)
class BundleResult:
    """R (C,3,3), t (C,3) ``cam_T_world``; X (P,3); residuals (M,2) pixels; iterations run."""

    R: np.ndarray
    t: np.ndarray
    X: np.ndarray
    residuals: np.ndarray
    iterations: int


def bundle_adjust(K: np.ndarray, R: np.ndarray, t: np.ndarray, X: np.ndarray, cam: np.ndarray,
                  point: np.ndarray, uv: np.ndarray, fixed: tuple[int, ...] = (0,), huber_px: float = 1.0,
                  iterations: int = 30, tolerance: float = 1e-9) -> BundleResult:
    """Minimise the Huber reprojection cost of observations ``uv`` (M,2) of points ``point`` (M,) by cameras
    ``cam`` (M,) over the free cameras and all points. Every point must lie in front of its cameras at the
    start; steps that would put one behind a camera are rejected like steps that raise the cost."""
    R, t, X = R.astype(np.float64).copy(), t.astype(np.float64).copy(), X.astype(np.float64).copy()
    C, P = len(R), len(X)
    free = np.ones(C, bool)
    free[list(fixed)] = False
    slot = np.full(C, -1)
    slot[free] = np.arange(int(free.sum()))
    nc = int(free.sum())
    fx, fy = K[0, 0], K[1, 1]
    proj, Xc = project(K, R[cam], t[cam], X[point])
    r = proj - uv
    cost = huber_cost(r, huber_px)
    lam = 1e-3
    it = 0
    on_free = free[cam]
    for it in range(1, iterations + 1):
        norm = np.linalg.norm(r, axis=1)
        w = np.where(norm <= huber_px, 1.0, huber_px / np.maximum(norm, 1e-12))
        z = Xc[:, 2]
        Jp = np.zeros((len(cam), 2, 3))  # d pixel / d camera-frame point
        Jp[:, 0, 0], Jp[:, 0, 2] = fx / z, -fx * Xc[:, 0] / z**2
        Jp[:, 1, 1], Jp[:, 1, 2] = fy / z, -fy * Xc[:, 1] / z**2
        Jc = np.concatenate([Jp @ -skew(Xc), Jp], axis=2)  # (M,2,6): δω, δt
        Jx = Jp @ R[cam]  # (M,2,3)
        Jcw, Jxw = Jc * w[:, None, None], Jx * w[:, None, None]
        U = segment_sum(cam, Jcw.transpose(0, 2, 1) @ Jc, C)
        V = segment_sum(point, Jxw.transpose(0, 2, 1) @ Jx, P)
        Wm = Jcw.transpose(0, 2, 1) @ Jx  # (M,6,3)
        gc = segment_sum(cam, np.einsum("mki,mk->mi", Jcw, r), C)
        gx = segment_sum(point, np.einsum("mki,mk->mi", Jxw, r), P)
        Wd = np.zeros((nc, P, 6, 3))
        Wd[slot[cam[on_free]], point[on_free]] = Wm[on_free]  # one observation per (camera, point)
        while True:
            Vd = V + lam * np.einsum("pii->pi", V)[:, :, None] * np.eye(3) + 1e-9 * np.eye(3)
            Vinv = np.linalg.inv(Vd)
            Ud = U[free] + lam * np.einsum("cii->ci", U[free])[:, :, None] * np.eye(6) + 1e-12 * np.eye(6)
            WV = np.einsum("cpij,pjk->cpik", Wd, Vinv).transpose(0, 2, 1, 3).reshape(6 * nc, 3 * P)
            Wf = Wd.transpose(0, 2, 1, 3).reshape(6 * nc, 3 * P)
            S = -(WV @ Wf.T)
            for k in range(nc):
                S[6 * k:6 * k + 6, 6 * k:6 * k + 6] += Ud[k]
            b = -gc[free].ravel() + WV @ gx.ravel()
            dcam = np.zeros((C, 6))
            dcam[free] = np.linalg.solve(S, b).reshape(nc, 6)
            wtdc = segment_sum(point, np.einsum("mij,mi->mj", Wm, dcam[cam]), P)
            dx = np.einsum("pij,pj->pi", Vinv, -gx - wtdc)
            dR = so3_exp(dcam[:, :3])
            Rn, tn, Xn = dR @ R, np.einsum("cij,cj->ci", dR, t) + dcam[:, 3:], X + dx
            proj_n, Xc_n = project(K, Rn[cam], tn[cam], Xn[point])
            rn = proj_n - uv
            cost_n = huber_cost(rn, huber_px) if np.all(Xc_n[:, 2] > 0) else np.inf
            if cost_n < cost:
                gain = (cost - cost_n) / max(cost, 1e-300)
                R, t, X, r, Xc, cost = Rn, tn, Xn, rn, Xc_n, cost_n
                lam = max(lam / 3.0, 1e-9)
                break
            lam *= 4.0
            if lam > 1e8:
                return BundleResult(R, t, X, r, it)
        if gain < tolerance:
            break
    return BundleResult(R, t, X, r, it)
