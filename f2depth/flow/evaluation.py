"""Flow accuracy against ground truth and flow visualisation.

End-point error (EPE) is the Euclidean distance between predicted and true flow vectors, in pixels,
averaged over a pixel set: ``all`` (every valid pixel), ``noc`` (not occluded in the next frame),
``occ`` and ``low_texture``.

EPE alone does not say whether a network under- or over-estimates motion, so over the ``all`` set
:class:`EPEAccumulator` also reports

- ``magnitude_ratio`` = Σ|flow| / Σ|gt|, the ratio of the summed vector lengths (1 = right overall
  magnitude, 0.5 = half the true motion; 0 for zero flow), and
- ``cosine``: the mean cosine of the angle between the predicted and the true vector over the pixels
  whose true flow is longer than ``COSINE_MIN_FLOW`` = 0.1 px (shorter ones have no reliable direction);
  a zero-length prediction counts as cosine 0 (1 = right direction, −1 = opposite).

**Low texture** (our definition): a pixel is low-texture when the local RMS gradient of the grey image
(``0.2989 R + 0.5870 G + 0.1140 B`` in [0, 1]) is below ``LOW_TEXTURE_THRESHOLD`` = 0.01 per pixel
(≈ 2.6 grey levels out of 255), where the RMS is taken over a ``LOW_TEXTURE_WINDOW`` = 7×7 box of
central-difference gradients ``(I(x+1) − I(x−1))/2``. Uniform walls, ceilings and smooth shading fall
in it; edges, text and texture do not. This is where photometric losses carry no signal, which is what
the patch-based fine-tuning targets.

:func:`flow_to_color` is the Middlebury colour coding (Baker et al., IJCV 2011): hue is the direction
on a 55-colour wheel (red → yellow → green → cyan → blue → magenta, 15/6/4/11/13/6 steps), saturation
the magnitude relative to the largest one shown.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

from f2depth.flow.census import GREY_WEIGHTS

LOW_TEXTURE_THRESHOLD = 0.01
LOW_TEXTURE_WINDOW = 7
COSINE_MIN_FLOW = 0.1


def gradient_energy(img: torch.Tensor, window: int = LOW_TEXTURE_WINDOW) -> torch.Tensor:
    """Local RMS gradient of the grey image: ``img (B,3,H,W)`` in [0,1] → ``(B,1,H,W)`` per pixel."""
    grey = (img * img.new_tensor(GREY_WEIGHTS).view(1, 3, 1, 1)).sum(1, keepdim=True)
    p = F.pad(grey, (1, 1, 1, 1), mode="replicate")
    gx = (p[:, :, 1:-1, 2:] - p[:, :, 1:-1, :-2]) / 2
    gy = (p[:, :, 2:, 1:-1] - p[:, :, :-2, 1:-1]) / 2
    energy = F.avg_pool2d(F.pad(gx * gx + gy * gy, (window // 2,) * 4, mode="replicate"), window, 1)
    return energy.sqrt()


def low_texture_mask(img: torch.Tensor, threshold: float = LOW_TEXTURE_THRESHOLD,
                     window: int = LOW_TEXTURE_WINDOW) -> torch.Tensor:
    """``img (B,3,H,W)`` in [0,1] → bool ``(B,1,H,W)``: local RMS gradient below ``threshold``."""
    return gradient_energy(img, window) < threshold


def endpoint_error(flow: torch.Tensor, gt: torch.Tensor) -> torch.Tensor:
    """``flow, gt (B,2,H,W)`` pixels, x first → EPE ``(B,1,H,W)``."""
    return (flow - gt).norm(dim=1, keepdim=True)


class EPEAccumulator:
    """Sums EPE over pixel sets across many frames, plus the flow and ground-truth vector lengths and the
    cosines between them over the ``all`` set; :meth:`result` gives the means, the magnitude ratio, the
    mean cosine and the pixel counts (see the module docstring)."""

    SETS = ("all", "noc", "occ", "low_texture")

    def __init__(self) -> None:
        self.sum = dict.fromkeys(self.SETS, 0.0)
        self.count = dict.fromkeys(self.SETS, 0)
        self.flow_length = 0.0    # Σ|flow| over the ``all`` pixels
        self.gt_length = 0.0      # Σ|gt| over the ``all`` pixels
        self.cosine_sum = 0.0     # Σ cos over the ``all`` pixels with |gt| > COSINE_MIN_FLOW
        self.cosine_count = 0

    def add(self, flow: torch.Tensor, gt: torch.Tensor, occluded: torch.Tensor | None = None,
            low_texture: torch.Tensor | None = None, valid: torch.Tensor | None = None) -> None:
        """``flow, gt (B,2,H,W)`` pixels, x first; optional bool ``occluded``, ``low_texture``, ``valid``
        ``(B,1,H,W)``. Pixels with non-finite flow or ground truth are not scored."""
        epe = endpoint_error(flow.float(), gt.float())
        base = torch.isfinite(epe) if valid is None else valid.bool() & torch.isfinite(epe)
        sets = {"all": base}
        if occluded is not None:
            sets["noc"] = base & ~occluded.bool()
            sets["occ"] = base & occluded.bool()
        if low_texture is not None:
            sets["low_texture"] = base & low_texture.bool()
        for name, m in sets.items():
            self.sum[name] += float(epe[m].double().sum())
            self.count[name] += int(m.sum())
        self._add_direction(flow, gt, base)

    def _add_direction(self, flow: torch.Tensor, gt: torch.Tensor, mask: torch.Tensor) -> None:
        """Vector lengths and cosines of the pixels of bool ``mask (B,1,H,W)``."""
        m = mask[:, 0]
        f = flow.detach().double().permute(0, 2, 3, 1)[m]      # (N,2)
        g = gt.detach().double().permute(0, 2, 3, 1)[m]        # (N,2)
        nf, ng = f.norm(dim=1), g.norm(dim=1)                   # (N,)
        self.flow_length += float(nf.sum())
        self.gt_length += float(ng.sum())
        moving = ng > COSINE_MIN_FLOW
        denom = nf[moving] * ng[moving]
        dot = (f[moving] * g[moving]).sum(1)
        cos = torch.where(denom > 0, dot / denom.clamp_min(torch.finfo(torch.float64).tiny), 0.0)
        self.cosine_sum += float(cos.clamp(-1.0, 1.0).sum())
        self.cosine_count += int(moving.sum())

    def result(self) -> dict[str, float | int | None]:
        """``{"epe_all", "epe_noc", "epe_occ", "epe_low_texture", "pixels_<set>", "magnitude_ratio",
        "cosine"}``: EPE None for empty sets; ``magnitude_ratio`` = Σ|flow| / Σ|gt| over ``all`` (None
        when Σ|gt| is 0 or no pixels); ``cosine`` = mean cosine over the ``all`` pixels with |gt| >
        ``COSINE_MIN_FLOW`` (None when there is none)."""
        out: dict[str, float | int | None] = {}
        for name in self.SETS:
            out[f"epe_{name}"] = self.sum[name] / self.count[name] if self.count[name] else None
        for name in self.SETS:
            out[f"pixels_{name}"] = self.count[name]
        out["magnitude_ratio"] = self.flow_length / self.gt_length if self.gt_length > 0 else None
        out["cosine"] = self.cosine_sum / self.cosine_count if self.cosine_count else None
        return out


def epe_stats(flow: torch.Tensor, gt: torch.Tensor, occluded: torch.Tensor | None = None,
              low_texture: torch.Tensor | None = None, valid: torch.Tensor | None = None) -> dict:
    """One-shot :class:`EPEAccumulator` over a batch (``flow, gt (B,2,H,W)`` pixels, x first; masks
    ``(B,1,H,W)``): EPE per pixel set, pixel counts, ``magnitude_ratio`` and ``cosine`` (see there)."""
    acc = EPEAccumulator()
    acc.add(flow, gt, occluded, low_texture, valid)
    return acc.result()


def color_wheel() -> np.ndarray:
    """The 55×3 Middlebury colour wheel, float in [0, 255]."""
    segments = [(15, (255, 0, 0), (255, 255, 0)), (6, (255, 255, 0), (0, 255, 0)),
                (4, (0, 255, 0), (0, 255, 255)), (11, (0, 255, 255), (0, 0, 255)),
                (13, (0, 0, 255), (255, 0, 255)), (6, (255, 0, 255), (255, 0, 0))]
    rows = []
    for n, start, end in segments:
        t = np.arange(n, dtype=np.float64)[:, None] / n
        rows.append(np.asarray(start, np.float64) * (1 - t) + np.asarray(end, np.float64) * t)
    return np.floor(np.concatenate(rows, 0))


def flow_to_color(flow: np.ndarray, max_flow: float | None = None) -> np.ndarray:
    """``flow (H,W,2)`` or ``(2,H,W)`` pixels → RGB uint8 ``(H,W,3)`` (Middlebury coding).

    Magnitudes are divided by ``max_flow`` (default: the largest finite magnitude); vectors longer than
    that are drawn at 75 % brightness; non-finite vectors are black.
    """
    f = np.asarray(flow, dtype=np.float64)
    if f.ndim == 3 and f.shape[0] == 2 and f.shape[-1] != 2:
        f = f.transpose(1, 2, 0)
    if f.ndim != 3 or f.shape[-1] != 2:
        raise ValueError(f"flow_to_color: expected (H,W,2) or (2,H,W), got {np.shape(flow)}")
    u, v = f[..., 0], f[..., 1]
    bad = ~(np.isfinite(u) & np.isfinite(v))
    u, v = np.where(bad, 0, u), np.where(bad, 0, v)
    mag = np.hypot(u, v)
    scale = max_flow if max_flow is not None else (float(mag.max()) if mag.size else 0.0)
    scale = max(scale, 1e-9)
    u, v, mag = u / scale, v / scale, mag / scale
    wheel = color_wheel()
    n = wheel.shape[0]
    angle = np.arctan2(-v, -u) / np.pi                 # in (-1, 1]
    fk = (angle + 1) / 2 * (n - 1)                      # 0 .. n-1
    k0 = np.floor(fk).astype(int)
    k1 = (k0 + 1) % n
    frac = (fk - k0)[..., None]
    col = ((1 - frac) * wheel[k0] + frac * wheel[k1]) / 255.0
    inside = (mag <= 1)[..., None]
    col = np.where(inside, 1 - mag[..., None] * (1 - col), col * 0.75)
    img = np.floor(255 * col).astype(np.uint8)
    img[bad] = 0
    return img
