"""DSO's pixel selector (Engel et al., TPAMI 2018; DSO's ``PixelSelector2.cpp``) and keypoint files.

``select_pixels(gray, preset="dso", **overrides)`` and ``KeypointSelector`` select
(:mod:`~f2depth.keypoints.api`); ``KeypointFile(path).tensor(frame_index)`` and ``fill_up(points, count, H,
W, generator)`` serve the losses (:mod:`~f2depth.keypoints.store`). See docs/keypoints.md. The names below
are imported from their module on first use, so importing one module of this package loads no other.
"""

from f2depth.lazy import lazy_getattr

_HOMES = {"select_pixels": "api", "KeypointSelector": "api", "rescale_points": "api",
          "PRESETS": "presets", "Preset": "presets", "get_preset": "presets", "KeypointFile": "store",
          "KeypointFileError": "store", "fill_up": "store", "save_keypoints": "store"}
__all__ = sorted(_HOMES)

__getattr__ = lazy_getattr(__name__, _HOMES)
