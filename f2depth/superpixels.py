"""P²Net's size threshold of a "large" superpixel, the one home of the constant that ``prepare`` reports and
the planar loss L_spp uses: 1000 px at P²Net's 288×384 training size (P²Net's code, `trainer_geo.py`),
scaled by image area to other sizes."""

from __future__ import annotations

MIN_AREA = 1000
P2NET_HW = (288, 384)


def scaled_min_area(height: int, width: int) -> float:
    """``MIN_AREA`` at 288×384 scaled by image area to ``height``×``width`` (111 px at 96×128)."""
    return MIN_AREA * height * width / (P2NET_HW[0] * P2NET_HW[1])
