"""Furniture recipes. Wall items take ``(builder, wall)`` and place one piece against wall 0..3 if there is
room; centre items take the builder and place a piece in the middle of the room."""

from __future__ import annotations

from f2depth.synth.builder import RoomBuilder
from f2depth.synth.scene import Material


def _clutter(b: RoomBuilder, frame, x0, x1, y0, y1, z, n):
    for _ in range(n):
        w, d, h = b.rng.uniform(0.06, 0.3), b.rng.uniform(0.06, 0.25), b.rng.uniform(0.04, 0.3)
        if x1 - x0 <= w or y1 - y0 <= d:
            return
        cx, cy = b.rng.uniform(x0, x1 - w), b.rng.uniform(y0, y1 - d)
        color = b.pick(b.style.accents)
        mat = b.detail("poster") if b.rng.random() < 0.3 else b.paint(color, 0.05)
        b.put(frame, cx, cx + w, cy, cy + d, z, z + h, {"default": mat}, "clutter", obstacle=False)


def _legs(b, frame, x0, x1, y0, y1, z, mat, t=0.04):
    for lx, ly in ((x0, y0), (x1 - t, y0), (x0, y1 - t), (x1 - t, y1 - t)):
        b.put(frame, lx, lx + t, ly, ly + t, 0.0, z, {"default": mat}, "leg")


def bed(b: RoomBuilder, wall: int):
    w, d = b.rng.uniform(1.3, 1.7), b.rng.uniform(1.9, 2.05)
    x0 = b.reserve(wall, w)
    if x0 is None:
        return
    f, wood, cover = b.wall_frame(wall), b.wood(), b.fabric()
    b.put(f, x0, x0 + w, 0.0, d, 0.0, 0.3, {"default": wood}, "bed")
    b.put(f, x0 + 0.02, x0 + w - 0.02, 0.08, d - 0.02, 0.3, 0.52, {"default": cover}, "mattress")
    b.put(f, x0, x0 + w, 0.0, 0.07, 0.0, b.rng.uniform(0.8, 1.1), {"default": wood}, "headboard")
    pillow = b.fabric((0.92, 0.92, 0.9))
    pw = (w - 0.3) / 2
    for px in (x0 + 0.1, x0 + 0.2 + pw):
        b.put(f, px, px + pw, 0.12, 0.5, 0.52, 0.64, {"default": pillow}, "pillow", obstacle=False)


def wardrobe(b: RoomBuilder, wall: int):
    w = b.rng.uniform(0.8, 1.5)
    x0 = b.reserve(wall, w)
    if x0 is not None:
        h = min(b.H - 0.2, b.rng.uniform(1.8, 2.2))
        b.put(b.wall_frame(wall), x0, x0 + w, 0.0, 0.6, 0.0, h, {"default": b.wood()}, "wardrobe")


def cabinet(b: RoomBuilder, wall: int):
    w = b.rng.uniform(0.45, 1.2)
    x0 = b.reserve(wall, w)
    if x0 is None:
        return
    f, h, d = b.wall_frame(wall), b.rng.uniform(0.5, 1.1), b.rng.uniform(0.4, 0.5)
    b.put(f, x0, x0 + w, 0.0, d, 0.0, h, {"default": b.wood()}, "cabinet")
    _clutter(b, f, x0, x0 + w, 0.05, d - 0.05, h, int(b.rng.integers(0, 3)))


def desk(b: RoomBuilder, wall: int):
    w, d = b.rng.uniform(1.0, 1.6), b.rng.uniform(0.6, 0.75)
    x0 = b.reserve(wall, w)
    if x0 is None:
        return
    f, wood, z = b.wall_frame(wall), b.wood(), b.rng.uniform(0.72, 0.76)
    b.put(f, x0, x0 + w, 0.0, d, z - 0.03, z, {"default": wood}, "desk")
    _legs(b, f, x0, x0 + w, 0.0, d, z - 0.03, wood)
    if b.rng.random() < 0.7:  # monitor
        mw = b.rng.uniform(0.45, 0.6)
        mx = x0 + b.rng.uniform(0.05, max(0.06, w - mw - 0.05))
        dark = b.paint((0.08, 0.08, 0.09), 0.02)
        b.put(f, mx + mw / 2 - 0.03, mx + mw / 2 + 0.03, 0.12, 0.18, z, z + 0.12, {"default": dark}, "stand")
        b.put(f, mx, mx + mw, 0.12, 0.16, z + 0.1, z + 0.1 + 0.6 * mw,
              {"default": dark, "front": b.detail("screen")}, "monitor")
    _clutter(b, f, x0 + 0.05, x0 + w - 0.05, 0.25, d - 0.05, z, int(b.rng.integers(1, 4)))


def shelf(b: RoomBuilder, wall: int):
    w = b.rng.uniform(0.7, 1.5)
    x0 = b.reserve(wall, w)
    if x0 is None:
        return
    h = min(b.H - 0.3, b.rng.uniform(0.9, 2.0))
    wood = b.wood()
    rows = max(2, round(h / 0.36))
    books = Material("books", wood.color, b.style.detail_density, size=rows)
    b.put(b.wall_frame(wall), x0, x0 + w, 0.0, 0.32, 0.0, h, {"default": wood, "front": books}, "bookshelf")


def sofa(b: RoomBuilder, wall: int):
    w, d = b.rng.uniform(1.7, 2.3), b.rng.uniform(0.85, 0.95)
    x0 = b.reserve(wall, w)
    if x0 is None:
        return
    f, m = b.wall_frame(wall), {"default": b.fabric()}
    b.put(f, x0, x0 + w, 0.0, d, 0.0, 0.42, m, "sofa")
    b.put(f, x0, x0 + w, 0.0, 0.22, 0.42, 0.85, m, "sofa back")
    for ax in (x0, x0 + w - 0.2):
        b.put(f, ax, ax + 0.2, 0.22, d, 0.42, 0.62, m, "sofa arm")


def tv_stand(b: RoomBuilder, wall: int):
    w = b.rng.uniform(1.1, 1.7)
    x0 = b.reserve(wall, w)
    if x0 is None:
        return
    f = b.wall_frame(wall)
    b.put(f, x0, x0 + w, 0.0, 0.45, 0.0, 0.5, {"default": b.wood()}, "tv stand")
    tw = 0.7 * w
    tx0 = x0 + (w - tw) / 2
    dark = b.paint((0.06, 0.06, 0.07), 0.02)
    b.put(f, tx0, tx0 + tw, 0.1, 0.16, 0.55, 0.55 + 0.56 * tw,
          {"default": dark, "front": b.detail("screen")}, "tv")


def counter(b: RoomBuilder, wall: int):
    length = b.wall_frame(wall)[3]
    w = b.rng.uniform(1.4, max(1.5, min(3.2, length - 0.4)))
    x0 = b.reserve(wall, w)
    if x0 is None:
        return
    f, body = b.wall_frame(wall), b.wood()
    b.put(f, x0, x0 + w, 0.0, 0.6, 0.0, 0.88, {"default": body}, "counter")
    b.put(f, x0, x0 + w, 0.0, 0.63, 0.88, 0.92, {"default": b.paint((0.8, 0.8, 0.78), 0.05)}, "worktop")
    tiles = b.detail("tiles", color=b.pick(((0.9, 0.9, 0.88), (0.7, 0.8, 0.85), (0.85, 0.75, 0.6))),
                     size=float(b.rng.choice([0.1, 0.15])), amp=0.15)
    b.put(f, x0, x0 + w, 0.0, 0.012, 0.92, 1.45, {"default": tiles}, "backsplash", obstacle=False)
    top = min(b.H - 0.15, 2.15)
    b.put(f, x0, x0 + w, 0.0, 0.35, 1.45, top, {"default": body}, "upper cabinets")
    _clutter(b, f, x0 + 0.1, x0 + w - 0.1, 0.1, 0.55, 0.92, int(b.rng.integers(1, 4)))


def fridge(b: RoomBuilder, wall: int):
    x0 = b.reserve(wall, 0.7)
    if x0 is not None:
        color = b.pick(((0.92, 0.92, 0.92), (0.7, 0.72, 0.74)))
        b.put(b.wall_frame(wall), x0, x0 + 0.7, 0.0, 0.7, 0.0, 1.8,
              {"default": b.paint(color, 0.02)}, "fridge")


def poster(b: RoomBuilder, wall: int):
    w, h = b.rng.uniform(0.35, 1.0), b.rng.uniform(0.45, 1.0)
    x0 = b.reserve(wall, w, high=True)
    if x0 is None:
        return
    z0 = b.rng.uniform(1.0, max(1.05, b.H - h - 0.3))
    m = {"default": b.paint((0.95, 0.95, 0.95), 0.01), "front": b.detail("poster")}
    b.put(b.wall_frame(wall), x0, x0 + w, 0.0, 0.015, z0, z0 + h, m, "poster", obstacle=False)


def whiteboard(b: RoomBuilder, wall: int):
    w = b.rng.uniform(1.2, 2.0)
    x0 = b.reserve(wall, w, high=True)
    if x0 is not None:
        m = {"default": b.paint((0.6, 0.6, 0.62), 0.02), "front": b.paint((0.96, 0.96, 0.96), 0.03)}
        b.put(b.wall_frame(wall), x0, x0 + w, 0.0, 0.02, 0.9, 2.0, m, "whiteboard", obstacle=False)


def window(b: RoomBuilder, wall: int):
    w, h = b.rng.uniform(0.8, 1.5), b.rng.uniform(0.9, 1.3)
    x0 = b.reserve(wall, w, high=True)
    if x0 is None:
        return
    f, z0 = b.wall_frame(wall), 0.95
    sky = Material("emissive", b.pick(((0.85, 0.9, 1.0), (0.95, 0.95, 0.9))), 4.0,
                   strength=b.rng.uniform(2.5, 5))
    frame_m = b.paint((0.95, 0.95, 0.95), 0.01)
    b.put(f, x0, x0 + w, 0.0, 0.02, z0, min(z0 + h, b.H - 0.2), {"default": frame_m, "front": sky}, "window",
          obstacle=False)
    b.put(f, x0 - 0.05, x0 + w + 0.05, 0.0, 0.12, z0 - 0.04, z0, {"default": frame_m}, "sill", obstacle=False)


def door(b: RoomBuilder, wall: int):
    x0 = b.reserve(wall, 0.95)
    if x0 is not None:
        b.put(b.wall_frame(wall), x0, x0 + 0.95, 0.0, 0.03, 0.0, 2.1, {"default": b.wood()}, "door",
              obstacle=False)


def lockers(b: RoomBuilder, wall: int):
    n = int(b.rng.integers(3, 7))
    x0 = b.reserve(wall, 0.4 * n)
    if x0 is None:
        return
    color = b.pick(((0.3, 0.45, 0.6), (0.6, 0.62, 0.66), (0.75, 0.3, 0.2)))
    for k in range(n):
        b.put(b.wall_frame(wall), x0 + 0.4 * k, x0 + 0.4 * k + 0.39, 0.0, 0.45, 0.0, 1.8,
              {"default": b.paint(color, 0.03)}, "locker")


def notice_board(b: RoomBuilder, wall: int):
    w = b.rng.uniform(1.0, 1.8)
    x0 = b.reserve(wall, w, high=True)
    if x0 is None:
        return
    f = b.wall_frame(wall)
    cork = Material("carpet", (0.62, 0.45, 0.3), b.style.detail_density, amp=0.2)
    b.put(f, x0, x0 + w, 0.0, 0.02, 1.0, 2.0, {"default": cork}, "notice board", obstacle=False)
    for _ in range(int(b.rng.integers(2, 6))):
        pw, ph = b.rng.uniform(0.15, 0.35), b.rng.uniform(0.2, 0.4)
        px, pz = b.rng.uniform(x0 + 0.03, x0 + w - pw - 0.03), b.rng.uniform(1.03, 1.97 - ph)
        b.put(f, px, px + pw, 0.02, 0.025, pz, pz + ph, {"default": b.detail("poster")}, "notice",
              obstacle=False)


def stairs(b: RoomBuilder, wall: int):
    n = int(b.rng.integers(6, 10))
    x0 = b.reserve(wall, 1.0)
    if x0 is None:
        return
    f, m = b.wall_frame(wall), {"default": b.fabric((0.3, 0.3, 0.32)), "front": b.wood((0.5, 0.4, 0.3))}
    for k in range(n):  # steps climbing away from the room along the wall
        b.put(f, x0, x0 + 1.0, 0.0, 0.28 * (n - k), 0.18 * k, 0.18 * (k + 1), m, "step")


def fireplace(b: RoomBuilder, wall: int):
    x0 = b.reserve(wall, 1.4)
    if x0 is None:
        return
    f = b.wall_frame(wall)
    brick = b.detail("bricks", color=(0.55, 0.25, 0.18), size=0.07)
    b.put(f, x0, x0 + 1.4, 0.0, 0.5, 0.0, 1.15, {"default": brick}, "fireplace")
    b.put(f, x0 + 0.35, x0 + 1.05, 0.5, 0.51, 0.1, 0.7, {"default": b.detail("screen")}, "hearth",
          obstacle=False)
    b.put(f, x0 - 0.1, x0 + 1.5, 0.0, 0.6, 1.15, 1.22, {"default": b.wood()}, "mantel")


# ---- things in the middle of the room ------------------------------------------------------------------
def _centre_frame(b: RoomBuilder, w: float, d: float):
    """A frame at a random spot where a w × d footprint fits in the room's middle (or None)."""
    lo_x, hi_x = 1.0, b.W - 1.0 - w
    lo_y, hi_y = 1.0, b.D - 1.0 - d
    if hi_x <= lo_x or hi_y <= lo_y:
        return None
    x, y = b.rng.uniform(lo_x, hi_x), b.rng.uniform(lo_y, hi_y)
    return ((x, y), (1, 0), (0, 1))


def table(b: RoomBuilder, chairs: bool = True, top: Material | None = None, props=None):
    w, d = b.rng.uniform(0.8, 1.6), b.rng.uniform(0.7, 1.0)
    f = _centre_frame(b, w, d)
    if f is None:
        return
    wood, z = b.wood(), b.rng.uniform(0.72, 0.76) if chairs else b.rng.uniform(0.4, 0.5)
    b.put(f, 0.0, w, 0.0, d, z - 0.04, z, {"default": wood, "top": top or wood}, "table")
    _legs(b, f, 0.02, w - 0.02, 0.02, d - 0.02, z - 0.04, wood)
    if chairs:
        seat = b.fabric()
        for cx, cy, by in ((w / 2 - 0.22, -0.5, -0.5), (w / 2 - 0.22, d + 0.06, d + 0.44)):
            b.put(f, cx, cx + 0.44, cy, cy + 0.44, 0.42, 0.46, {"default": seat}, "chair")
            _legs(b, f, cx, cx + 0.44, cy, cy + 0.44, 0.42, wood, t=0.03)
            b.put(f, cx, cx + 0.44, by, by + 0.04, 0.46, 0.9, {"default": seat}, "chair back")
    if props:
        props(b, f, w, d, z)
    else:
        _clutter(b, f, 0.1, w - 0.1, 0.1, d - 0.1, z, int(b.rng.integers(0, 3)))


def rug(b: RoomBuilder):
    w, d = b.rng.uniform(1.2, 2.4), b.rng.uniform(0.9, 1.8)
    f = _centre_frame(b, w, d)
    if f is not None:
        b.put(f, 0.0, w, 0.0, d, 0.0, 0.012, {"default": b.detail("rug")}, "rug", obstacle=False)


def tiled_patch(b: RoomBuilder):
    w, d = b.rng.uniform(1.0, 2.0), b.rng.uniform(1.0, 2.0)
    f = _centre_frame(b, w, d)
    if f is not None:
        tiles = b.detail("tiles", color=b.pick(((0.85, 0.85, 0.82), (0.6, 0.4, 0.3), (0.3, 0.3, 0.32))),
                         size=float(b.rng.choice([0.2, 0.3])), amp=0.25)
        b.put(f, 0.0, w, 0.0, d, 0.0, 0.005, {"default": tiles}, "tiled patch", obstacle=False)


def head_props(b, f, w, d, z):
    for _ in range(int(b.rng.integers(2, 5))):
        x, y = b.rng.uniform(0.05, w - 0.25), b.rng.uniform(0.05, d - 0.25)
        skin = b.paint(b.pick(((0.85, 0.65, 0.5), (0.6, 0.42, 0.3), (0.9, 0.9, 0.88))), 0.04)
        b.put(f, x, x + 0.18, y, y + 0.2, z, z + 0.26, {"default": skin}, "head", obstacle=False)


def pumpkin_props(b, f, w, d, z):
    for _ in range(int(b.rng.integers(1, 3))):
        s = b.rng.uniform(0.25, 0.4)
        x, y = b.rng.uniform(0.0, max(0.01, w - s)), b.rng.uniform(0.0, max(0.01, d - s))
        m = Material("carpet", (0.95, 0.45, 0.05), b.style.detail_density, amp=0.15)
        b.put(f, x, x + s, y, y + s, z, z + 0.8 * s, {"default": m}, "pumpkin", obstacle=False)
