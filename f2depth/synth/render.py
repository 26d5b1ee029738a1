"""Vectorised ray casting of a baked :class:`~f2depth.synth.scene.Scene` (NumPy, float32).

One ray per pixel centre gives the exact z-depth (camera-frame directions have z = 1, so the ray
parameter of a hit *is* its z-depth) and a first colour. Anti-aliasing is adaptive supersampling: the
pixels where the surface id changes between neighbours (geometric edges) or that show a detailed
texture (posters, books, rugs, tiles, …) with texels smaller than 2 px are re-rendered with
``ss × ss`` stratified samples and box filtered; elsewhere the surface is smooth at pixel scale and
the centre sample is the pixel's mean.

The room is intersected as a box seen from inside (every ray hits it); furniture boxes with the slab
method, each only on the rays inside the image window of its projection (clipped at the near plane).
"""

from __future__ import annotations

import numpy as np

from f2depth.synth.scene import Scene

NEAR = 1e-3  # metres: hits closer than this are ignored
MIN_PX_PER_TEXEL = 2.0  # detailed textures seen coarser than this are supersampled

_CORNERS = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)])
_EDGES = np.array([(0, 1), (2, 3), (4, 5), (6, 7), (0, 2), (1, 3), (4, 6), (5, 7), (0, 4), (1, 5), (2, 6),
                   (3, 7)])


def _bounds(lo, hi, R, o, K) -> tuple[float, float, float, float] | None:
    """Pixel bounds (u0, u1, v0, v1) of the projection of box lo..hi, or None when it is behind."""
    corners = np.where(_CORNERS == 0, lo, hi)
    cam = (corners - o) @ R  # camera frame (8, 3)
    z = cam[:, 2]
    front = z > NEAR
    if not front.any():
        return None
    pts = [cam[front]]
    if not front.all():  # where the edges cross the near plane
        a, b = _EDGES[:, 0], _EDGES[:, 1]
        cross = front[a] != front[b]
        za, zb = z[a[cross]], z[b[cross]]
        s = (NEAR * 1.0001 - za) / (zb - za)
        pts.append(cam[a[cross]] + s[:, None] * (cam[b[cross]] - cam[a[cross]]))
    p = np.concatenate(pts)
    u = K[0, 0] * p[:, 0] / p[:, 2] + K[0, 2]
    v = K[1, 1] * p[:, 1] / p[:, 2] + K[1, 2]
    return u.min() - 1, u.max() + 1, v.min() - 1, v.max() + 1


class _GridRays:
    """Rays through the pixel centres of an (H, W) image; box windows are array slices."""

    def __init__(self, K: np.ndarray, hw: tuple[int, int]):
        self.K, (self.h, self.w) = K, hw
        self.xn = ((np.arange(self.w) - K[0, 2]) / K[0, 0]).astype(np.float32)[None, :]
        self.yn = ((np.arange(self.h) - K[1, 2]) / K[1, 1]).astype(np.float32)[:, None]

    def select(self, b):
        u0, u1, v0, v1 = b
        c0, c1 = int(np.clip(np.floor(u0), 0, self.w)), int(np.clip(np.ceil(u1) + 1, 0, self.w))
        r0, r1 = int(np.clip(np.floor(v0), 0, self.h)), int(np.clip(np.ceil(v1) + 1, 0, self.h))
        if c1 <= c0 or r1 <= r0:
            return None
        return slice(r0, r1), slice(c0, c1)


class _ListRays:
    """Rays through arbitrary pixel positions (N,); box windows are index arrays."""

    def __init__(self, K: np.ndarray, u: np.ndarray, v: np.ndarray):
        self.K, self.u, self.v = K, u, v
        self.xn = ((u - K[0, 2]) / K[0, 0]).astype(np.float32)
        self.yn = ((v - K[1, 2]) / K[1, 1]).astype(np.float32)

    def select(self, b):
        u0, u1, v0, v1 = b
        idx = np.flatnonzero((self.u >= u0) & (self.u <= u1) & (self.v >= v0) & (self.v <= v1))
        return idx if idx.size else None


def cast(scene: Scene, world_T_cam: np.ndarray, rays) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]]:
    """First hits of ``rays``: z-depth ``t`` float32, surface id ``sid`` int64 and the world-frame
    directions (3 arrays), all of the rays' shape."""
    R = np.asarray(world_T_cam, np.float64)[:3, :3]
    o = np.asarray(world_T_cam, np.float64)[:3, 3]
    D = []
    for i in range(3):
        d = np.float32(R[i, 0]) * rays.xn + np.float32(R[i, 1]) * rays.yn + np.float32(R[i, 2])
        d[np.abs(d) < 1e-9] = 1e-9
        D.append(d)
    inv = [1.0 / d for d in D]
    lo, hi = scene.room_lo, scene.room_hi
    t = face = None
    for i in range(3):  # room seen from inside: the nearest exit plane
        pos = inv[i] > 0
        ti = np.where(pos, np.float32(hi[i] - o[i]), np.float32(lo[i] - o[i])) * inv[i]
        fi = pos.astype(np.int64) + 2 * i
        if t is None:
            t, face = ti, fi
        else:
            m = ti < t
            t = np.where(m, ti, t)
            face = np.where(m, fi, face)
    sid = scene.room_surface.astype(np.int64)[face]
    for b in range(len(scene.box_lo)):
        blo, bhi = scene.box_lo[b], scene.box_hi[b]
        bounds = _bounds(blo, bhi, R, o, rays.K)
        sel = None if bounds is None else rays.select(bounds)
        if sel is None:
            continue
        tn = tf = ax = None
        for i in range(3):
            iv = inv[i][sel]
            a = np.float32(blo[i] - o[i]) * iv
            c = np.float32(bhi[i] - o[i]) * iv
            n, f = np.minimum(a, c), np.maximum(a, c)
            if tn is None:
                tn, tf, ax = n, f, np.zeros(n.shape, np.int64)
            else:
                m = n > tn
                tn = np.where(m, n, tn)
                ax[m] = i
                tf = np.minimum(tf, f)
        t_sel = t[sel]
        hit = (tn <= tf) & (tn > NEAR) & (tn < t_sel)
        if not hit.any():
            continue
        ax_h = ax[hit]
        d_h = np.where(ax_h == 0, D[0][sel][hit], np.where(ax_h == 1, D[1][sel][hit], D[2][sel][hit]))
        s_sel = sid[sel]
        t_sel[hit] = tn[hit]
        s_sel[hit] = scene.box_surface[b, 2 * ax_h + (d_h < 0)]  # enter through the hi plane when d < 0
        t[sel] = t_sel
        sid[sel] = s_sel
    return t, sid, D


def shade(scene: Scene, t: np.ndarray, sid: np.ndarray, D, origin: np.ndarray) -> np.ndarray:
    """Bilinear lookup of the baked radiance at the hit points → (*t.shape, 3) float32 linear."""
    o = np.asarray(origin, np.float64)
    p = [np.float32(o[i]) + t * D[i] for i in range(3)]
    A = scene.tex_affine
    x = A[0][sid] * p[0]
    x += A[1][sid] * p[1]
    x += A[2][sid] * p[2]
    x += A[3][sid]
    y = A[4][sid] * p[0]
    y += A[5][sid] * p[1]
    y += A[6][sid] * p[2]
    y += A[7][sid]
    w = scene.tex_w.astype(np.int64)[sid]
    h = scene.tex_h[sid]
    np.clip(x, 0, w - 1, out=x)
    np.clip(y, 0, h - 1, out=y)
    x0, y0 = x.astype(np.int64), y.astype(np.int64)  # truncation = floor for x >= 0
    fx, fy = x - x0, y - y0
    dx = (x0 < w - 1).astype(np.int64)
    dy = (y0 < h - 1) * w
    i00 = scene.offset[sid] + y0 * w + x0
    i01, i10 = i00 + dx, i00 + dy
    i11 = i10 + dx
    out = np.empty((*t.shape, 3), np.float32)
    for c in range(3):
        a = scene.atlas_planes[c]
        c00, c01, c10, c11 = a[i00], a[i01], a[i10], a[i11]
        top = c00 + (c01 - c00) * fx
        bottom = c10 + (c11 - c10) * fx
        out[..., c] = top + (bottom - top) * fy
    return out


def render(scene: Scene, world_T_cam: np.ndarray, K: np.ndarray, hw: tuple[int, int], ss: int,
           adaptive: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Render one view on the ideal pinhole grid of ``K``.

    Returns linear radiance (H, W, 3) float32 (anti-aliased with ``ss × ss`` samples where needed, or
    everywhere when ``adaptive`` is False) and z-depth (H, W) float32 metres at the pixel centres.
    """
    if ss < 1:
        raise ValueError(f"supersample must be >= 1, got {ss}")
    K = np.asarray(K, np.float64)
    origin = np.asarray(world_T_cam, np.float64)[:3, 3]
    t, sid, D = cast(scene, world_T_cam, _GridRays(K, hw))
    color = shade(scene, t, sid, D, origin)
    if ss > 1:
        if adaptive:
            # detailed textures alias only where a texel is smaller than ~2 px (minification)
            fpx = min(K[0, 0], K[1, 1])
            need = scene.detail[sid] & (t * scene.density[sid] > np.float32(fpx / MIN_PX_PER_TEXEL))
            edge_x = sid[:, 1:] != sid[:, :-1]
            edge_y = sid[1:, :] != sid[:-1, :]
            need[:, 1:] |= edge_x
            need[:, :-1] |= edge_x
            need[1:, :] |= edge_y
            need[:-1, :] |= edge_y
            py, px = np.nonzero(need)
        else:
            py, px = np.indices(hw).reshape(2, -1)
        if py.size:
            off = (np.arange(ss) + 0.5) / ss - 0.5
            ou, ov = np.meshgrid(off, off)
            u = (px[:, None] + ou.reshape(1, -1)).ravel()
            v = (py[:, None] + ov.reshape(1, -1)).ravel()
            ts, ss_sid, Ds = cast(scene, world_T_cam, _ListRays(K, u, v))
            samples = shade(scene, ts, ss_sid, Ds, origin).reshape(py.size, ss * ss, 3)
            color[py, px] = samples.mean(axis=1)
    return color, np.ascontiguousarray(t, np.float32)
