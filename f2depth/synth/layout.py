"""Room layouts: a box room of a :class:`~f2depth.synth.styles.Style` and kind, furniture against the walls
and in the middle, wall decorations, rugs and lamps, then baked into a
:class:`~f2depth.synth.scene.Scene`."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from f2depth.synth.builder import RoomBuilder
from f2depth.synth.furniture import (
    bed,
    cabinet,
    counter,
    desk,
    door,
    fireplace,
    fridge,
    head_props,
    lockers,
    notice_board,
    poster,
    pumpkin_props,
    rug,
    shelf,
    sofa,
    stairs,
    table,
    tiled_patch,
    tv_stand,
    wardrobe,
    whiteboard,
    window,
)
from f2depth.synth.scene import Box, Light, Material, Scene, bake
from f2depth.synth.styles import STYLES

NYU_KINDS = ("bedroom", "living_room", "office", "kitchen", "dining_room", "study")
SEVENSCENES_NAMES = ("chess", "fire", "heads", "office", "pumpkin", "redkitchen", "stairs")
CAMPUS_KINDS = ("corridor", "classroom", "lobby", "library", "lab", "office")
WallRecipe = Callable[[RoomBuilder, int], None]
_WALL_ITEMS: dict[str, tuple[list[WallRecipe], list[WallRecipe]]] = {
    # (always placed, drawn from)
    "bedroom": ([bed], [wardrobe, cabinet, cabinet, desk, shelf]),
    "living_room": ([sofa, tv_stand], [shelf, shelf, cabinet, cabinet]),
    "office": ([desk, desk], [shelf, cabinet, desk, whiteboard]),
    "kitchen": ([counter, fridge], [counter, cabinet, shelf]),
    "dining_room": ([cabinet], [shelf, cabinet, shelf]),
    "study": ([desk, shelf], [shelf, cabinet, wardrobe]),
    # 7-Scenes
    "chess": ([desk], [shelf, cabinet, cabinet]),
    "fire": ([fireplace], [sofa, cabinet, shelf]),
    "heads": ([desk, desk], [cabinet, shelf]),
    "pumpkin": ([shelf], [cabinet, desk, shelf]),
    "redkitchen": ([counter, counter], [fridge, cabinet]),
    "stairs": ([stairs], [cabinet, shelf]),
    # campus
    "corridor": ([door, door, lockers], [door, lockers, notice_board]),
    "classroom": ([whiteboard, desk], [desk, cabinet, shelf, door]),
    "lobby": ([door, notice_board], [lockers, cabinet, shelf]),
    "library": ([shelf, shelf, shelf], [shelf, desk, door]),
    "lab": ([desk, desk, cabinet], [whiteboard, shelf, door]),
    # animated
    "animated": ([], [shelf, cabinet, wardrobe, desk, sofa]),
}
_CENTRE = {"living_room": lambda b: table(b, chairs=False), "kitchen": table, "dining_room": table,
           "chess": lambda b: table(b, chairs=True, top=b.detail("chess")),
           "heads": lambda b: table(b, chairs=False, props=head_props),
           "pumpkin": lambda b: table(b, chairs=False, props=pumpkin_props), "classroom": table,
           "library": table}


def build(style_name: str, kind: str, name: str, rng: np.random.Generator) -> Scene:
    """Lay out and bake a room of ``style_name`` and ``kind`` (see the recipe tables)."""
    style = STYLES[style_name]
    if kind == "redkitchen":  # 7-Scenes' red kitchen
        style = dataclasses.replace(style, wood=((0.62, 0.08, 0.08), (0.7, 0.12, 0.1)))
    if kind not in _WALL_ITEMS:
        raise ValueError(f"unknown room kind {kind!r}; known: {sorted(_WALL_ITEMS)}")
    size = (float(rng.uniform(*style.size_x)), float(rng.uniform(*style.size_y)),
            float(rng.uniform(*style.height)))
    if rng.random() < 0.5 and style.name != "campus":
        size = (size[1], size[0], size[2])
    b = RoomBuilder(style, rng, size)
    always, optional = _WALL_ITEMS[kind]
    for recipe in always:
        recipe(b, int(rng.integers(4)))
    for recipe in optional:
        if rng.random() < 0.6:
            recipe(b, int(rng.integers(4)))
    if kind in _CENTRE:
        _CENTRE[kind](b)
    if style.rich:
        _props(b, int(rng.integers(6, 12)))
    for _ in range(int(rng.integers(style.posters[0], style.posters[1] + 1))):
        poster(b, int(rng.integers(4)))
    if rng.random() < style.window_prob:
        window(b, int(rng.integers(4)))
    if rng.random() < style.rug_prob:
        rug(b)
    if kind == "kitchen" and rng.random() < 0.6:
        tiled_patch(b)
    lights = _lights(b)
    wall_mats = [b.paint(b.pick(style.walls))] * 4
    if rng.random() < 0.3:  # an accent wall
        wall_mats[int(rng.integers(4))] = b.paint(b.pick(style.walls))
    fk, fc, famp = style.floors[int(rng.integers(len(style.floors)))]
    floor = Material(fk, fc, style.wall_density * (2 if fk != "flat" else 1), amp=famp)
    if style.ceiling_kind == "tiles":
        ceiling = Material("tiles", style.ceiling, style.wall_density * 2, amp=0.04, size=0.6)
    else:
        ceiling = b.paint(style.ceiling, style.wall_amp * 0.5)
    mats = [*wall_mats, floor, ceiling]
    if style.rich:
        mats = [Material("rich", density=style.wall_density) for _ in range(6)]
    # room faces: x-lo, x-hi, y-lo, y-hi walls, floor, ceiling
    room = Box((0.0, 0.0, 0.0), size, tuple(mats[i] for i in (3, 1, 0, 2, 4, 5)), "room")
    mean_direct = sum(np.mean(lt.power) for lt in lights) / (size[2] ** 2)
    return bake(name, room, b.boxes, lights, style.ambient * mean_direct, rng)


def _lights(b: RoomBuilder) -> list[Light]:
    """Point lights below ceiling fixtures, spread over the room along its longer side."""
    n = int(b.rng.integers(b.style.lights[0], b.style.lights[1] + 1))
    long_x = b.W >= b.D
    out = []
    color = np.asarray(b.pick(b.style.light_color))
    for k in range(n):
        s = (k + b.rng.uniform(0.3, 0.7)) / n
        t = b.rng.uniform(0.3, 0.7)
        x, y = (s * b.W, t * b.D) if long_x else (t * b.W, s * b.D)
        z = b.H - 0.25
        power = color * (z**2) * b.rng.uniform(0.6, 1.0)
        out.append(Light((x, y, z), tuple(power)))
        lamp = Material("emissive", tuple(color), 4.0, strength=b.rng.uniform(6, 10))
        panel = 0.6 if b.style.name == "campus" else 0.3
        f = ((x - panel / 2, y - 0.15), (1, 0), (0, 1))
        b.put(f, 0.0, panel, 0.0, 0.3, b.H - 0.06, b.H, {"default": lamp}, "lamp", obstacle=False)
    return out


def _props(b: RoomBuilder, n: int):
    """Free-standing and hanging blocks for the animated set."""
    for _ in range(n):
        w, d = b.rng.uniform(0.2, 1.0), b.rng.uniform(0.2, 1.0)
        x, y = b.rng.uniform(0.3, b.W - w - 0.3), b.rng.uniform(0.3, b.D - d - 0.3)
        z0 = 0.0 if b.rng.random() < 0.6 else b.rng.uniform(1.9, b.H - 0.6)
        z1 = z0 + b.rng.uniform(0.3, 1.8) if z0 == 0.0 else b.rng.uniform(z0 + 0.2, b.H - 0.1)
        f = ((x, y), (1, 0), (0, 1))
        b.put(f, 0.0, w, 0.0, d, z0, z1, {"default": b.paint((0.5, 0.5, 0.5))}, "prop", obstacle=z0 == 0.0)
