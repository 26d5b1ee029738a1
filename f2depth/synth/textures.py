"""Procedural albedo textures, generated once per surface from a seeded ``numpy.random.Generator``.

Every generator takes ``(rng, h, w, ...)`` and returns a linear-light albedo image ``(h, w, 3)`` float32
in [0, 1] (colours are given in sRGB and converted). Texture row 0 is the top of the surface as seen by a
viewer, column 0 its left edge. ``h`` and ``w`` are texel counts (surface size × texel density).
"""

from __future__ import annotations

import cv2
import numpy as np

Color = tuple[float, float, float]


def srgb_to_linear(c: np.ndarray | Color) -> np.ndarray:
    """sRGB in [0, 1] → linear light (exact sRGB curve)."""
    c = np.clip(np.asarray(c, dtype=np.float32), 0.0, 1.0)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4).astype(np.float32)


def value_noise(rng: np.random.Generator, h: int, w: int, cells: float) -> np.ndarray:
    """Smooth noise (h, w) float32 with zero mean and unit-ish amplitude; ``cells`` features across the
    larger side (bicubic interpolation of a random grid)."""
    n = max(h, w)
    gh = max(2, int(np.ceil(cells * h / n)) + 2)
    gw = max(2, int(np.ceil(cells * w / n)) + 2)
    grid = rng.standard_normal((gh, gw)).astype(np.float32)
    return cv2.resize(grid, (w, h), interpolation=cv2.INTER_CUBIC)


def fractal_noise(rng: np.random.Generator, h: int, w: int, base_cells: float,
                  octaves: int = 4) -> np.ndarray:
    """Sum of ``octaves`` value-noise layers, each twice the frequency and half the amplitude."""
    out = np.zeros((h, w), np.float32)
    amp, total = 1.0, 0.0
    for o in range(octaves):
        cells = min(base_cells * 2**o, max(h, w) / 2)
        out += amp * value_noise(rng, h, w, cells)
        total += amp
        amp *= 0.5
    return out / total


def _tint(gray: np.ndarray, color: Color) -> np.ndarray:
    """Modulate a linear colour by a (h, w) factor around 1."""
    return np.clip(gray[..., None] * srgb_to_linear(color)[None, None, :], 0.0, 1.0).astype(np.float32)


def flat(rng: np.random.Generator, h: int, w: int, color: Color, amp: float = 0.025) -> np.ndarray:
    """Painted wall / ceiling: a flat colour with faint low-frequency blotches and fine grain."""
    blot = fractal_noise(rng, h, w, base_cells=max(2.0, max(h, w) / 60.0), octaves=3)
    grain = rng.standard_normal((h, w)).astype(np.float32)
    grain = cv2.GaussianBlur(grain, (0, 0), 0.7)
    return _tint(1.0 + amp * blot + 0.3 * amp * grain, color)


def wood(rng: np.random.Generator, h: int, w: int, color: Color, contrast: float = 0.08) -> np.ndarray:
    """Low-contrast wood grain running along the longer side."""
    long_h = h >= w
    gh, gw = (h, max(2, w // 8)) if long_h else (max(2, h // 8), w)
    streaks = fractal_noise(rng, gh, gw, base_cells=max(4.0, max(gh, gw) / 12.0), octaves=3)
    streaks = cv2.resize(streaks, (w, h), interpolation=cv2.INTER_LINEAR)
    blot = value_noise(rng, h, w, cells=3.0)
    return _tint(1.0 + contrast * streaks + 0.5 * contrast * blot, color)


def carpet(rng: np.random.Generator, h: int, w: int, color: Color, contrast: float = 0.08) -> np.ndarray:
    """Carpet / lino: speckle plus faint blotches."""
    speck = rng.standard_normal((h, w)).astype(np.float32)
    speck = cv2.GaussianBlur(speck, (0, 0), 0.8)
    blot = fractal_noise(rng, h, w, base_cells=4.0, octaves=3)
    return _tint(1.0 + contrast * speck + 0.6 * contrast * blot, color)


def tiles(rng: np.random.Generator, h: int, w: int, color: Color, tile_px: int,
          contrast: float = 0.25) -> np.ndarray:
    """Tiles of ``tile_px`` texels with per-tile shade variations and dark grout lines."""
    tile_px = max(4, int(tile_px))
    ny, nx = h // tile_px + 2, w // tile_px + 2
    shade = 1.0 + contrast * rng.uniform(-1.0, 1.0, (ny, nx)).astype(np.float32)
    shade = np.repeat(np.repeat(shade, tile_px, 0), tile_px, 1)[:h, :w]
    yy, xx = np.mgrid[0:h, 0:w]
    grout = ((yy % tile_px) < max(1, tile_px // 12)) | ((xx % tile_px) < max(1, tile_px // 12))
    img = _tint(shade, color)
    img[grout] *= 0.45
    return img + 0.02 * _tint(value_noise(rng, h, w, 6.0), color)


def _palette_color(rng: np.random.Generator, palette: list[Color] | None) -> Color:
    if palette:
        return palette[int(rng.integers(len(palette)))]
    return tuple(float(v) for v in rng.uniform(0.05, 0.95, 3))


def poster(rng: np.random.Generator, h: int, w: int, palette: list[Color] | None = None) -> np.ndarray:
    """A poster or framed picture: bold shapes, stripes and lines of 'text' on a coloured ground."""
    img = np.zeros((h, w, 3), np.float32)
    img[:] = _palette_color(rng, palette)
    s = max(h, w)
    for _ in range(int(rng.integers(4, 10))):
        col = tuple(float(v) for v in _palette_color(rng, palette))
        kind = int(rng.integers(4))
        if kind == 0:
            c = (int(rng.integers(w)), int(rng.integers(h)))
            cv2.circle(img, c, int(rng.uniform(0.05, 0.3) * s), col, -1, cv2.LINE_AA)
        elif kind == 1:
            p = (int(rng.integers(w)), int(rng.integers(h)))
            q = (p[0] + int(rng.uniform(0.1, 0.5) * w), p[1] + int(rng.uniform(0.1, 0.5) * h))
            cv2.rectangle(img, p, q, col, -1, cv2.LINE_AA)
        elif kind == 2:
            pts = rng.integers(0, [w, h], size=(3, 2)).astype(np.int32)
            cv2.fillPoly(img, [pts], col, cv2.LINE_AA)
        else:
            y0 = int(rng.integers(h))
            for k in range(int(rng.integers(2, 6))):
                y = y0 + k * max(3, h // 25)
                x0 = int(rng.uniform(0.05, 0.2) * w)
                cv2.line(img, (x0, y), (x0 + int(rng.uniform(0.3, 0.7) * w), y), col, max(1, h // 60))
    border = max(1, s // 40)
    cv2.rectangle(img, (0, 0), (w - 1, h - 1), (0.05, 0.05, 0.05), border)
    return srgb_to_linear(img)


def books(rng: np.random.Generator, h: int, w: int, wood_color: Color, rows: int) -> np.ndarray:
    """Front of a book shelf: ``rows`` wooden boards with book spines of random width, height and colour."""
    img = np.empty((h, w, 3), np.float32)
    img[:] = wood_color
    n_rows = max(1, int(rows))
    row_h = h / n_rows
    board = max(1, int(0.08 * row_h))
    for r in range(n_rows):
        top, bottom = int(r * row_h) + board, int((r + 1) * row_h)
        x = int(rng.integers(0, max(1, w // 20) + 1))
        while x < w - 2:
            bw = int(rng.uniform(0.015, 0.05) * w) + 1
            if rng.random() < 0.08:  # a gap
                x += bw * 2
                continue
            bh = int((bottom - top) * rng.uniform(0.6, 0.97))
            col = tuple(float(v) for v in rng.uniform(0.05, 0.9, 3))
            img[bottom - bh : bottom, x : min(w, x + bw)] = col
            if bw > 3 and rng.random() < 0.5:  # a label band on the spine
                y = bottom - bh + int(bh * rng.uniform(0.15, 0.7))
                img[y : y + max(1, bh // 12), x + 1 : min(w, x + bw - 1)] = rng.uniform(0.6, 1.0)
            x += bw
    img = srgb_to_linear(img)
    shade = 1.0 + 0.05 * value_noise(rng, h, w, 20.0)
    return np.clip(img * shade[..., None], 0, 1).astype(np.float32)


def rug(rng: np.random.Generator, h: int, w: int, palette: list[Color] | None = None) -> np.ndarray:
    """A patterned rug: border bands, stripes or diamonds, and woven speckle."""
    base, alt, edge = (_palette_color(rng, palette) for _ in range(3))
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    period = rng.uniform(0.08, 0.2) * min(h, w)
    if rng.random() < 0.5:
        pattern = (np.abs(xx - w / 2) + np.abs(yy - h / 2)) % period < period / 2
    else:
        pattern = (xx + rng.uniform(-0.5, 0.5) * yy) % period < period / 2
    img = np.where(pattern[..., None], np.float32(base), np.float32(alt)).astype(np.float32)
    b = max(2, int(0.08 * min(h, w)))
    img[:b] = img[-b:] = edge
    img[:, :b] = img[:, -b:] = edge
    img = srgb_to_linear(img)
    speck = 1.0 + 0.12 * cv2.GaussianBlur(rng.standard_normal((h, w)).astype(np.float32), (0, 0), 0.6)
    return np.clip(img * speck[..., None], 0, 1).astype(np.float32)


def chessboard(rng: np.random.Generator, h: int, w: int, squares: int = 8) -> np.ndarray:
    """A chess board with a wooden rim."""
    yy, xx = np.mgrid[0:h, 0:w]
    cell = min(h, w) / (squares + 1)
    rim = cell / 2
    inside = (yy >= rim) & (yy < h - rim) & (xx >= rim) & (xx < w - rim)
    dark = (((yy - rim) // cell + (xx - rim) // cell) % 2).astype(bool)
    img = np.empty((h, w, 3), np.float32)
    img[:] = (0.45, 0.28, 0.15)
    img[inside & dark] = (0.12, 0.08, 0.06)
    img[inside & ~dark] = (0.88, 0.82, 0.7)
    img = srgb_to_linear(img)
    return np.clip(img * (1.0 + 0.04 * value_noise(rng, h, w, 10.0))[..., None], 0, 1).astype(np.float32)


def bricks(rng: np.random.Generator, h: int, w: int, color: Color, brick_px: int) -> np.ndarray:
    """Running-bond brickwork with mortar lines and per-brick shade variation."""
    bh = max(3, int(brick_px))
    bw = 2 * bh + 1
    yy, xx = np.mgrid[0:h, 0:w]
    row = yy // bh
    xs = xx + (row % 2) * (bw // 2)
    col = xs // bw
    shade = 1.0 + 0.25 * rng.uniform(-1, 1, (h // bh + 2, w // bw + 3)).astype(np.float32)
    img = _tint(shade[row, col], color)
    mortar = ((yy % bh) < max(1, bh // 6)) | ((xs % bw) < max(1, bh // 6))
    img[mortar] = srgb_to_linear((0.7, 0.68, 0.64))
    return img


def screen(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    """A switched-off monitor or TV: near-black glass with a faint gradient."""
    g = 0.03 + 0.015 * value_noise(rng, h, w, 2.0)
    return np.repeat(np.clip(g, 0.005, 0.1)[..., None], 3, axis=2).astype(np.float32)


def rich(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    """Strong texture for the animated set: coloured multi-scale noise overlaid with shapes or a pattern."""
    layers = [fractal_noise(rng, h, w, base_cells=rng.uniform(4, 16), octaves=5) for _ in range(3)]
    img = np.stack(layers, axis=-1)
    img = 0.5 + 0.45 * img / (np.abs(img).max() + 1e-6)
    choice = int(rng.integers(3))
    if choice == 0:
        img = 0.5 * img + 0.5 * np.asarray(srgb_to_linear(poster(rng, h, w)) ** (1 / 2.2))
    elif choice == 1:
        t = tiles(rng, h, w, tuple(rng.uniform(0.3, 0.9, 3)), tile_px=int(rng.integers(6, 24)), contrast=0.5)
        img = 0.5 * img + 0.5 * t ** (1 / 2.2)
    else:
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
        period = rng.uniform(4, 20)
        stripes = 0.5 + 0.5 * np.sin((xx * rng.uniform(-1, 1) + yy) * 2 * np.pi / period)
        img = img * (0.6 + 0.4 * stripes[..., None])
    return srgb_to_linear(np.clip(img, 0, 1))


def emissive(h: int, w: int, color: Color, strength: float) -> np.ndarray:
    """A lamp or window: a constant radiance (linear, may exceed 1) — used without lighting."""
    out = np.empty((h, w, 3), np.float32)
    out[:] = srgb_to_linear(color) * strength
    return out
