"""Backward warping with ARFlow's conventions: one implementation, in :mod:`f2depth.geometry`.

``warp(img, flow)[..., y, x] = img[..., y + v(y, x), x + u(y, x)]``, bilinear, ``align_corners=True``,
``border`` padding by default (ARFlow's code, ``utils/warp_utils.py``, ``flow_warp``). Re-exported here
as ``f2depth.flow.warp`` (a stable public name) together with the pixel grid the ARFlow loss uses.
"""

from __future__ import annotations

from f2depth.geometry import pixel_grid as base_grid
from f2depth.geometry import warp

__all__ = ["base_grid", "warp"]
