"""Public selector API: ``select_pixels`` (a fresh selector per image) and ``KeypointSelector`` (pot carried
over a sequence, as DSO's persistent selector)."""

from __future__ import annotations

import cv2
import numpy as np

from f2depth.keypoints.makemaps import MapsResult, make_maps
from f2depth.keypoints.presets import Preset, get_preset
from f2depth.keypoints.select import prepare


def _check_gray(gray: np.ndarray) -> np.ndarray:
    gray = np.asarray(gray)
    if gray.ndim != 2:
        raise ValueError(f"expected a grey image of shape (H, W), got shape {gray.shape}; convert RGB with "
                         "cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)")
    if gray.dtype != np.uint8 and not np.issubdtype(gray.dtype, np.floating):
        raise ValueError(f"expected a uint8 (or float) grey image, got dtype {gray.dtype}")
    return gray


def rescale_points(points: np.ndarray, from_size: tuple[int, int], to_size: tuple[int, int]) -> np.ndarray:
    """Map (N, 3) x, y, level from a (height, width) grid to another with P²Net's ``v·H // h``.

    Points that land on the same pixel are all kept (P²Net keeps them); the result is re-sorted into
    raster order of the target grid, stable, so coinciding points keep their original order.
    """
    (h0, w0), (h1, w1) = from_size, to_size
    out = points.copy()
    out[:, 0] = points[:, 0] * w1 // w0
    out[:, 1] = points[:, 1] * h1 // h0
    return out[np.argsort(out[:, 1] * w1 + out[:, 0], kind="stable")]


class KeypointSelector:
    """DSO's pixel selector with a preset; the cell size ``pot`` carries over from image to image.

    ``selector(gray, out_hw=None)`` returns (N, 3) int64 x, y, level in raster order at ``out_hw``
    (default: the size of ``gray``).
    ``last`` holds the :class:`MapsResult` of the latest call (at the working size).
    """

    def __init__(self, preset: str | Preset = "dso", **overrides) -> None:
        self.preset = get_preset(preset, **overrides)
        self.pot = self.preset.pot
        self.last: MapsResult | None = None

    def __call__(self, gray: np.ndarray, out_hw: tuple[int, int] | None = None) -> np.ndarray:
        """Keypoints (N, 3) int64 x, y, level of ``gray`` (H, W).

        They are selected at the preset's working size (or at (H, W)) and mapped to ``out_hw`` (default:
        (H, W)) with P²Net's integer arithmetic ``x·W_out // W_work``, ``y·H_out // H_work``: the
        keypoints of a full-resolution frame at the training size (P²Net's ``datasets/nyu_dataset.py``).
        """
        gray = _check_gray(gray)
        cfg = self.preset
        out_hw = tuple(gray.shape) if out_hw is None else (int(out_hw[0]), int(out_hw[1]))
        work = gray
        if cfg.work_size is not None and tuple(cfg.work_size) != gray.shape:
            height, width = cfg.work_size
            work = cv2.resize(gray, (width, height), interpolation=cv2.INTER_LINEAR)
        prep = prepare(work, cfg.th_factor, cfg.direction, cfg.hist_add)
        result = make_maps(prep, self.pot, cfg.density, cfg.recursions)
        self.pot = result.pot_out
        self.last = result
        points = result.points
        if cfg.max_points is not None:
            points = points[: cfg.max_points]
        if work.shape != out_hw:
            points = rescale_points(points, work.shape, out_hw)
        return points


def select_pixels(gray: np.ndarray, preset: str | Preset = "dso", out_hw: tuple[int, int] | None = None,
                  **overrides) -> np.ndarray:
    """Keypoints of an 8-bit grey image (H, W): (N, 3) int64 x, y, level (0/1/2) in raster order,
    mapped to ``out_hw`` (default (H, W)) with P²Net's integer arithmetic.

    A fresh selector (pot starts at ``pot``, 3 by default). ``preset`` ``"dso"`` or ``"p2net"``;
    overrides: ``density``, ``recursions``, ``direction``, ``th_factor``, ``pot`` (and the other
    :class:`Preset` fields). A flat image gives an empty (0, 3) array.
    """
    return KeypointSelector(preset, **overrides)(gray, out_hw)

