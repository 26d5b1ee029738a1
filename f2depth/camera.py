"""Camera models: the NYU Depth V2 RGB calibration, lens (un)distortion, intrinsics under crop and resize, and
the intrinsics of an image from given values or the NYU camera's field of view (:func:`intrinsics`).

Pixel convention everywhere in f2depth: pixel (u, v) = (column, row) has its centre at integer
coordinates; ``cv2.resize`` maps a source coordinate x to ``(x + 0.5) * s - 0.5``.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

#: NYU Depth V2 RGB camera (toolbox ``camera_params.m``), 640×480.
NYU_RGB_K = np.array([[5.1885790117450188e02, 0.0, 3.2558244941119034e02],
                      [0.0, 5.1946961112127485e02, 2.5373616633400465e02], [0.0, 0.0, 1.0]])
#: OpenCV order (k1, k2, p1, p2, k3).
NYU_RGB_DIST = np.array([2.0796615318809061e-01, -5.8613825163911781e-01, 7.2231363135888329e-04,
                         1.0479627195765181e-03, 4.9856986684705107e-01])
NYU_SIZE_HW = (480, 640)
#: horizontal focal length per image width of the NYU Depth V2 RGB camera (the training data)
NYU_FX_PER_WIDTH = float(NYU_RGB_K[0, 0]) / NYU_SIZE_HW[1]


@dataclass(frozen=True)
class RawCamera:
    """The camera of a raw frame folder: ``K`` (3,3), ``dist`` (5,) OpenCV k1 k2 p1 p2 k3, ``hw`` (height,
    width) px of its frames, ``source`` where the intrinsics came from (printed and recorded)."""

    K: np.ndarray
    dist: np.ndarray
    hw: tuple[int, int]
    source: str

    def to_json(self) -> dict:
        return {"K": np.asarray(self.K).tolist(), "dist": np.asarray(self.dist).tolist(),
                "height": self.hw[0], "width": self.hw[1], "intrinsics_source": self.source}


#: NYU Depth V2's raw RGB frames.
NYU_RAW_CAMERA = RawCamera(NYU_RGB_K, NYU_RGB_DIST, NYU_SIZE_HW, "NYU Depth V2 RGB calibration")


def undistort_normalized(uv: np.ndarray, K: np.ndarray, dist: np.ndarray, iters: int = 50) -> np.ndarray:
    """Distorted pixels (..., 2) → ideal normalised coordinates (..., 2), solved to ~1e-10 by iteration.

    ``cv2.undistortPoints`` stops after 5 iterations, which leaves ~0.1 px errors in NYU's corners;
    this uses OpenCV's iterative solver with a tight criterion.
    """
    pts = np.ascontiguousarray(uv.reshape(-1, 1, 2), dtype=np.float64)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, iters, 1e-12)
    if hasattr(cv2, "undistortPointsIter"):  # OpenCV 4.x
        out = cv2.undistortPointsIter(pts, K, dist, None, None, crit)
    else:  # OpenCV 5 folded the criteria into undistortPoints(src, K, dist, dst, R, P, criteria)
        out = cv2.undistortPoints(pts, K, dist, None, None, None, crit)
    return out.reshape(uv.shape)


def distortion_maps(K: np.ndarray, dist: np.ndarray, hw: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Maps for ``cv2.remap`` that turn an ideal pinhole image (intrinsics K) into the distorted one.

    Returns (map_x, map_y) float32 (H, W): for each distorted pixel, where to read the ideal image.
    """
    h, w = hw
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    xy = undistort_normalized(np.stack([u, v], -1), K, dist)
    map_x = K[0, 0] * xy[..., 0] + K[0, 2]
    map_y = K[1, 1] * xy[..., 1] + K[1, 2]
    return map_x.astype(np.float32), map_y.astype(np.float32)


def undistort_image(image: np.ndarray, K: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """``cv2.undistort`` with the same K for the output (as P²Net does): same size, same intrinsics."""
    return cv2.undistort(image, K, dist)


def undistorted_valid_share(K: np.ndarray, dist: np.ndarray, hw: tuple[int, int], side: int = 160) -> float:
    """The share of an :func:`undistort_image` output (intrinsics K, distortion ``dist``, size ``hw``) that
    reads from inside the distorted frame, the rest being black; measured on a copy at most ``side`` px on
    its long side (the share does not depend on the size: the distortion acts on normalised coordinates)."""
    h, w = hw
    s = min(1.0, side / max(h, w))
    small = (max(round(h * s), 1), max(round(w * s), 1))
    Ks = crop_resize_intrinsics(np.asarray(K, np.float64), hw, 0, small)
    with np.errstate(all="ignore"):
        map_x, map_y = cv2.initUndistortRectifyMap(Ks, np.asarray(dist, np.float64), None, Ks,
                                                   (small[1], small[0]), cv2.CV_32FC1)
        inside = (np.isfinite(map_x) & np.isfinite(map_y) & (map_x >= -0.5) & (map_x <= small[1] - 0.5)
                  & (map_y >= -0.5) & (map_y <= small[0] - 0.5))
    return float(inside.mean())


def crop_resize_intrinsics(K: np.ndarray, src_hw: tuple[int, int], crop: int, dst_hw: tuple[int, int],
                           p2net_cxcy_bug: bool = False) -> np.ndarray:
    """Intrinsics after cropping ``crop`` px from every side of a ``src_hw`` image and resizing to ``dst_hw``.

    With ``p2net_cxcy_bug`` the principal point is computed as P²Net's loader does (the *uncropped*
    cx, cy divided by the *cropped* size, no half-pixel shift; P²Net's ``datasets/nyu_dataset.py``,
    ``_get_intrinsics``, acknowledged in svip-lab/Indoor-SfMLearner issue #16), which
    misplaces it by ~10 px at 288×384. Default: the geometrically correct values.
    """
    hc, wc = src_hw[0] - 2 * crop, src_hw[1] - 2 * crop
    if hc <= 0 or wc <= 0:
        raise ValueError(f"crop {crop} leaves nothing of a {src_hw} image")
    sy, sx = dst_hw[0] / hc, dst_hw[1] / wc
    out = np.eye(3)
    out[0, 0] = K[0, 0] * sx
    out[1, 1] = K[1, 1] * sy
    if p2net_cxcy_bug:
        out[0, 2] = K[0, 2] / wc * dst_hw[1]
        out[1, 2] = K[1, 2] / hc * dst_hw[0]
    else:
        out[0, 2] = (K[0, 2] - crop + 0.5) * sx - 0.5
        out[1, 2] = (K[1, 2] - crop + 0.5) * sy - 0.5
    return out


def default_intrinsics(height: int, width: int) -> np.ndarray:
    """K (3,3) for an image of unknown camera: the horizontal field of view of the NYU Depth V2 RGB camera
    (fx = fy = 0.811·W) and the principal point at the image centre ((W−1)/2, (H−1)/2)."""
    f = NYU_FX_PER_WIDTH * width
    return np.array([[f, 0.0, (width - 1) / 2.0], [0.0, f, (height - 1) / 2.0], [0.0, 0.0, 1.0]])


def intrinsics(height: int, width: int, fx: float | None = None, fy: float | None = None,
               cx: float | None = None, cy: float | None = None) -> np.ndarray:
    """K (3,3) in pixels of a (height, width) image: the given values; fy defaults to fx, cx and cy to the
    image centre; no fx (and no fy) → :func:`default_intrinsics`."""
    if fx is None and fy is None:
        K = default_intrinsics(height, width)
    else:
        fx = fx if fx is not None else fy
        fy = fy if fy is not None else fx
        K = np.array([[fx, 0.0, (width - 1) / 2.0], [0.0, fy, (height - 1) / 2.0], [0.0, 0.0, 1.0]])
    if cx is not None:
        K[0, 2] = cx
    if cy is not None:
        K[1, 2] = cy
    if not (K[0, 0] > 0 and K[1, 1] > 0):
        raise ValueError(f"focal lengths must be positive, got fx={K[0, 0]}, fy={K[1, 1]}")
    return K
