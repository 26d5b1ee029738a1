"""Which frames of a video are worth training on: the static-camera filter and the blur filter.

* **Motion** (the rule SC-Depth, Bian et al., applies to its training videos: a frame is kept only when
  the camera moved since the last kept one): corners of the last kept frame (``cv2.goodFeaturesToTrack``)
  tracked into the candidate with pyramidal Lucas–Kanade, kept where the backward track returns within
  ``FB_TOLERANCE`` px; the median displacement of those, as a share of the image diagonal, must reach
  ``min_motion``. Too few tracks (a cut, a blank wall, a fast pan): the motion is unknown and the frame is
  kept (reported as ``untracked``), since dropping it would drop every frame of a fast stretch.
* **Blur** (optional): the variance of the Laplacian of the grey frame (Pech-Pacheco et al., ICPR 2000)
  below ``min_sharpness`` drops the frame; 0 turns the filter off.

Both run on a grey copy at most ``ANALYSIS_SIDE`` px on its long side, so a 4K video costs what a VGA one
does; the shares do not depend on that size (the blur score does, which is why it is measured there).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

ANALYSIS_SIDE = 320   # px, long side of the grey copy the filters read
MAX_CORNERS = 300
MIN_TRACKS = 12       # fewer good tracks: motion unknown
FB_TOLERANCE = 1.0    # px at the analysis size: forward–backward track error of a good track
_LK = {"winSize": (21, 21), "maxLevel": 3,
       "criteria": (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01)}


def analysis_grey(rgb: np.ndarray, side: int = ANALYSIS_SIDE) -> np.ndarray:
    """RGB uint8 (H, W, 3) → grey uint8 at most ``side`` px on its long side (INTER_AREA)."""
    grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    scale = side / max(grey.shape)
    if scale < 1:
        size = (max(round(grey.shape[1] * scale), 1), max(round(grey.shape[0] * scale), 1))
        grey = cv2.resize(grey, size, interpolation=cv2.INTER_AREA)
    return grey


def sharpness(grey: np.ndarray) -> float:
    """Variance of the Laplacian of a grey uint8 image (higher = sharper)."""
    return float(cv2.Laplacian(grey, cv2.CV_64F).var())


def corners(grey: np.ndarray, max_corners: int = MAX_CORNERS, min_distance: int = 7) -> np.ndarray | None:
    """Shi–Tomasi corners of a grey image (``cv2.goodFeaturesToTrack``): (n,1,2) float32, or None."""
    return cv2.goodFeaturesToTrack(grey, max_corners, qualityLevel=0.01, minDistance=min_distance,
                                   blockSize=7)


def tracked_corners(ref: np.ndarray, cur: np.ndarray, pts: np.ndarray | None = None,
                    fb_tolerance: float = FB_TOLERANCE, min_tracks: int = MIN_TRACKS
                    ) -> tuple[np.ndarray, np.ndarray] | None:
    """Corners ``pts`` of grey ``ref`` (default :func:`corners` of it) tracked into grey ``cur`` (same size)
    with pyramidal Lucas–Kanade, kept where the backward track returns within ``fb_tolerance`` px → their
    positions ``(a, b)`` (n,2) px, x first, in ``ref`` and ``cur``; None with fewer than ``min_tracks``."""
    if pts is None:
        pts = corners(ref)
    if pts is None or len(pts) < min_tracks:
        return None
    fwd, st1, _ = cv2.calcOpticalFlowPyrLK(ref, cur, pts, None, **_LK)
    back, st2, _ = cv2.calcOpticalFlowPyrLK(cur, ref, fwd, None, **_LK)
    good = (st1.ravel() == 1) & (st2.ravel() == 1) & (np.linalg.norm((back - pts).reshape(-1, 2), axis=1)
                                                      < fb_tolerance)
    if good.sum() < min_tracks:
        return None
    return pts.reshape(-1, 2)[good], fwd.reshape(-1, 2)[good]


def median_motion(ref: np.ndarray, cur: np.ndarray) -> float | None:
    """Median displacement (px) of corners of grey ``ref`` tracked into grey ``cur`` (same size), over the
    tracks that pass the forward–backward check; None with fewer than ``MIN_TRACKS`` of them."""
    tracks = tracked_corners(ref, cur)
    if tracks is None:
        return None
    a, b = tracks
    return float(np.median(np.linalg.norm(b - a, axis=1)))


@dataclass
class FrameFilter:
    """Streaming decision per candidate frame: :meth:`offer` → ``"kept"``, ``"static"`` or ``"blur"``.
    The first sharp frame is always kept. ``counts`` tallies the decisions (and ``untracked`` kept ones)."""

    min_motion: float     # share of the image diagonal
    min_sharpness: float  # 0: off

    def __post_init__(self) -> None:
        self._ref: np.ndarray | None = None
        self.counts = {"kept": 0, "static": 0, "blur": 0, "untracked": 0}

    def offer(self, rgb: np.ndarray) -> str:
        grey = analysis_grey(rgb)
        if self.min_sharpness > 0 and sharpness(grey) < self.min_sharpness:
            verdict = "blur"
        elif self._ref is None or self._ref.shape != grey.shape:
            verdict = "kept"
        else:
            motion = median_motion(self._ref, grey)
            if motion is None:
                self.counts["untracked"] += 1
                verdict = "kept"
            else:
                verdict = "kept" if motion >= self.min_motion * float(np.hypot(*grey.shape)) else "static"
        if verdict == "kept":
            self._ref = grey
        self.counts[verdict] += 1
        return verdict
