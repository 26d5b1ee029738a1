"""Scene description: an axis-aligned box room, furniture boxes, point lights, and the baked texture atlas.

World frame: metres, z up, the room spans ``[room.lo, room.hi]`` with the floor at z = 0.
Every surface is one face of an axis-aligned box. Face index ``f`` in 0..5 is ``(axis, side) =
(f // 2, f % 2)``: side 0 is the plane ``x_axis = lo[axis]``, side 1 the plane ``x_axis = hi[axis]``.
Room faces are seen from inside, furniture faces from outside.

Because the world is static and Lambertian, each surface's outgoing radiance (albedo × irradiance from
point lights plus an ambient term, or a constant emission for lamps and windows) is baked once into a
texel grid; all texel grids are concatenated into one flat ``atlas`` (T, 3) so that shading a ray is a
bilinear lookup ``atlas[offset[s] + y * width[s] + x]`` regardless of which surface it hit (the atlas is
kept as three contiguous colour planes, which NumPy gathers fastest).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from f2depth.synth import textures as tx

#: texture side limit in texels (huge faces get a lower density)
MAX_TEXELS_SIDE = 2048
#: material kinds whose texture has detail at pixel scale
DETAIL_KINDS = frozenset({"poster", "books", "rug", "tiles", "bricks", "chess", "rich"})


@dataclass(frozen=True)
class Material:
    """How a face looks. ``kind`` selects a generator in :mod:`f2depth.synth.textures`.

    ``color`` is sRGB in [0, 1]; ``density`` texels per metre; ``amp`` the contrast of the low-texture
    kinds; ``size`` the tile/brick size in metres or the number of shelf rows for ``books``;
    ``strength`` the radiance of ``emissive`` faces; ``palette`` colours for posters and rugs.
    """

    kind: str = "flat"
    color: tx.Color = (0.8, 0.8, 0.8)
    density: float = 60.0
    amp: float = 0.025
    size: float = 0.0
    strength: float = 0.0
    palette: tuple[tx.Color, ...] = ()


@dataclass(frozen=True)
class Box:
    """Axis-aligned box ``lo`` … ``hi`` (metres) with one :class:`Material` per face (index order above)."""

    lo: tuple[float, float, float]
    hi: tuple[float, float, float]
    materials: tuple[Material, ...]
    label: str = ""
    obstacle: bool = True  # blocks the camera path (rugs, posters and lamps do not)


@dataclass(frozen=True)
class Light:
    position: tuple[float, float, float]
    power: tuple[float, float, float]  # linear RGB intensity (irradiance × m² at normal incidence)


@dataclass
class Scene:
    """A baked scene, ready for :func:`f2depth.synth.render.render`."""

    name: str
    room_lo: np.ndarray  # (3,) float64
    room_hi: np.ndarray  # (3,)
    box_lo: np.ndarray  # (B, 3) float64
    box_hi: np.ndarray  # (B, 3)
    room_surface: np.ndarray  # (6,) int32 surface id of each room face
    box_surface: np.ndarray  # (B, 6) int32
    obstacles: np.ndarray  # (M, 4) float64 footprints xmin, ymin, xmax, ymax of obstacle boxes
    # surface table (S,): texel coordinates of a world point p are
    # x = A[0] p_x + A[1] p_y + A[2] p_z + A[3],  y = A[4] p_x + A[5] p_y + A[6] p_z + A[7]
    tex_affine: np.ndarray  # (8, S) float32
    offset: np.ndarray  # (S,) int64 start of the surface's texels in the atlas
    tex_w: np.ndarray  # (S,) int32
    tex_h: np.ndarray  # (S,) int32
    detail: np.ndarray  # (S,) bool: texture has texel-scale detail (anti-alias where it is minified)
    density: np.ndarray  # (S,) float32 texels per metre (the finer of the two axes)
    atlas_planes: tuple[np.ndarray, np.ndarray, np.ndarray]  # R, G, B planes (T,) float32 linear radiance
    exposure: float = 1.0  # scale that brings the room's typical radiance to mid-grey
    info: dict = field(default_factory=dict)


def _face_frame(face: int, inside: bool):
    """Visible normal and the signed in-plane texture axes of a face.

    Returns (normal (3,), (u_axis, u_sign), (v_axis, v_sign)); texture x grows along ``u_sign * e_u``,
    texture y along ``v_sign * e_v`` (downwards on walls, so posters stand upright).
    """
    axis, side = divmod(face, 2)
    outward = 1.0 if side == 1 else -1.0
    normal = np.zeros(3)
    normal[axis] = -outward if inside else outward
    if axis == 2:
        return normal, (0, 1.0), (1, -1.0 if normal[2] > 0 else 1.0)
    right = np.cross(-normal, np.array([0.0, 0.0, 1.0]))
    u_axis = int(np.argmax(np.abs(right)))
    return normal, (u_axis, float(np.sign(right[u_axis]))), (2, -1.0)


def _occlusion(pts: np.ndarray, normal: np.ndarray, inside: bool, room_hi: np.ndarray, boxes: list[Box]):
    """Ambient-occlusion-like darkening (h, w) in (0, 1] of surface points ``pts`` (h, w, 3): contact
    shadows where furniture meets the floor or stands at a wall, soft shadow under tables and beds,
    darker room corners and furniture feet. A cheap stand-in for global illumination."""
    z = pts[..., 2]
    ao = np.ones(pts.shape[:2])
    if normal[2] == 0:  # vertical faces darken towards the floor
        ao *= 1.0 - 0.3 * np.exp(-z / 0.12)
    if not inside:
        return ao
    hi = room_hi
    if normal[2] == 0:
        ao *= 1.0 - 0.15 * np.exp(-(hi[2] - z) / 0.15)
        along = 1 if normal[0] != 0 else 0  # the horizontal in-plane axis
        c = pts[..., along]
        ao *= 1.0 - 0.2 * np.exp(-np.minimum(c, hi[along] - c) / 0.15)
    else:
        edge = np.minimum(np.minimum(pts[..., 0], hi[0] - pts[..., 0]),
                          np.minimum(pts[..., 1], hi[1] - pts[..., 1]))
        ao *= 1.0 - 0.2 * np.exp(-edge / 0.15)
    for box in boxes:
        lo_b, hi_b = np.asarray(box.lo), np.asarray(box.hi)
        if not box.obstacle or normal[2] < 0 or lo_b[2] > 1.5:  # only furniture casts these shadows
            continue
        if normal[2] > 0:  # floor: distance to the footprint, weaker for raised boxes
            dx = np.maximum(np.maximum(lo_b[0] - pts[..., 0], pts[..., 0] - hi_b[0]), 0.0)
            dy = np.maximum(np.maximum(lo_b[1] - pts[..., 1], pts[..., 1] - hi_b[1]), 0.0)
            ao *= 1.0 - 0.45 * np.exp(-np.hypot(dx, dy) / 0.12 - lo_b[2] / 0.5)
        else:  # a wall: boxes standing close to it
            a = 0 if normal[0] != 0 else 1
            plane = pts[0, 0, a]
            gap = max(lo_b[a] - plane, plane - hi_b[a], 0.0)
            if gap > 0.3:
                continue
            b = 1 - a
            du = np.maximum(np.maximum(lo_b[b] - pts[..., b], pts[..., b] - hi_b[b]), 0.0)
            dz = np.maximum(np.maximum(lo_b[2] - z, z - hi_b[2]), 0.0)
            ao *= 1.0 - 0.35 * np.exp(-np.hypot(du, dz) / 0.1 - gap / 0.1)
    return ao


def _texture(mat: Material, rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    k = mat.kind
    if k == "flat":
        return tx.flat(rng, h, w, mat.color, mat.amp)
    if k == "wood":
        return tx.wood(rng, h, w, mat.color, mat.amp)
    if k == "carpet":
        return tx.carpet(rng, h, w, mat.color, mat.amp)
    if k == "tiles":
        return tx.tiles(rng, h, w, mat.color, int(round(mat.size * mat.density)), mat.amp)
    if k == "bricks":
        return tx.bricks(rng, h, w, mat.color, int(round(mat.size * mat.density)))
    if k == "poster":
        return tx.poster(rng, h, w, list(mat.palette) or None)
    if k == "books":
        return tx.books(rng, h, w, mat.color, int(mat.size) or 4)
    if k == "rug":
        return tx.rug(rng, h, w, list(mat.palette) or None)
    if k == "chess":
        return tx.chessboard(rng, h, w)
    if k == "screen":
        return tx.screen(rng, h, w)
    if k == "rich":
        return tx.rich(rng, h, w)
    if k == "emissive":
        return tx.emissive(h, w, mat.color, mat.strength)
    raise ValueError(f"unknown material kind {k!r}")


def _irradiance(pts: np.ndarray, normal: np.ndarray, positions: np.ndarray, powers: np.ndarray,
                ambient: float, softness: float) -> np.ndarray:
    """Lambertian irradiance (h,w,3) at surface points ``pts`` (h,w,3) m with unit ``normal`` from point
    lights at ``positions`` (L,3) m of ``powers`` (L,3), each fall-off softened by ``softness`` m, plus
    ``ambient`` (occlusion left to the caller)."""
    irr = np.full(pts.shape[:2] + (3,), ambient, np.float64)
    for lp, li in zip(positions, powers):
        d = lp - pts
        dist2 = np.einsum("hwc,hwc->hw", d, d)
        cos = np.maximum(d @ normal, 0.0) / np.sqrt(dist2)
        irr += (cos / (dist2 + softness**2))[..., None] * li
    return irr


def _scene(name: str, room: Box, boxes: list[Box], n_lights: int, tables: dict[str, list],
           surface_ids: np.ndarray, chunks: list[np.ndarray], room_samples: list[np.ndarray],
           target_grey: float) -> Scene:
    """The baked faces (``bake``'s texel tables and radiance chunks) as a Scene with its exposure."""
    atlas = np.concatenate(chunks).astype(np.float32)
    lum = np.concatenate(room_samples).mean(axis=1)
    # mid-grey for the typical wall/floor, but keep the brightest 2 % below the tone curve's shoulder
    exposure = min(target_grey / max(float(np.median(lum)), 1e-6),
                   0.75 / max(float(np.quantile(lum, 0.98)), 1e-6))
    obstacles = np.array([[b.lo[0], b.lo[1], b.hi[0], b.hi[1]] for b in boxes if b.obstacle],
                         np.float64).reshape(-1, 4)
    return Scene(name=name, room_lo=np.asarray(room.lo, np.float64), room_hi=np.asarray(room.hi, np.float64),
                 box_lo=np.array([b.lo for b in boxes], np.float64).reshape(-1, 3),
                 box_hi=np.array([b.hi for b in boxes], np.float64).reshape(-1, 3),
                 room_surface=surface_ids[0].copy(), box_surface=surface_ids[1:].copy(), obstacles=obstacles,
                 tex_affine=np.array(tables["affine"], np.float32).T.copy(),
                 offset=np.array(tables["offset"], np.int64), tex_w=np.array(tables["tex_w"], np.int32),
                 tex_h=np.array(tables["tex_h"], np.int32), detail=np.array(tables["detail"], bool),
                 density=np.array(tables["density"], np.float32),
                 atlas_planes=tuple(np.ascontiguousarray(atlas[:, c]) for c in range(3)), exposure=exposure,
                 info={"boxes": [b.label for b in boxes], "lights": n_lights})


def bake(name: str, room: Box, boxes: list[Box], lights: list[Light], ambient: float,
         rng: np.random.Generator, target_grey: float = 0.18, softness: float = 0.7) -> Scene:
    """Generate every face texture, bake Lambertian lighting into it and build the atlas.

    ``ambient`` is the indirect irradiance (same units as the lights' power / m²). ``target_grey`` is the
    linear radiance the room's median wall/floor texel is exposed to. ``softness`` (m) is added to the light
    distance in the inverse-square fall-off, as for a lamp of that size: a soft glow, not a hot spot.
    """
    all_boxes = [room, *boxes]
    lights_p = np.array([lt.position for lt in lights], np.float64).reshape(-1, 3)
    lights_i = np.array([lt.power for lt in lights], np.float64).reshape(-1, 3)
    tables: dict[str, list] = {k: [] for k in ("tex_w", "tex_h", "affine", "offset", "detail", "density")}
    chunks: list[np.ndarray] = []
    room_samples: list[np.ndarray] = []
    surface_ids = np.zeros((len(all_boxes), 6), np.int32)
    offset = 0
    for b, box in enumerate(all_boxes):
        lo, hi = np.asarray(box.lo, np.float64), np.asarray(box.hi, np.float64)
        if np.any(hi <= lo):
            raise ValueError(f"box {box.label!r} of scene {name} has non-positive size: {lo} .. {hi}")
        inside = b == 0
        for f in range(6):
            mat = box.materials[f]
            normal, (ua, us), (va, vs) = _face_frame(f, inside)
            ext_u, ext_v = hi[ua] - lo[ua], hi[va] - lo[va]
            tw = int(np.clip(np.ceil(ext_u * mat.density), 2, MAX_TEXELS_SIDE))
            th = int(np.clip(np.ceil(ext_v * mat.density), 2, MAX_TEXELS_SIDE))
            su, sv = tw / ext_u, th / ext_v
            # texel coordinate with centres at integers: x = (us * p_u - min(us * p_u)) * su - 0.5
            min_u = lo[ua] if us > 0 else -hi[ua]
            min_v = lo[va] if vs > 0 else -hi[va]
            albedo = _texture(mat, rng, th, tw)
            if mat.kind == "emissive":
                radiance = albedo
            else:
                # lighting is smooth: evaluate it on a grid 4× coarser than the texels and interpolate
                cw, ch = max(2, -(-tw // 4)), max(2, -(-th // 4))
                xs = (((np.arange(cw) + 0.5) * tw / cw) / su + min_u) * us
                ys = (((np.arange(ch) + 0.5) * th / ch) / sv + min_v) * vs
                pts = np.zeros((ch, cw, 3))
                pts[..., ua] = xs[None, :]
                pts[..., va] = ys[:, None]
                axis, side = divmod(f, 2)
                pts[..., axis] = hi[axis] if side else lo[axis]
                irr = _irradiance(pts, normal, lights_p, lights_i, ambient, softness)
                irr *= _occlusion(pts, normal, inside, np.asarray(room.hi, np.float64), boxes)[..., None]
                irr = cv2.resize(irr.astype(np.float32), (tw, th), interpolation=cv2.INTER_LINEAR)
                radiance = (albedo * irr).astype(np.float32)
                if inside and f != 5:  # walls and floor set the exposure
                    room_samples.append(radiance[::4, ::4].reshape(-1, 3))
            surface_ids[b, f] = len(tables["offset"])
            affine = np.zeros(8)  # texel x = affine[:3]·p + affine[3], y = affine[4:7]·p + affine[7]
            affine[ua], affine[3] = us * su, -min_u * su - 0.5
            affine[4 + va], affine[7] = vs * sv, -min_v * sv - 0.5
            for key, value in (("offset", offset), ("tex_w", tw), ("tex_h", th), ("affine", affine),
                               ("detail", mat.kind in DETAIL_KINDS), ("density", max(su, sv))):
                tables[key].append(value)
            chunks.append(radiance.reshape(-1, 3))
            offset += tw * th
    return _scene(name, room, boxes, len(lights), tables, surface_ids, chunks, room_samples, target_grey)
