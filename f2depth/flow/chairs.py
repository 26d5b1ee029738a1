"""FlyingChairs-style training pairs with exact optical flow, generated on the fly (Dosovitskiy et al.,
"FlowNet", ICCV 2015, §4: textured foreground objects moving over a textured background, each layer with
its own affine motion).

A pair is a background and 1–4 foreground shapes (ellipse, star polygon, rectangle), each a *layer* with a
texture from a pool (procedural textures of :mod:`f2depth.synth.textures` plus crops of given images, e.g.
frames of the animated set) and its own affine motion from frame 1 to frame 2::

    x2 = c + t + s · R(θ) · (x1 − c)        c: the layer's centre, t: translation, s: scale, θ: rotation

(pixels of the output image, x first, pixel centres at integers). Later layers occlude earlier ones. Both
frames are rendered at ``supersample`` × the output size and area-downsampled, then quantised to 8 bits.
Ground truth is exact: at each output pixel centre of frame 1 the flow is ``x2 − x1`` of the topmost layer
there; the pixel is *occluded* when another layer covers ``x2`` in frame 2 or ``x2`` leaves the image.

Everything is drawn from a seeded ``numpy.random.Generator`` and rendered with ``torch.grid_sample``
(``float32``, CPU), so a seed gives the same pairs on every run. Shapes (see :func:`render_pairs`):
images ``(B,3,H,W)`` RGB in [0, 1] (sRGB, 8-bit steps), flow ``(B,2,H,W)`` pixels, x first, occluded
``(B,1,H,W)`` bool.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import torch
import torch.nn.functional as F

from f2depth.synth import textures as tx

SHAPES = ("ellipse", "star", "rectangle")
TEXTURE_MARGIN = 32  # px of the output image that a texture extends beyond each side of the image


@dataclass(frozen=True)
class ChairsSpec:
    """What the generated pairs look like (the ``flow_pretrain.chairs.data`` keys)."""

    height: int = field(metadata={"min": 16})
    width: int = field(metadata={"min": 16})
    max_shift: float = field(metadata={"min": 0})        # px: translation of every layer in ±max_shift (x, y)
    small_share: float = field(metadata={"min": 0, "max": 1})  # share of layers whose translation is ÷4
    rotation_deg: float = field(metadata={"min": 0})     # rotation in ±rotation_deg
    scale: float = field(metadata={"min": 0, "max": 0.5})  # scale in 1 ± scale
    min_shapes: int = field(metadata={"min": 0})          # foreground shapes per pair: min_shapes..max_shapes
    max_shapes: int = field(metadata={"min": 0})
    min_size: float = field(metadata={"gt": 0})           # shape radius as a share of min(H, W) ...
    max_size: float = field(metadata={"gt": 0})           # ... drawn in [min_size, max_size]
    supersample: int = field(metadata={"min": 1})         # rendered at this factor, area-downsampled
    textures: int = field(metadata={"min": 1})            # procedural textures in the pool
    image_crops: int = field(metadata={"min": 0})         # crops of the given images added to the pool

    def __post_init__(self) -> None:
        if self.max_shapes < self.min_shapes:
            raise ValueError(f"max_shapes = {self.max_shapes} must be >= min_shapes = {self.min_shapes}")
        if self.max_size < self.min_size:
            raise ValueError(f"max_size = {self.max_size} must be >= min_size = {self.min_size}")


def _srgb(linear: np.ndarray) -> np.ndarray:
    """Linear-light albedo → display values (gamma 1/2.2), float32 in [0, 1]."""
    return np.clip(linear, 0.0, 1.0).astype(np.float32) ** (1 / 2.2)


def _procedural(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    """One texture ``(h, w, 3)`` in display values: rich noise most of the time, else an indoor material."""
    kind = int(rng.integers(10))
    colour = tuple(float(v) for v in rng.uniform(0.15, 0.9, 3))
    if kind < 4:
        return _srgb(tx.rich(rng, h, w))
    makers = [lambda: tx.poster(rng, h, w),
              lambda: tx.tiles(rng, h, w, colour, tile_px=int(rng.integers(8, 40)), contrast=0.4),
              lambda: tx.bricks(rng, h, w, colour, brick_px=int(rng.integers(8, 24))),
              lambda: tx.rug(rng, h, w),
              lambda: tx.books(rng, h, w, colour, rows=int(rng.integers(2, 5))),
              lambda: tx.chessboard(rng, h, w, squares=int(rng.integers(4, 12))),
              lambda: tx.carpet(rng, h, w, colour, contrast=0.3) if rng.random() < 0.5
              else tx.wood(rng, h, w, colour, contrast=0.3)]
    return _srgb(makers[kind - 4]())


def _crop(rng: np.random.Generator, image: np.ndarray, h: int, w: int) -> np.ndarray:
    """A random crop (half to all of each side) of an RGB uint8 ``image (H, W, 3)``, resized to (h, w)."""
    ih, iw = image.shape[:2]
    ch, cw = int(ih * rng.uniform(0.5, 1.0)), int(iw * rng.uniform(0.5, 1.0))
    y, x = int(rng.integers(ih - ch + 1)), int(rng.integers(iw - cw + 1))
    crop = torch.from_numpy(np.ascontiguousarray(image[y:y + ch, x:x + cw])).permute(2, 0, 1)[None].float()
    crop = F.interpolate(crop / 255.0, size=(h, w), mode="bilinear", align_corners=False)
    return crop[0].permute(1, 2, 0).numpy()


def texture_pool(spec: ChairsSpec, rng: np.random.Generator, images: Sequence[np.ndarray] = ()
                 ) -> torch.Tensor:
    """The textures a generator draws from → ``(N,3,Ht,Wt)`` float32 in [0, 1], ``supersample`` texels per
    output pixel, covering the image plus :data:`TEXTURE_MARGIN` on each side. ``spec.textures`` procedural
    ones, then ``spec.image_crops`` crops of ``images`` (RGB uint8 ``(H, W, 3)``; none without images)."""
    s = spec.supersample
    h, w = s * (spec.height + 2 * TEXTURE_MARGIN), s * (spec.width + 2 * TEXTURE_MARGIN)
    pool = [_procedural(rng, h, w) for _ in range(spec.textures)]
    if images:
        pool += [_crop(rng, images[int(rng.integers(len(images)))], h, w) for _ in range(spec.image_crops)]
    return torch.from_numpy(np.stack(pool)).permute(0, 3, 1, 2).contiguous()


@dataclass(frozen=True)
class Layer:
    """One layer of one pair: its texture, shape (``kind``, ``radii`` of a star's vertices or the semi-axes
    of an ellipse or rectangle), placement (``centre`` px, ``angle`` of the texture and shape in frame 1) and
    motion (``shift`` px, ``rotation`` rad, ``scale``)."""

    texture: int
    kind: str                 # background | ellipse | star | rectangle
    radii: tuple[float, ...]
    centre: tuple[float, float]
    angle: float
    shift: tuple[float, float]
    rotation: float
    scale: float


def draw_layers(spec: ChairsSpec, rng: np.random.Generator, n_textures: int) -> list[Layer]:
    """The layers of one pair, background first."""
    h, w = spec.height, spec.width
    n = 1 + int(rng.integers(spec.min_shapes, spec.max_shapes + 1))
    layers = []
    for i in range(n):
        shift = rng.uniform(-spec.max_shift, spec.max_shift, 2)
        if rng.random() < spec.small_share:
            shift = shift / 4
        motion = {"shift": (float(shift[0]), float(shift[1])),
                  "rotation": math.radians(float(rng.uniform(-spec.rotation_deg, spec.rotation_deg))),
                  "scale": float(1 + rng.uniform(-spec.scale, spec.scale))}
        texture = int(rng.integers(n_textures))
        if i == 0:
            layers.append(Layer(texture, "background", (), ((w - 1) / 2, (h - 1) / 2), 0.0, **motion))
            continue
        kind = SHAPES[int(rng.integers(len(SHAPES)))]
        r = float(rng.uniform(spec.min_size, spec.max_size)) * min(h, w)
        if kind == "star":
            k = int(rng.integers(5, 10))
            inner = float(rng.uniform(0.35, 0.8))
            radii = tuple(r * (1.0 if j % 2 == 0 else inner) * float(rng.uniform(0.85, 1.0))
                          for j in range(2 * k))
        else:
            radii = (r, r * float(rng.uniform(0.45, 1.0)))
        centre = (float(rng.uniform(0, w - 1)), float(rng.uniform(0, h - 1)))
        layers.append(Layer(texture, kind, radii, centre, float(rng.uniform(-math.pi, math.pi)), **motion))
    return layers


def _rotation(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _translation(tx: float, ty: float) -> np.ndarray:
    return np.array([[1.0, 0.0, tx], [0.0, 1.0, ty], [0.0, 0.0, 1.0]])


def _scaling(f: float) -> np.ndarray:
    return np.diag([f, f, 1.0])


def layer_matrix(layer: Layer, frame: int) -> np.ndarray:
    """``(3,3)`` float64: homogeneous pixel positions of frame 1 or 2 (x first) → the layer's own
    coordinates (px, its centre at 0, rotated by its frame-1 angle). Frame 2 first undoes the motion."""
    cx, cy = layer.centre
    to_own = _rotation(-layer.angle) @ _translation(-cx, -cy)
    return to_own if frame == 1 else to_own @ np.linalg.inv(motion_matrix(layer))


def motion_matrix(layer: Layer) -> np.ndarray:
    """``(3,3)`` float64: homogeneous frame-1 positions → where the layer carries them in frame 2,
    x2 = c + t + s·R(θ)·(x1 − c)."""
    (cx, cy), (tx, ty) = layer.centre, layer.shift
    return (_translation(cx + tx, cy + ty) @ _scaling(layer.scale) @ _rotation(layer.rotation)
            @ _translation(-cx, -cy))


def _apply(m: np.ndarray, points: torch.Tensor) -> torch.Tensor:
    """The affine ``m (3,3)`` applied to positions ``points (...,2)``, x first."""
    (a, b, c), (d, e, f) = m[:2].tolist()  # Python floats: no tensor made of each numpy scalar
    x, y = points[..., 0], points[..., 1]
    return torch.stack([a * x + b * y + c, d * x + e * y + f], -1)


def to_layer(layer: Layer, points: torch.Tensor, frame: int) -> torch.Tensor:
    """Pixel positions ``points (...,2)`` (x first) of frame 1 or 2 → the layer's coordinates ``(...,2)``."""
    return _apply(layer_matrix(layer, frame), points)


def move(layer: Layer, points: torch.Tensor) -> torch.Tensor:
    """Frame-1 positions ``points (...,2)`` → where the layer carries them in frame 2."""
    return _apply(motion_matrix(layer), points)


def inside(layer: Layer, u: torch.Tensor) -> torch.Tensor:
    """Layer coordinates ``u (...,2)`` → bool ``(...)``: inside the layer's shape."""
    if layer.kind == "background":
        return torch.ones(u.shape[:-1], dtype=torch.bool)
    x, y = u[..., 0], u[..., 1]
    if layer.kind == "ellipse":
        a, b = layer.radii
        return (x / a) ** 2 + (y / b) ** 2 <= 1
    if layer.kind == "rectangle":
        a, b = layer.radii
        return (x.abs() <= a) & (y.abs() <= b)
    radii = torch.tensor(layer.radii + layer.radii[:1], dtype=torch.float32)  # star: radius linear in angle
    k = len(layer.radii)
    t = (torch.atan2(y, x) % (2 * math.pi)) / (2 * math.pi) * k
    j = t.floor().long().clamp(max=k - 1)
    frac = t - j
    bound = radii.take(j) * (1 - frac) + radii.take(j + 1) * frac
    return x.hypot(y) <= bound


def _centres(h: int, w: int, supersample: int) -> torch.Tensor:
    """Output-pixel positions ``(h·s, w·s, 2)`` (x first) of the centres of the ``s×s`` sub-pixels."""
    s = supersample
    ys = (torch.arange(h * s, dtype=torch.float32) + 0.5) / s - 0.5
    xs = (torch.arange(w * s, dtype=torch.float32) + 0.5) / s - 0.5
    gy, gx = torch.meshgrid(ys, xs, indexing="ij")
    return torch.stack([gx, gy], -1)


def _texture_theta(m: np.ndarray, image_hw: tuple[int, int], texture_hw: tuple[int, int], texels_per_px: int
                   ) -> np.ndarray:
    """``affine_grid``'s ``(2,3)`` (``align_corners=False``) for the layer matrix ``m``: normalised render
    coordinates → normalised texture coordinates (the layer's centre at the texture's centre)."""
    (h, w), (ht, wt) = image_hw, texture_hw
    from_render = np.array([[w / 2, 0.0, w / 2 - 0.5], [0.0, h / 2, h / 2 - 0.5], [0.0, 0.0, 1.0]])
    to_texels = np.array([[texels_per_px, 0.0, (wt - 1) / 2], [0.0, texels_per_px, (ht - 1) / 2],
                          [0.0, 0.0, 1.0]])
    to_normalised = np.array([[2 / wt, 0.0, 1 / wt - 1], [0.0, 2 / ht, 1 / ht - 1], [0.0, 0.0, 1.0]])
    return (to_normalised @ to_texels @ m @ from_render)[:2]


def _labels(layers: Sequence[Layer], points: torch.Tensor, frame: int) -> torch.Tensor:
    """Index of the topmost layer at each position ``points (...,2)`` of a frame → ``(...)`` long."""
    top = torch.zeros(points.shape[:-1], dtype=torch.long)
    for i, layer in enumerate(layers[1:], 1):
        top[inside(layer, to_layer(layer, points, frame))] = i
    return top


def render_frames(spec: ChairsSpec, pool: torch.Tensor, scenes: Sequence[Sequence[Layer]]) -> torch.Tensor:
    """Frames 1 and 2 of every pair → ``(n,2,3,H,W)`` in [0, 1], 8-bit steps, rendered at ``supersample`` ×
    the size and area-downsampled. Every layer of every pair and frame is placed by one ``affine_grid``;
    each position is then sampled (``grid_sample``, bilinear) once, in the texture of its topmost layer
    only: a texture is read in place, never copied, and hidden positions are never sampled."""
    if any(not layers or layers[0].kind != "background" for layers in scenes):
        raise ValueError("render_frames: every pair's first layer must be its background (draw_layers)")
    h, w, s = spec.height, spec.width, spec.supersample
    texture_hw = tuple(pool.shape[-2:])
    jobs = [(p, frame, layer) for p, layers in enumerate(scenes) for frame in (1, 2) for layer in layers]
    mats = [layer_matrix(layer, frame) for _, frame, layer in jobs]
    theta = torch.from_numpy(np.stack([_texture_theta(m, (h, w), texture_hw, s) for m in mats])).float()
    grid = F.affine_grid(theta, [len(jobs), 3, h * s, w * s], align_corners=False)
    texels = torch.tensor([texture_hw[1], texture_hw[0]])
    top = torch.empty(len(scenes) * 2, h * s, w * s, dtype=torch.long)  # the job seen at each position
    for j, (p, frame, layer) in enumerate(jobs):
        if layer.kind == "background":
            top[2 * p + frame - 1] = j
        else:
            own = grid[j] * texels / (2 * s)  # the layer's coordinates, px
            top[2 * p + frame - 1][inside(layer, own)] = j
    out = torch.empty(len(scenes) * 2, 3, h * s * w * s)
    top, grid = top.flatten(1), grid.flatten(1, 2)
    for j, (p, frame, layer) in enumerate(jobs):
        f = 2 * p + frame - 1
        seen = (top[f] == j).nonzero()[:, 0]
        if len(seen):
            where = grid[j].index_select(0, seen)[None, None]
            colour = F.grid_sample(pool[layer.texture:layer.texture + 1], where, mode="bilinear",
                                   padding_mode="reflection", align_corners=False)
            out[f].index_copy_(1, seen, colour[0, :, 0])
    out = out.unflatten(2, (h * s, w * s))
    if s > 1:
        out = F.avg_pool2d(out, s)
    return ((out.clamp(0, 1) * 255).round() / 255).unflatten(0, (len(scenes), 2))


def flow_truth(spec: ChairsSpec, layers: Sequence[Layer]) -> tuple[torch.Tensor, torch.Tensor]:
    """Exact flow ``(2,H,W)`` px (frame 1 → 2) and occlusion ``(1,H,W)`` bool at the output pixel centres:
    the motion of the topmost layer of frame 1; occluded where frame 2's topmost layer at the moved
    position is another one or the position leaves the image."""
    h, w = spec.height, spec.width
    x1 = _centres(h, w, 1)
    top1 = _labels(layers, x1, 1)
    x2 = torch.zeros_like(x1)
    for i, layer in enumerate(layers):
        x2 = torch.where((top1 == i)[..., None], move(layer, x1), x2)
    top2 = _labels(layers, x2, 2)
    leaves = (x2[..., 0] < -0.5) | (x2[..., 0] > w - 0.5) | (x2[..., 1] < -0.5) | (x2[..., 1] > h - 0.5)
    return (x2 - x1).permute(2, 0, 1), ((top2 != top1) | leaves)[None]


def render_pairs(spec: ChairsSpec, pool: torch.Tensor, rng: np.random.Generator, n: int,
                 part: slice = slice(None)) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """``n`` new pairs → ``img1, img2 (n,3,H,W)`` in [0, 1], ``flow (n,2,H,W)`` px x first (frame 1 → 2),
    ``occluded (n,1,H,W)`` bool. ``pool``: :func:`texture_pool`'s ``(N,3,Ht,Wt)``. ``part``: render only
    these of the ``n`` pairs drawn (a data-parallel rank's share; ``rng`` moves on as for all ``n``)."""
    scenes = [draw_layers(spec, rng, len(pool)) for _ in range(n)][part]
    frames = render_frames(spec, pool, scenes)
    flow, occluded = zip(*(flow_truth(spec, layers) for layers in scenes))
    return frames[:, 0], frames[:, 1], torch.stack(flow), torch.stack(occluded)
