"""Incremental structure from motion over the corner tracks of one video with known intrinsics.

1. Initial pair: frame 0 and the later frame (every 5th tried) whose essential matrix (MAGSAC) leaves the
   most inlier tracks with at least ``init_angle_deg`` of parallax; relative pose from the essential
   matrix with the cheirality test, inlier tracks triangulated.
2. Every other frame in time order: pose from the triangulated points it sees (PnP in a RANSAC loop,
   refined by Levenberg–Marquardt), then its new tracks are triangulated (two views: the first and last
   registered observation; kept with at least ``min_angle_deg`` of parallax, in front of every camera and
   within 2 × ``pnp_threshold_px`` of every registered observation). A bundle adjustment of everything so
   far runs after every ``ba_every`` new frames.
3. A global bundle adjustment; observations off by more than ``outlier_px`` are dropped; it runs again.

A frame that cannot be registered (fewer than ``min_points`` points, PnP failure) stays unregistered;
a video without an initial pair (a textureless scene) has no registered frame at all.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.ndimage import distance_transform_edt

from f2depth.poses.bundle import bundle_adjust
from f2depth.poses.tracks import Tracks


@dataclass(frozen=True)
class ReconstructConfig:
    min_points: int = 10  # tracks an initial pair / points a PnP needs
    init_angle_deg: float = 1.0  # parallax that counts a track for the initial pair
    min_angle_deg: float = 0.5  # parallax a triangulated point needs
    essential_threshold_px: float = 0.5
    pnp_threshold_px: float = 1.5
    huber_px: float = 1.0
    outlier_px: float = 1.0
    ba_every: int = 10
    ba_iterations: int = 30


@dataclass(frozen=True)
class Reconstruction:
    """cam_T_world (N,4,4) float64 (NaN where not registered), registered (N,) bool, points (T,3) per track
    (NaN where none), inlier (M,) bool per observation of ``tracks``; the gauge is frame-0-centred with an
    arbitrary scale until ``normalised``."""

    cam_T_world: np.ndarray
    registered: np.ndarray
    points: np.ndarray
    inlier: np.ndarray
    tracks: Tracks

    def observation_depths(self) -> np.ndarray:
        """z of every inlier observation of a point in its registered camera (M',)."""
        m = self.inlier
        T = self.cam_T_world[self.tracks.frame[m]]
        X = self.points[self.tracks.track[m]]
        return np.einsum("mij,mj->mi", T[:, :3, :3], X)[:, 2] + T[:, 2, 3]

    def shared_points(self) -> np.ndarray:
        """(N, N) int: points seen (inlier) by both frames i and j."""
        n = self.tracks.n_frames
        m = self.inlier
        vis = np.zeros((n, self.tracks.n_tracks), np.int64)
        vis[self.tracks.frame[m], self.tracks.track[m]] = 1
        return vis @ vis.T

    def image_median_depth(self, hw: tuple[int, int], cell: int = 8) -> float | None:
        """The median depth of the images as the points sample them: on a grid of ``cell`` px, every grid
        cell of a registered frame takes the depth of the nearest point observed in that frame, and the
        median runs over all cells of all frames (None without points). Corners crowd on furniture and
        leave walls empty; weighting each point by the image area it is nearest to counts a wall by its
        area, as the depth network sees it (on the synthetic default this halves the spread of the scene
        scales against the median depth of the true depth maps)."""
        m = self.inlier
        if not m.any():
            return None
        depths, frames = self.observation_depths(), self.tracks.frame[m]
        gh, gw = -(-hw[0] // cell), -(-hw[1] // cell)
        cells = np.clip((self.tracks.uv[m] / cell).astype(int), 0, [gw - 1, gh - 1])
        values, weights = [], []
        for f in np.unique(frames):
            sel = np.flatnonzero(frames == f)
            label = np.full((gh, gw), -1)
            label[cells[sel, 1], cells[sel, 0]] = np.arange(len(sel))
            _, (iy, ix) = distance_transform_edt(label < 0, return_indices=True)
            area = np.bincount(label[iy, ix].ravel(), minlength=len(sel))
            values.append(depths[sel])
            weights.append(area)
        v, w = np.concatenate(values), np.concatenate(weights).astype(np.float64)
        order = np.argsort(v)
        cum = np.cumsum(w[order])
        return float(v[order][np.searchsorted(cum, 0.5 * cum[-1])])

    def normalised(self, median_depth: float, hw: tuple[int, int]) -> Reconstruction:
        """The same reconstruction scaled so that ``image_median_depth(hw)`` is ``median_depth``."""
        current = self.image_median_depth(hw)
        if current is None:
            return self
        s = median_depth / current
        T = self.cam_T_world.copy()
        T[:, :3, 3] *= s
        return Reconstruction(T, self.registered, self.points * s, self.inlier, self.tracks)


def _rays(K_inv: np.ndarray, uv: np.ndarray) -> np.ndarray:
    return np.c_[uv, np.ones(len(uv))] @ K_inv.T


def _angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    cos = (a * b).sum(-1) / np.linalg.norm(a, axis=-1) / np.linalg.norm(b, axis=-1)
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def pose_from_essential(E: np.ndarray, x1: np.ndarray, x2: np.ndarray, K: np.ndarray,
                        inlier: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The decomposition of E (``x2 ~ R·x1 + t``, |t| = 1) that puts the most inliers in front of both
    cameras → (R (3,3), t (3,), in_front (N,) bool)."""
    K_inv = np.linalg.inv(K)
    r1, r2 = _rays(K_inv, x1), _rays(K_inv, x2)
    R1, R2, t = cv2.decomposeEssentialMat(E)
    best = (-1, np.eye(3), np.zeros(3), np.zeros(len(x1), bool))
    for R in (R1, R2):
        for tt in (t[:, 0], -t[:, 0]):
            A = np.stack([r1 @ R.T, -r2], axis=2)  # z1·R·r1 − z2·r2 = −t
            AtA = np.einsum("nki,nkj->nij", A, A) + 1e-12 * np.eye(2)
            z = np.linalg.solve(AtA, np.einsum("nki,k->ni", A, -tt)[..., None])[..., 0]
            front = (z[:, 0] > 0) & (z[:, 1] > 0) & inlier
            if front.sum() > best[0]:
                best = (int(front.sum()), R, tt, front)
    return best[1], best[2], best[3]


def triangulate_two_view(P1: np.ndarray, P2: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> np.ndarray:
    """Linear (DLT) triangulation: projection matrices P1, P2 (N,3,4), pixels x1, x2 (N,2) → X (N,3)."""
    A = np.stack([x1[:, :1] * P1[:, 2] - P1[:, 0], x1[:, 1:] * P1[:, 2] - P1[:, 1],
                  x2[:, :1] * P2[:, 2] - P2[:, 0], x2[:, 1:] * P2[:, 2] - P2[:, 1]], axis=1)
    Xh = np.linalg.svd(A)[2][:, -1]
    return Xh[:, :3] / Xh[:, 3:4]


class _Builder:
    """The mutable state of one incremental reconstruction."""

    def __init__(self, tracks: Tracks, K: np.ndarray, cfg: ReconstructConfig) -> None:
        self.tr, self.K, self.cfg = tracks, K, cfg
        self.K_inv = np.linalg.inv(K)
        n, t = tracks.n_frames, tracks.n_tracks
        self.T = np.full((n, 4, 4), np.nan)
        self.reg = np.zeros(n, bool)
        self.X = np.full((t, 3), np.nan)
        self.inlier = np.ones(len(tracks.track), bool)
        starts = np.searchsorted(tracks.track, np.arange(t + 1))
        self.start, self.end = starts[:-1], starts[1:]

    def has_point(self) -> np.ndarray:
        return ~np.isnan(self.X[:, 0])

    def set_pose(self, f: int, R: np.ndarray, t: np.ndarray) -> None:
        self.T[f] = np.eye(4)
        self.T[f, :3, :3], self.T[f, :3, 3] = R, t
        self.reg[f] = True

    def triangulate(self, candidates: np.ndarray) -> None:
        """Points for the ``candidates`` (track ids) without one (module docstring, step 2)."""
        tr, cfg = self.tr, self.cfg
        cand = np.zeros(tr.n_tracks, bool)
        cand[candidates] = True
        cand &= ~self.has_point()
        obs = np.flatnonzero(cand[tr.track] & self.reg[tr.frame] & self.inlier)
        if not len(obs):
            return
        tid = tr.track[obs]
        first = obs[np.r_[True, tid[1:] != tid[:-1]]]
        last = obs[np.r_[tid[1:] != tid[:-1], True]]
        two = first != last
        first, last = first[two], last[two]
        if not len(first):
            return
        f1, f2 = tr.frame[first], tr.frame[last]
        P = self.K @ self.T[:, :3, :]
        X = triangulate_two_view(P[f1], P[f2], tr.uv[first], tr.uv[last])
        R1, R2 = self.T[f1, :3, :3], self.T[f2, :3, :3]
        ray1 = np.einsum("nji,nj->ni", R1, _rays(self.K_inv, tr.uv[first]))
        ray2 = np.einsum("nji,nj->ni", R2, _rays(self.K_inv, tr.uv[last]))
        good = (_angle_deg(ray1, ray2) >= cfg.min_angle_deg) & np.all(np.isfinite(X), axis=1)
        ids = tr.track[first]
        Xall = np.full((tr.n_tracks, 3), np.nan)
        Xall[ids[good]] = X[good]
        check = obs[~np.isnan(Xall[tr.track[obs], 0])]
        T = self.T[tr.frame[check]]
        Xc = np.einsum("mij,mj->mi", T[:, :3, :3], Xall[tr.track[check]]) + T[:, :3, 3]
        z = np.where(Xc[:, 2:] > 0, Xc[:, 2:], np.nan)  # behind a camera: NaN, never within the threshold
        uv = Xc[:, :2] / z * [self.K[0, 0], self.K[1, 1]] + self.K[:2, 2]
        err = np.linalg.norm(uv - tr.uv[check], axis=1)
        bad_tracks = np.unique(tr.track[check][~(err <= 2 * cfg.pnp_threshold_px)])
        Xall[bad_tracks] = np.nan
        keep = ~np.isnan(Xall[:, 0])
        self.X[keep] = Xall[keep]

    def initialise(self, b: int) -> bool:
        cfg = self.cfg
        common, x1, x2 = self.matches(0, b)
        if len(common) < cfg.min_points:
            return False
        E, mask = cv2.findEssentialMat(x1, x2, self.K, method=cv2.USAC_MAGSAC, prob=0.9999,
                                       threshold=cfg.essential_threshold_px)
        if E is None or E.shape != (3, 3):
            return False
        R, t, front = pose_from_essential(E, x1, x2, self.K, mask[:, 0] > 0)
        if front.sum() < cfg.min_points:
            return False
        self.set_pose(0, np.eye(3), np.zeros(3))
        self.set_pose(b, R, t)
        self.triangulate(common[front])
        return int(self.has_point().sum()) >= cfg.min_points

    def matches(self, a: int, b: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        tr = self.tr
        ia, ib = np.flatnonzero(tr.frame == a), np.flatnonzero(tr.frame == b)
        common, ka, kb = np.intersect1d(tr.track[ia], tr.track[ib], return_indices=True)
        return common, tr.uv[ia[ka]], tr.uv[ib[kb]]

    def register(self, f: int) -> bool:
        tr, cfg = self.tr, self.cfg
        obs = np.flatnonzero((tr.frame == f) & self.has_point()[tr.track])
        if len(obs) < cfg.min_points:
            return False
        X, x = self.X[tr.track[obs]], tr.uv[obs]
        near = np.flatnonzero(self.reg)[np.argmin(np.abs(np.flatnonzero(self.reg) - f))]
        rv0 = cv2.Rodrigues(self.T[near, :3, :3])[0]
        tv0 = self.T[near, :3, 3].reshape(3, 1).copy()
        ok, rv, tv, inl = cv2.solvePnPRansac(X, x, self.K, None, rv0, tv0, useExtrinsicGuess=True,
                                             reprojectionError=cfg.pnp_threshold_px, iterationsCount=200,
                                             flags=cv2.SOLVEPNP_ITERATIVE)
        if not ok or inl is None or len(inl) < cfg.min_points:
            return False
        inl = inl[:, 0]
        rv, tv = cv2.solvePnPRefineLM(X[inl], x[inl], self.K, None, rv, tv)
        self.set_pose(f, cv2.Rodrigues(rv)[0], tv[:, 0])
        self.triangulate(np.unique(tr.track[tr.frame == f]))
        return True

    def adjust(self, iterations: int, outlier_px: float | None = None) -> None:
        tr, cfg = self.tr, self.cfg
        obs = np.flatnonzero(self.reg[tr.frame] & self.has_point()[tr.track] & self.inlier)
        frames, cam = np.unique(tr.frame[obs], return_inverse=True)
        tracks, point = np.unique(tr.track[obs], return_inverse=True)
        # frame 0 (the initial pair's first frame, frames[0]) fixes the gauge
        res = bundle_adjust(self.K, self.T[frames, :3, :3], self.T[frames, :3, 3], self.X[tracks], cam, point,
                            tr.uv[obs], fixed=(0,), huber_px=cfg.huber_px, iterations=iterations)
        self.T[frames, :3, :3], self.T[frames, :3, 3] = res.R, res.t
        self.X[tracks] = res.X
        if outlier_px is not None:
            self.inlier[obs[np.linalg.norm(res.residuals, axis=1) > outlier_px]] = False
            seen = np.bincount(tr.track[self.inlier & self.reg[tr.frame]], minlength=tr.n_tracks)
            self.X[seen < 2] = np.nan

    def result(self) -> Reconstruction:
        inlier = self.inlier & self.reg[self.tr.frame] & self.has_point()[self.tr.track]
        return Reconstruction(self.T.copy(), self.reg.copy(), self.X.copy(), inlier, self.tr)


def choose_initial_pair(tracks: Tracks, K: np.ndarray, cfg: ReconstructConfig, step: int = 5) -> int | None:
    """The partner b of frame 0 (module docstring, step 1), or None."""
    builder = _Builder(tracks, K, cfg)
    best, best_b = 0, None
    for b in range(step, tracks.n_frames, step):
        common, x1, x2 = builder.matches(0, b)
        if len(common) < max(cfg.min_points, 8):
            continue
        E, mask = cv2.findEssentialMat(x1, x2, K, method=cv2.USAC_MAGSAC, prob=0.9999,
                                       threshold=cfg.essential_threshold_px)
        if E is None or E.shape != (3, 3):
            continue
        R, _, front = pose_from_essential(E, x1, x2, K, mask[:, 0] > 0)
        K_inv = np.linalg.inv(K)
        parallax = _angle_deg(_rays(K_inv, x1), _rays(K_inv, x2) @ R)
        score = int(((parallax >= cfg.init_angle_deg) & front).sum())
        if score > best:
            best, best_b = score, b
    return best_b if best >= cfg.min_points else None


def reconstruct(tracks: Tracks, K: np.ndarray, cfg: ReconstructConfig) -> Reconstruction:
    """Camera poses of every frame of ``tracks`` that can be registered (module docstring)."""
    builder = _Builder(tracks, K, cfg)
    b = choose_initial_pair(tracks, K, cfg) if tracks.n_tracks else None
    if b is None or not builder.initialise(b):
        return _Builder(tracks, K, cfg).result()
    builder.adjust(cfg.ba_iterations)
    added = 0
    for f in [*range(1, b), *range(b + 1, tracks.n_frames)]:
        added += builder.register(f)
        if added >= cfg.ba_every:
            builder.adjust(10)
            added = 0
    builder.adjust(cfg.ba_iterations, outlier_px=cfg.outlier_px)
    builder.adjust(cfg.ba_iterations)
    return builder.result()
