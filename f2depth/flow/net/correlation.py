"""PWC-Lite's cost volume in plain PyTorch (CPU and CUDA), with a hand-written backward.

Semantics (ARFlow / FlowNet2 ``Correlation(pad 4, kernel 1, max_displacement 4, strides 1)``; ARFlow's
code, ``models/pwclite.py`` and ``models/correlation_native.py``)::

    out[b, (dy+4)*9 + (dx+4), y, x] = mean_c f1[b, c, y, x] * f2[b, c, y+dy, x+dx],   dy, dx ∈ {-4..4}

81 channels, dy the outer (slow) index and dx the inner one, f2 zero outside the image.

Implementation ("banded GEMM"): both maps are written channels-last into zero-padded slabs of row width
``W + 8`` and stacked over the batch, so that pixel ``p`` of f1 meets ``p + dy·(W+8) + dx`` of f2 for every
pixel of every image. For each of the 9 row offsets dy, runs of ``L`` consecutive pixels of f1 (L×C) are
multiplied with the ``L + 8`` f2 pixels they can see (C×(L+8)) in one batched matrix product; the 9
diagonals of each L×(L+8) block are the dx = -4..4 correlations. That turns 81 memory-bound
multiply-and-reduce passes into 9 compute-bound ``bmm`` calls (about (L+8)/9 times the minimal
multiply-adds). The backward pass does the same with the transposed products. Nothing per displacement
is stored for autograd: only the two inputs are saved. The output is returned in channels-last strides
(shape (B, 81, H, W)), which is what the convolutions after it prefer.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch.autograd.function import once_differentiable

MAX_DISPLACEMENT = 4
BLOCK = 16  # pixels per GEMM block (L); 16 measured fastest on AVX-512 CPU at the 1/4 and 1/8 levels


def correlation_reference(f1: torch.Tensor, f2: torch.Tensor, max_displacement: int = MAX_DISPLACEMENT
                          ) -> torch.Tensor:
    """Straightforward shift-and-multiply cost volume (autograd through 81 products): ``(B,C,H,W)`` ×2 →
    ``(B,(2r+1)²,H,W)``. Slow and memory-hungry; the ground truth for tests and benchmarks."""
    _, _, h, w = f1.shape
    r = max_displacement
    f2p = F.pad(f2, (r, r, r, r))
    outs = [(f1 * f2p[:, :, dy : dy + h, dx : dx + w]).mean(1, keepdim=True)
            for dy in range(2 * r + 1) for dx in range(2 * r + 1)]
    return torch.cat(outs, 1)


class _Layout:
    """Geometry of the padded, batch-stacked channels-last slabs for one (B, C, H, W, r, L)."""

    def __init__(self, b: int, c: int, h: int, w: int, r: int, block: int) -> None:
        self.b, self.c, self.h, self.w, self.r, self.block = b, c, h, w, r, block
        self.d = 2 * r + 1
        self.wp = w + 2 * r                       # padded row width
        self.rows = h + 2 * r                     # padded rows per image
        npix = b * self.rows * self.wp            # slab pixels covering every image
        self.nblk = -(-npix // block)
        self.npix = self.nblk * block             # f1 slab length (whole blocks)
        self.f2len = self.npix + 2 * r * self.wp + 2 * r  # f2 slab: reach of the last block at dy = dx = 2r

    def slab1(self, f1: torch.Tensor) -> torch.Tensor:
        """f1 at rows [0, H) and columns [0, W) of each image's slab, zeros elsewhere → (npix, C)."""
        s = f1.new_zeros(self.npix, self.c)
        view = s[: self.b * self.rows * self.wp].view(self.b, self.rows, self.wp, self.c)
        view[:, : self.h, : self.w] = f1.permute(0, 2, 3, 1)
        return s

    def slab2(self, f2: torch.Tensor) -> torch.Tensor:
        """f2 zero-padded by r on every side, flattened over (b, row, col) → (f2len, C)."""
        s = f2.new_zeros(self.f2len, self.c)
        view = s[: self.b * self.rows * self.wp].view(self.b, self.rows, self.wp, self.c)
        view[:, self.r : self.r + self.h, self.r : self.r + self.w] = f2.permute(0, 2, 3, 1)
        return s

    def windows(self, slab2: torch.Tensor, dy: int, extra: int | None = None) -> torch.Tensor:
        """Overlapping f2 windows of block j at row offset dy: (nblk, L + 2r, C) view (no copy)."""
        n = self.block + 2 * self.r if extra is None else extra
        return slab2[dy * self.wp :].as_strided((self.nblk, n, self.c), (self.block * self.c, self.c, 1))

    def band(self, blocks: torch.Tensor) -> torch.Tensor:
        """The 2r+1 diagonals of (nblk, L, L + 2r) block products: (nblk, L, 2r+1) view, [i, k] = [i, i+k]."""
        return blocks.as_strided((self.nblk, self.block, self.d), (blocks.stride(0), blocks.stride(1) + 1, 1))

    def crop(self, vol: torch.Tensor) -> torch.Tensor:
        """(npix, ...) slab-ordered values → (B, H, W, ...) for the real pixels."""
        v = vol[: self.b * self.rows * self.wp].view(self.b, self.rows, self.wp, *vol.shape[1:])
        return v[:, : self.h, : self.w]


class _Correlation(torch.autograd.Function):
    @staticmethod
    def forward(ctx, f1: torch.Tensor, f2: torch.Tensor, r: int, block: int) -> torch.Tensor:  # noqa: D102
        b, c, h, w = f1.shape
        lay = _Layout(b, c, h, w, r, block)
        a = lay.slab1(f1).view(lay.nblk, block, c)
        s2 = lay.slab2(f2)
        vol = f1.new_empty(lay.npix, lay.d, lay.d)
        prod = f1.new_empty(lay.nblk, block, block + 2 * r)
        for dy in range(lay.d):
            torch.bmm(a, lay.windows(s2, dy).transpose(1, 2), out=prod)
            vol[:, dy].view(lay.nblk, block, lay.d).copy_(lay.band(prod))
        out = torch.empty((b, h, w, lay.d * lay.d), dtype=f1.dtype, device=f1.device)
        out.copy_(lay.crop(vol.view(lay.npix, lay.d * lay.d)))
        out.mul_(1.0 / c)
        ctx.save_for_backward(f1, f2)
        ctx.r, ctx.block = r, block
        return out

    @staticmethod
    @once_differentiable
    def backward(ctx, grad: torch.Tensor):  # noqa: D102
        f1, f2 = ctx.saved_tensors
        r, block = ctx.r, ctx.block
        b, c, h, w = f1.shape
        lay = _Layout(b, c, h, w, r, block)
        need1, need2 = ctx.needs_input_grad[0], ctx.needs_input_grad[1]
        # grad in slab order, scaled by 1/C; zero at padding pixels so they contribute nothing
        g = grad.new_zeros(lay.npix, lay.d, lay.d)
        lay.crop(g.view(lay.npix, lay.d * lay.d)).copy_(grad)
        g.mul_(1.0 / c)
        a = lay.slab1(f1).view(lay.nblk, block, c)
        s2 = lay.slab2(f2)
        band_blocks = grad.new_zeros(lay.nblk, block, block + 2 * r)
        band = lay.band(band_blocks)
        ga = torch.zeros_like(a) if need1 else None
        gs2 = torch.zeros_like(s2) if need2 else None
        tmp = grad.new_empty(lay.nblk, block + 2 * r, c) if need2 else None
        for dy in range(lay.d):
            band.copy_(g[:, dy].view(lay.nblk, block, lay.d))
            if need1:
                ga.baddbmm_(band_blocks, lay.windows(s2, dy))
            if need2:
                torch.bmm(band_blocks.transpose(1, 2), a, out=tmp)
                # overlap-add: rows [0, L) of block j land on j·L + i, rows [L, L+2r) on the next block's head
                lay.windows(gs2, dy, extra=block).add_(tmp[:, :block])
                tail = gs2[dy * lay.wp + block :].as_strided((lay.nblk, 2 * r, c), (block * c, c, 1))
                tail.add_(tmp[:, block:])
        g1 = g2 = None
        if need1:
            g1 = lay.crop(ga.view(lay.npix, c)).permute(0, 3, 1, 2).contiguous()
        if need2:
            v = gs2[: b * lay.rows * lay.wp].view(b, lay.rows, lay.wp, c)
            g2 = v[:, r : r + h, r : r + w].permute(0, 3, 1, 2).contiguous()
        return g1, g2, None, None


def correlation(f1: torch.Tensor, f2: torch.Tensor, max_displacement: int = MAX_DISPLACEMENT,
                block: int = BLOCK) -> torch.Tensor:
    """PWC-Lite cost volume: ``f1, f2 (B,C,H,W)`` → ``(B,(2r+1)²,H,W)`` (channels-last strides), r = 4.

    Exactly :func:`correlation_reference` up to float rounding; differentiable in both inputs.
    """
    if f1.shape != f2.shape or f1.dim() != 4:
        raise ValueError(f"correlation: feature maps must be (B,C,H,W) of one shape, got {tuple(f1.shape)} "
                         f"and {tuple(f2.shape)}")
    if block < 2 * max_displacement:
        raise ValueError(f"correlation: block {block} must be at least 2·max_displacement")
    if f1.dtype != f2.dtype:
        # under autocast the warped f2 can come back in float32 (CPU grid_sample) next to a bfloat16 f1:
        # compute in autocast's dtype, as a matrix product would, else in the wider of the two
        dev = f1.device.type
        dtype = (torch.get_autocast_dtype(dev) if torch.is_autocast_enabled(dev)
                 else torch.promote_types(f1.dtype, f2.dtype))
        f1, f2 = f1.to(dtype), f2.to(dtype)
    return _Correlation.apply(f1, f2, max_displacement, block).permute(0, 3, 1, 2)
