"""Placing furniture: :class:`RoomBuilder` turns boxes given in a wall's local frame (x along the wall,
y from the wall into the room, z up) into world boxes of a :class:`~f2depth.synth.scene.Scene`, picks
materials from the room's :class:`~f2depth.synth.styles.Style` and keeps the wall intervals in use."""

from __future__ import annotations

import numpy as np

from f2depth.synth.scene import Box, Material
from f2depth.synth.styles import Style

#: local face names of the horizontal normals in a wall frame
_LOCAL = {(-1, 0): "left", (1, 0): "right", (0, -1): "back", (0, 1): "front"}

#: faces flush with the room's boundary get a minimal texture
HIDDEN = Material("flat", (0.5, 0.5, 0.5), density=1.0, amp=0.0)


class RoomBuilder:
    """Collects boxes in world coordinates for a room of size (W, D, H) with its corner at the origin."""

    def __init__(self, style: Style, rng: np.random.Generator, size: tuple[float, float, float]):
        self.style, self.rng = style, rng
        self.W, self.D, self.H = size
        self.boxes: list[Box] = []
        self.low: dict[int, list[tuple[float, float]]] = {k: [] for k in range(4)}
        self.high: dict[int, list[tuple[float, float]]] = {k: [] for k in range(4)}

    # ---- materials ---------------------------------------------------------------------------------
    def pick(self, colors):
        return colors[int(self.rng.integers(len(colors)))]

    def wood(self, color=None) -> Material:
        return Material("wood", color or self.pick(self.style.wood), self.style.wall_density * 1.5, amp=0.07)

    def paint(self, color, amp: float | None = None) -> Material:
        return Material("flat", color, self.style.wall_density,
                        amp=self.style.wall_amp if amp is None else amp)

    def fabric(self, color=None) -> Material:
        return Material("carpet", color or self.pick(self.style.fabric), self.style.wall_density * 2,
                        amp=0.06)

    def detail(self, kind: str, **kw) -> Material:
        kw.setdefault("palette", self.style.accents)
        return Material(kind, density=self.style.detail_density, **kw)

    # ---- geometry ----------------------------------------------------------------------------------
    def wall_frame(self, wall: int):
        """(origin (2,), ex (2,), ey (2,), length) of wall 0..3 (y=0, x=W, y=D, x=0), y into the room."""
        W, D = self.W, self.D
        return [((0.0, 0.0), (1, 0), (0, 1), W), ((W, 0.0), (0, 1), (-1, 0), D),
                ((W, D), (-1, 0), (0, -1), W), ((0.0, D), (0, -1), (1, 0), D)][wall]

    def put(self, frame, x0, x1, y0, y1, z0, z1, mats: dict[str, Material], label: str, obstacle=True):
        """Add a box given in the local frame; ``mats`` maps left/right/back/front/top/bottom/default."""
        origin, ex, ey = np.asarray(frame[0], float), np.asarray(frame[1]), np.asarray(frame[2])
        p, q = origin + x0 * ex + y0 * ey, origin + x1 * ex + y1 * ey
        lo = (min(p[0], q[0]), min(p[1], q[1]), z0)
        hi = (max(p[0], q[0]), max(p[1], q[1]), z1)
        faces = []
        for f in range(6):
            axis, side = divmod(f, 2)
            if axis == 2:
                name = "top" if side else "bottom"
            else:
                n = np.zeros(2, int)
                n[axis] = 1 if side else -1
                name = _LOCAL[(int(n @ ex), int(n @ ey))]
            mat = mats.get(name, mats["default"])
            plane = (hi if side else lo)[axis]
            bound = (self.W, self.D, self.H)[axis] if side else 0.0
            if abs(plane - bound) < 1e-9:  # flush with a wall, the floor or the ceiling: never seen
                faces.append(HIDDEN)
                continue
            if self.style.rich and mat.kind != "emissive":
                mat = Material("rich", density=self.style.detail_density)
            faces.append(mat)
        self.boxes.append(Box(lo, hi, tuple(faces), label, obstacle))

    def reserve(self, wall: int, width: float, high: bool = False, margin: float = 0.08) -> float | None:
        """A free start position along ``wall`` for an item of ``width`` (None if the wall is full)."""
        length = self.wall_frame(wall)[3]
        used = (self.high if high else self.low)[wall]
        for _ in range(30):
            if length - width - 2 * margin <= 0:
                return None
            x0 = float(self.rng.uniform(margin, length - width - margin))
            if all(x0 + width + margin <= a or x0 >= b + margin for a, b in used):
                used.append((x0, x0 + width))
                return x0
        return None
