"""Room styles: palettes, sizes, texture choices and lighting of the four synthetic domains.

- ``nyu``: homes and offices (bedroom, living room, office, kitchen, dining room, study) with light,
  flat-painted walls, wooden or carpeted floors, wooden furniture, and a few posters, book shelves, rugs
  and tiled patches;
- ``sevenscenes``: the held-out domain — darker saturated walls, blue-grey speckled carpet, acoustic
  ceiling tiles, black/steel furniture, desk clutter, warm dim light and stronger vignetting;
- ``campus``: university corridors, classrooms and lobbies: long bright rooms, lino floors, ceiling
  light panels, doors, notice boards and lockers;
- ``animated``: strongly textured surfaces everywhere, for flow pretraining.
"""

from __future__ import annotations

from dataclasses import dataclass

from f2depth.synth.textures import Color


@dataclass(frozen=True)
class Style:
    name: str
    walls: tuple[Color, ...]
    floors: tuple[tuple[str, Color, float], ...]  # (material kind, colour, contrast)
    ceiling: Color
    wood: tuple[Color, ...]  # furniture bodies
    fabric: tuple[Color, ...]  # beds, sofas, chairs
    accents: tuple[Color, ...]  # posters, rugs, clutter
    size_x: tuple[float, float] = (3.5, 7.0)
    size_y: tuple[float, float] = (3.0, 6.0)
    height: tuple[float, float] = (2.4, 3.0)
    wall_amp: float = 0.02  # faint wall noise
    wall_density: float = 50.0  # texels per metre of the low-texture surfaces
    detail_density: float = 220.0  # texels per metre of posters, books, rugs, tiles
    lights: tuple[int, int] = (2, 4)
    light_color: tuple[Color, ...] = ((1.0, 0.93, 0.82), (1.0, 1.0, 1.0), (0.92, 0.95, 1.0))
    ambient: float = 0.3  # indirect light relative to the mean direct irradiance
    posters: tuple[int, int] = (1, 3)
    rug_prob: float = 0.5
    window_prob: float = 0.5
    ceiling_kind: str = "flat"
    rich: bool = False  # every surface strongly textured
    vignetting: tuple[float, float] = (0.15, 0.3)
    noise: tuple[float, float] = (1.2, 2.2)  # sensor noise std in 8-bit levels at mid-grey
    exposure_jitter: float = 0.04  # relative exposure change between frames (slow random walk)


NYU = Style(
    name="nyu",
    walls=((0.86, 0.84, 0.78), (0.9, 0.88, 0.84), (0.8, 0.82, 0.8), (0.88, 0.82, 0.72), (0.78, 0.8, 0.84),
           (0.92, 0.91, 0.88), (0.84, 0.78, 0.7), (0.74, 0.78, 0.72)),
    floors=(("wood", (0.6, 0.45, 0.3), 0.08), ("wood", (0.72, 0.58, 0.42), 0.07),
            ("carpet", (0.55, 0.52, 0.48), 0.06), ("carpet", (0.45, 0.42, 0.4), 0.06),
            ("flat", (0.7, 0.68, 0.64), 0.03)),
    ceiling=(0.93, 0.93, 0.92),
    wood=((0.55, 0.4, 0.28), (0.75, 0.65, 0.5), (0.9, 0.9, 0.88), (0.35, 0.25, 0.18), (0.6, 0.6, 0.6)),
    fabric=((0.35, 0.4, 0.55), (0.7, 0.66, 0.6), (0.55, 0.3, 0.28), (0.4, 0.5, 0.4), (0.85, 0.85, 0.85)),
    accents=((0.85, 0.2, 0.15), (0.1, 0.35, 0.7), (0.95, 0.8, 0.2), (0.1, 0.55, 0.3), (0.95, 0.95, 0.95),
             (0.1, 0.1, 0.12), (0.9, 0.5, 0.1), (0.5, 0.2, 0.6)),
)

SEVENSCENES = Style(
    name="sevenscenes",
    walls=((0.25, 0.42, 0.45), (0.5, 0.22, 0.22), (0.35, 0.38, 0.5), (0.62, 0.5, 0.22), (0.4, 0.4, 0.42)),
    floors=(("carpet", (0.28, 0.32, 0.4), 0.16), ("carpet", (0.35, 0.35, 0.36), 0.18)),
    ceiling=(0.78, 0.78, 0.76),
    wood=((0.12, 0.12, 0.13), (0.45, 0.47, 0.5), (0.25, 0.2, 0.18)),
    fabric=((0.15, 0.15, 0.2), (0.5, 0.1, 0.1), (0.2, 0.3, 0.25)),
    accents=((0.95, 0.55, 0.1), (0.2, 0.7, 0.9), (0.9, 0.9, 0.2), (0.95, 0.95, 0.95), (0.8, 0.1, 0.3),
             (0.3, 0.8, 0.4)),
    size_x=(4.0, 7.0), size_y=(3.5, 6.0), height=(2.5, 2.9), wall_amp=0.03, lights=(2, 3),
    light_color=((1.0, 0.85, 0.65), (1.0, 0.9, 0.75)), ambient=0.2, posters=(0, 2), rug_prob=0.0,
    window_prob=0.2, ceiling_kind="tiles", vignetting=(0.3, 0.45), noise=(1.8, 2.8),
)

CAMPUS = Style(
    name="campus",
    walls=((0.93, 0.93, 0.9), (0.9, 0.88, 0.8), (0.85, 0.88, 0.9)),
    floors=(("flat", (0.6, 0.6, 0.58), 0.05), ("flat", (0.55, 0.5, 0.45), 0.05),
            ("carpet", (0.4, 0.42, 0.45), 0.05)),
    ceiling=(0.95, 0.95, 0.95),
    wood=((0.7, 0.55, 0.38), (0.6, 0.62, 0.66), (0.3, 0.45, 0.6)),
    fabric=((0.2, 0.25, 0.35), (0.55, 0.1, 0.1)),
    accents=((0.85, 0.2, 0.15), (0.1, 0.35, 0.7), (0.95, 0.8, 0.2), (0.95, 0.95, 0.95), (0.1, 0.1, 0.12)),
    size_x=(2.6, 3.6), size_y=(6.0, 8.0), height=(2.7, 3.3), wall_amp=0.015, lights=(3, 4),
    light_color=((0.95, 0.98, 1.0),), ambient=0.35, posters=(2, 4), rug_prob=0.0, window_prob=0.5,
    vignetting=(0.08, 0.18), noise=(1.0, 1.8),
)

ANIMATED = Style(name="animated", walls=((0.7, 0.6, 0.5),), floors=(("rich", (0.5, 0.5, 0.5), 0.0),),
                 ceiling=(0.6, 0.6, 0.6), wood=((0.5, 0.5, 0.5),), fabric=((0.5, 0.5, 0.5),),
                 accents=((0.5, 0.5, 0.5),), size_x=(5.0, 8.0), size_y=(5.0, 8.0), height=(2.8, 3.6),
                 wall_density=80.0, detail_density=80.0, lights=(2, 4), ambient=0.35, posters=(0, 0),
                 rug_prob=0.0, window_prob=0.0, rich=True, vignetting=(0.1, 0.2), noise=(0.5, 1.0))

STYLES = {s.name: s for s in (NYU, SEVENSCENES, CAMPUS, ANIMATED)}
