"""The focal length of a video from the video itself, when no camera file, ``--fov`` or EXIF gives it.

Mendonça & Cipolla's self-calibration (CVPR 1999, "A simple technique for self-calibration"): for the right
intrinsics K, the essential matrix ``E = Kᵀ F K`` of every frame pair has two equal singular values. With
square pixels and the principal point at the image centre (what a phone's video nearly always has; the
camera file is the way to give anything else) only the focal length f is unknown, and it is the f that
minimises ``Σ (σ₁ − σ₂) / σ₂`` over the pairs (the worst ``TRIM`` share of pairs left out).

* **Pairs**: every frame ``k`` with the frames ``k − g`` for ``g`` in ``GAPS``, on a grey copy at most
  ``ANALYSIS_SIDE`` px on its long side; corners tracked as the static-camera filter tracks them
  (:func:`f2depth.ingest.select.tracked_corners`; here up to ``MAX_CORNERS``, kept where the backward track
  returns within ``FB_TOLERANCE`` px); a pair counts when the
  median track moved ``MIN_SHARE`` of the diagonal (no baseline, no geometry) and MAGSAC++
  (``cv2.USAC_MAGSAC``) finds F with ``MIN_INLIERS`` inliers. At most ``MAX_PAIRS`` pairs are used, so a
  long video costs what a short one does; frames are streamed, never held (``max(GAPS)`` grey copies).
* **Search**: f on a geometric grid over horizontal fields of view ``FOV_RANGE``, then the grid's best
  refined by a parabola through its neighbours.
* **Confidence**: the 16–84 % range of the estimate over ``BOOTSTRAP`` resamplings of the pairs, as a
  share of f (``spread``), and the median two-view reprojection error (px at the frames' size) of the F
  inliers triangulated with that f (``cv2.recoverPose``). The spread says how much the pairs agree, not how
  far f is from the truth (distortion and the principal point are not modelled, and the bias they and the
  motion give is shared by all pairs): on rendered clips it held the truth on 3 of 24. The error bar
  printed with fx is ``ERROR_BAR``, the 90th percentile of the error measured by
  ``benchmarks/bench_selfcal_coverage.py`` (docs/ingest.md, "How accurate is self-calibration"). An
  estimate from fewer than
  ``MIN_PAIRS`` pairs, from pairs a homography explains (median share of the inliers above
  ``MAX_HOMOGRAPHY_SHARE``: a camera turning in place, which gives no F), with a spread above
  ``MAX_SPREAD``, at an end of the search range, or with a reprojection error above
  ``MAX_REPROJECTION_PX`` (or none: nothing triangulates) is refused with one line asking for ``--fov`` or
  a camera file.

Lens distortion is not estimated (a wide lens biases f; measured on the embedded NYU-lens clips:
docs/ingest.md), which is why a camera file, ``--fov`` and EXIF all come first.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from f2depth.camera import RawCamera, intrinsics
from f2depth.errors import DataError
from f2depth.ingest.select import analysis_grey, corners, tracked_corners

ANALYSIS_SIDE = 640
GAPS = (2, 4, 6)
MIN_SHARE = 0.015
MIN_INLIERS = 30
MIN_PAIRS = 12
MAX_PAIRS = 300
MAX_CORNERS = 800
FB_TOLERANCE = 0.5
RANSAC_PX = 0.5
TRIM = 0.2
FOV_RANGE = (20.0, 120.0)
GRID = 300
BOOTSTRAP = 100
MAX_SPREAD = 0.08
#: A clip whose pairs a homography explains this well (the median share of their F inliers within
#: RANSAC_PX of one) has no parallax: the camera turned in place (or saw one plane), and F is undefined.
#: Rendered clips: walking 0.54–0.85, turning in place 0.92–1.0.
MAX_HOMOGRAPHY_SHARE = 0.9
#: The most median two-view reprojection error (px at the analysis size) an estimate may have.
MAX_REPROJECTION_PX = 2.0
#: The error bar of an estimate that is not refused, as a share of fx: the 90th percentile of |fx / true − 1|
#: (18.0 %, rounded up) over the ERROR_BAR_CLIPS rendered clips (known fx, lens distortion, principal point
#: and motion) that benchmarks/bench_selfcal_coverage.py self-calibrated without a refusal (seeds 0 and 1;
#: 22 of the 24 within it; docs/ingest.md, "How accurate is self-calibration").
ERROR_BAR = 0.20
ERROR_BAR_CLIPS = 24
ERROR_BAR_WITHIN = 22
ERROR_BAR_RULE = (f"90th percentile of |relative error| on {ERROR_BAR_CLIPS} rendered clips "
                  "(benchmarks/bench_selfcal_coverage.py, docs/ingest.md)")


@dataclass(frozen=True)
class PairGeometry:
    """One frame pair at the analysis size: F (3,3) and its inlier tracks ``a``, ``b`` (n,2) px, x first."""

    F: np.ndarray
    a: np.ndarray
    b: np.ndarray
    homography_share: float = 0.0  # the share of the inliers a homography explains (no parallax: ~1)


@dataclass(frozen=True)
class FocalEstimate:
    """The self-calibrated focal length ``fx`` (px at the frames' size ``hw``) and how sure it is."""

    fx: float
    hw: tuple[int, int]
    pairs: int
    spread: float             # 16–84 % bootstrap range ÷ fx (how much the pairs agree, not the error)
    reprojection_px: float    # median two-view reprojection error of the inliers at the frames' size
    fov_deg: float

    @property
    def error_bar(self) -> float:
        """The error bar printed with fx, a share of fx: ``ERROR_BAR``, measured (module docstring)."""
        return ERROR_BAR

    def camera(self) -> RawCamera:
        h, w = self.hw
        source = (f"self-calibrated from the video (Mendonça–Cipolla, {self.pairs} pairs): fx {self.fx:.1f} "
                  f"px (horizontal FOV {self.fov_deg:.1f}°), typical error ±{100 * self.error_bar:.0f} % "
                  f"(measured: {ERROR_BAR_WITHIN} of {ERROR_BAR_CLIPS} rendered clips within it, "
                  f"docs/ingest.md; the pairs agree to ±{100 * self.spread / 2:.1f} %, which is not the "
                  f"error), reprojection {self.reprojection_px:.2f} px")
        return RawCamera(intrinsics(h, w, fx=self.fx), np.zeros(5), (h, w), source)

    def to_json(self) -> dict:
        return {"fx": self.fx, "error_bar": self.error_bar, "error_bar_rule": ERROR_BAR_RULE,
                "pairs": self.pairs, "spread": self.spread, "reprojection_px": self.reprojection_px,
                "fov_deg": self.fov_deg}


def frame_corners(grey: np.ndarray) -> np.ndarray | None:
    """The corners of a frame that later frames are tracked from (each frame's found once)."""
    return corners(grey, MAX_CORNERS, min_distance=8)


def pair_geometry(ref: np.ndarray, cur: np.ndarray, ref_corners: np.ndarray | None = None
                  ) -> PairGeometry | None:
    """F between grey frames ``ref`` (with its :func:`frame_corners`, found when not given) and ``cur``
    (module docstring), or None without enough motion/tracks."""
    pts = frame_corners(ref) if ref_corners is None else ref_corners
    if pts is None:
        return None
    tracks = tracked_corners(ref, cur, pts, fb_tolerance=FB_TOLERANCE, min_tracks=MIN_INLIERS)
    if tracks is None:
        return None
    a, b = tracks
    if np.median(np.linalg.norm(b - a, axis=1)) < MIN_SHARE * math.hypot(*ref.shape):
        return None
    try:
        F, mask = cv2.findFundamentalMat(a, b, cv2.USAC_MAGSAC, RANSAC_PX, 0.999)
    except cv2.error:  # OpenCV 5's MAGSAC++ asserts on some degenerate track sets (rendered clips)
        return None
    if F is None or F.shape != (3, 3) or mask is None:
        return None
    inl = mask.ravel() == 1
    if inl.sum() < MIN_INLIERS:
        return None
    try:
        H, h_mask = cv2.findHomography(a[inl], b[inl], cv2.USAC_MAGSAC, RANSAC_PX, confidence=0.999)
    except cv2.error:
        H = h_mask = None
    share = 0.0 if H is None or h_mask is None else float(h_mask.mean())
    return PairGeometry(F, a[inl], b[inl], share)


def collect_pairs(scenes: Iterable[Iterable[np.ndarray]]
                  ) -> tuple[list[PairGeometry], tuple[int, int], float]:
    """The pairs of every scene's RGB frames (streamed) → (pairs, frame size (h, w), analysis scale)."""
    pairs: list[PairGeometry] = []
    hw, scale = (0, 0), 1.0
    for frames in scenes:
        window: deque[tuple[np.ndarray, np.ndarray | None]] = deque(maxlen=max(GAPS))  # (grey, corners)
        for rgb in frames:
            hw = tuple(rgb.shape[:2])
            grey = analysis_grey(rgb, ANALYSIS_SIDE)
            scale = min(1.0, ANALYSIS_SIDE / max(hw))
            for gap in GAPS:
                if len(window) >= gap and len(pairs) < MAX_PAIRS:
                    ref, ref_corners = window[-gap]
                    found = pair_geometry(ref, grey, ref_corners)
                    if found is not None:
                        pairs.append(found)
            window.append((grey, frame_corners(grey)))
            if len(pairs) >= MAX_PAIRS:
                return pairs, hw, scale
    return pairs, hw, scale


def focal_costs(focals: np.ndarray, Fs: np.ndarray, hw: tuple[int, int], trim: float = TRIM) -> np.ndarray:
    """Mendonça–Cipolla's cost of each focal length ``focals`` (m,) px for fundamental matrices ``Fs``
    (n,3,3) at size ``hw``: the mean of ``(σ₁ − σ₂)/σ₂`` of ``Kᵀ F K`` over the best ``1 − trim`` of the
    pairs → (m,)."""
    h, w = hw
    K = np.zeros((len(focals), 3, 3))
    K[:, 0, 0] = K[:, 1, 1] = focals
    K[:, 0, 2], K[:, 1, 2], K[:, 2, 2] = (w - 1) / 2, (h - 1) / 2, 1.0
    E = np.einsum("mji,njk,mkl->mnil", K, Fs, K)
    s = np.linalg.svd(E, compute_uv=False)                               # (m,n,3), descending
    c = np.sort((s[..., 0] - s[..., 1]) / np.maximum(s[..., 1], 1e-12), axis=1)
    keep = max(int(round(c.shape[1] * (1 - trim))), 1)
    return c[:, :keep].mean(axis=1)


def best_focal(grid: np.ndarray, Fs: np.ndarray, hw: tuple[int, int]) -> tuple[float, int]:
    """The minimum of :func:`focal_costs` over ``grid`` refined by a parabola in log f → (f, grid index)."""
    c = focal_costs(grid, Fs, hw)
    i = int(np.argmin(c))
    if 0 < i < len(grid) - 1:
        x = np.log(grid[i - 1:i + 2])
        denom = c[i - 1] - 2 * c[i] + c[i + 1]
        if denom > 0:
            step = 0.5 * (c[i - 1] - c[i + 1]) / denom
            return float(np.exp(x[1] + step * (x[2] - x[1]))), i
    return float(grid[i]), i


def reprojection_error(pairs: list[PairGeometry], f: float, hw: tuple[int, int]) -> float:
    """Median reprojection error (px at ``hw``, the analysis size) of the pairs' inliers triangulated from
    ``E = Kᵀ F K`` with focal length ``f``."""
    h, w = hw
    K = intrinsics(h, w, fx=f)
    errors = []
    for p in pairs:
        _, R, t, mask = cv2.recoverPose(K.T @ p.F @ K, p.a, p.b, K)
        inl = mask.ravel() > 0
        if inl.sum() < 8:
            continue
        P1, P2 = K @ np.eye(3, 4), K @ np.hstack([R, t])
        X = cv2.triangulatePoints(P1, P2, p.a[inl].T.astype(np.float64), p.b[inl].T.astype(np.float64))
        for P, x in ((P1, p.a[inl]), (P2, p.b[inl])):
            proj = P @ X
            errors.append(np.linalg.norm(proj[:2] / proj[2] - x.T, axis=0))
    return float(np.median(np.concatenate(errors))) if errors else math.inf


def estimate_focal(scenes: Iterable[Iterable[np.ndarray]], where: str | Path,
                   seed: int = 0) -> FocalEstimate:
    """Self-calibrate the focal length from the scenes' RGB frames (module docstring); ``where`` names the
    input in the one-line DataError of a refused estimate."""
    pairs, hw, scale = collect_pairs(scenes)
    fix = "give --fov DEG (a phone's main camera: about 65–75) or --camera FILE (docs/ingest.md)"
    if len(pairs) < MIN_PAIRS:
        raise DataError(Path(where), f"unknown intrinsics and self-calibration failed: {len(pairs)} frame "
                        f"pairs with enough motion and matches (at least {MIN_PAIRS} needed)", fix)
    ah = (round(hw[0] * scale), round(hw[1] * scale))
    lo, hi = (ah[1] / 2 / math.tan(math.radians(fov) / 2) for fov in (FOV_RANGE[1], FOV_RANGE[0]))
    grid = np.geomspace(lo, hi, GRID)
    Fs = np.stack([p.F for p in pairs])
    f, index = best_focal(grid, Fs, ah)
    if index in (0, GRID - 1):
        raise DataError(Path(where), f"unknown intrinsics and self-calibration failed: the best focal length "
                        f"is at the end of the {FOV_RANGE[0]:g}–{FOV_RANGE[1]:g}° range searched", fix)
    flat = float(np.median([p.homography_share for p in pairs]))
    if flat > MAX_HOMOGRAPHY_SHARE:
        raise DataError(Path(where), f"unknown intrinsics and self-calibration failed: a homography explains "
                        f"{100 * flat:.0f} % of the tracks of the median pair (at most "
                        f"{100 * MAX_HOMOGRAPHY_SHARE:.0f} %): the camera turns in place or sees one plane, "
                        "which gives no focal length", fix + "; or record walking sideways")
    rng = np.random.default_rng(seed)
    boot = [best_focal(grid, Fs[rng.integers(0, len(pairs), len(pairs))], ah)[0] for _ in range(BOOTSTRAP)]
    low, high = np.percentile(boot, [16, 84])
    spread = float((high - low) / f)
    if spread > MAX_SPREAD:
        raise DataError(Path(where), f"unknown intrinsics and self-calibration is unsure: fx {f / scale:.0f} "
                        f"px with a 16–84 % range of {100 * spread:.0f} % over {len(pairs)} pairs (at most "
                        f"{100 * MAX_SPREAD:.0f} %)", fix)
    reproj = reprojection_error(pairs, f, ah)
    if not reproj <= MAX_REPROJECTION_PX:  # inf: no pair triangulates (no baseline)
        raise DataError(Path(where), f"unknown intrinsics and self-calibration failed: fx {f / scale:.0f} px "
                        f"reprojects its pairs' tracks with a median error of {reproj:.3g} px (at most "
                        f"{MAX_REPROJECTION_PX:g} px at {ah[1]}×{ah[0]}): the frames do not fit one camera "
                        "moving through a still scene", fix)
    reproj /= scale
    fov = math.degrees(2 * math.atan(ah[1] / 2 / f))
    return FocalEstimate(f / scale, hw, len(pairs), spread, reproj, fov)
