"""DSO's pixel selector (Engel et al., TPAMI 2018; DSO's ``PixelSelector2.cpp``) and keypoint files.

``select_pixels(gray, preset="dso", **overrides)`` and ``select_raw(gray, pot, direction)`` select;
``KeypointFile(path).tensor(frame_index)`` and ``fill_up(points, count, H, W, generator)`` serve the losses.
See docs/keypoints.md.
"""

from f2depth.keypoints.api import KeypointSelector, rescale_points, select_pixels, select_raw
from f2depth.keypoints.presets import PRESETS, Preset, get_preset
from f2depth.keypoints.store import KeypointFile, KeypointFileError, fill_up, save_keypoints

__all__ = [
    "PRESETS",
    "KeypointFile",
    "KeypointFileError",
    "KeypointSelector",
    "Preset",
    "fill_up",
    "get_preset",
    "rescale_points",
    "save_keypoints",
    "select_pixels",
    "select_raw",
]
