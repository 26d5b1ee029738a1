"""Overlay pictures of keypoints for reports."""

from __future__ import annotations

import cv2
import numpy as np

#: RGB colour per level: level 0 red, level 1 yellow, level 2 cyan.
LEVEL_COLOURS = ((255, 40, 40), (255, 220, 0), (0, 220, 255))


def draw_keypoints(rgb: np.ndarray, points: np.ndarray, min_side: int = 480) -> np.ndarray:
    """The image (H, W, 3) uint8 RGB with its keypoints (N, 3) x, y, level drawn as dots.

    Small images are enlarged by an integer factor (nearest) until the short side is at least
    ``min_side`` px, so that the dots stay visible; a 24-px caption strip goes on top; returns RGB uint8.
    """
    scale = max(1, -(-min_side // max(1, min(rgb.shape[:2]))))
    canvas = np.ascontiguousarray(np.repeat(np.repeat(rgb, scale, axis=0), scale, axis=1))
    radius = max(1, scale // 2)
    for x, y, level in np.asarray(points, np.int64).reshape(-1, 3):
        centre = (int(x) * scale + scale // 2, int(y) * scale + scale // 2)
        cv2.circle(canvas, centre, radius, LEVEL_COLOURS[min(int(level), 2)], -1, lineType=cv2.LINE_AA)
    banner = np.zeros((24, canvas.shape[1], 3), np.uint8)
    pixels = len(np.unique(np.asarray(points).reshape(-1, 3)[:, :2], axis=0))
    label = f"{len(points)} keypoints on {pixels} pixels: red level 0, yellow level 1, cyan level 2"
    cv2.putText(banner, label, (6, 17), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
    return np.concatenate([banner, canvas], axis=0)
