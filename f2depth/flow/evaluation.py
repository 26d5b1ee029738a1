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

Neither tells whether the flow comes from the images at all: a network that outputs the same field for
every pair scores a good ``cosine`` on a set whose motion happens to share its direction. So, when the
caller also runs the network on the swapped frames, ``swap_consistency`` is the mean cosine between
``flow(1→2)`` and ``−flow(2→1)`` at the same pixel over the pixels where both are longer than
``COSINE_MIN_FLOW`` (a sign check, not the warped forward–backward check): about +1 for flow that is
matched from the images, about −1 for an image-independent (constant) output.

**Low texture** (our definition): a pixel is low-texture when the local RMS gradient of the grey image
(``0.2989 R + 0.5870 G + 0.1140 B`` in [0, 1]) is below ``LOW_TEXTURE_THRESHOLD`` = 0.01 per pixel
(≈ 2.6 grey levels out of 255), where the RMS is taken over a ``LOW_TEXTURE_WINDOW`` = 7×7 box of
central-difference gradients ``(I(x+1) − I(x−1))/2``. Uniform walls, ceilings and smooth shading fall
in it; edges, text and texture do not. This is where photometric losses carry no signal, which is what
the patch-based fine-tuning targets.

Flow pictures use :func:`f2depth.colour.flow_to_color` (the Middlebury colour coding).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import TYPE_CHECKING

import torch
import torch.nn.functional as F

from f2depth.colour import GREY_MATLAB, grey
from f2depth.geometry import endpoint_error, resize_flow

if TYPE_CHECKING:
    from f2depth.flow.finetune_data import GTPair
    from f2depth.flow.net.network import FlowNetwork

LOW_TEXTURE_THRESHOLD = 0.01
LOW_TEXTURE_WINDOW = 7
COSINE_MIN_FLOW = 0.1


def gradient_energy(img: torch.Tensor, window: int = LOW_TEXTURE_WINDOW) -> torch.Tensor:
    """Local RMS gradient of the grey image: ``img (B,3,H,W)`` in [0,1] → ``(B,1,H,W)`` per pixel."""
    p = F.pad(grey(img, GREY_MATLAB), (1, 1, 1, 1), mode="replicate")
    gx = (p[:, :, 1:-1, 2:] - p[:, :, 1:-1, :-2]) / 2
    gy = (p[:, :, 2:, 1:-1] - p[:, :, :-2, 1:-1]) / 2
    energy = F.avg_pool2d(F.pad(gx * gx + gy * gy, (window // 2,) * 4, mode="replicate"), window, 1)
    return energy.sqrt()


def low_texture_mask(img: torch.Tensor, threshold: float = LOW_TEXTURE_THRESHOLD,
                     window: int = LOW_TEXTURE_WINDOW) -> torch.Tensor:
    """``img (B,3,H,W)`` in [0,1] → bool ``(B,1,H,W)``: local RMS gradient below ``threshold``."""
    return gradient_energy(img, window) < threshold


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
        self.swap_sum = 0.0       # Σ cos(flow 1→2, −flow 2→1) (see the module docstring)
        self.swap_count = 0

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

    def add_swapped(self, flow: torch.Tensor, swapped: torch.Tensor) -> None:
        """``flow (B,2,H,W)`` predicted for (frame 1, frame 2) and ``swapped`` for (frame 2, frame 1), pixels,
        x first → adds to ``swap_consistency`` (module docstring)."""
        f = flow.detach().double()
        b = -swapped.detach().double()
        nf, nb = f.norm(dim=1), b.norm(dim=1)
        both = (nf > COSINE_MIN_FLOW) & (nb > COSINE_MIN_FLOW)
        cos = (f * b).sum(1)[both] / (nf[both] * nb[both])
        self.swap_sum += float(cos.clamp(-1.0, 1.0).sum())
        self.swap_count += int(both.sum())

    def result(self) -> dict[str, float | int | None]:
        """``{"epe_all", "epe_noc", "epe_occ", "epe_low_texture", "pixels_<set>", "magnitude_ratio",
        "cosine"}``: EPE None for empty sets; ``magnitude_ratio`` = Σ|flow| / Σ|gt| over ``all`` (None
        when Σ|gt| is 0 or no pixels); ``cosine`` = mean cosine over the ``all`` pixels with |gt| >
        ``COSINE_MIN_FLOW`` (None when there is none); ``swap_consistency`` (None without
        :meth:`add_swapped` or pixels)."""
        out: dict[str, float | int | None] = {}
        for name in self.SETS:
            out[f"epe_{name}"] = self.sum[name] / self.count[name] if self.count[name] else None
        for name in self.SETS:
            out[f"pixels_{name}"] = self.count[name]
        out["magnitude_ratio"] = self.flow_length / self.gt_length if self.gt_length > 0 else None
        out["cosine"] = self.cosine_sum / self.cosine_count if self.cosine_count else None
        out["swap_consistency"] = self.swap_sum / self.swap_count if self.swap_count else None
        return out


def epe_stats(flow: torch.Tensor, gt: torch.Tensor, occluded: torch.Tensor | None = None,
              low_texture: torch.Tensor | None = None, valid: torch.Tensor | None = None) -> dict:
    """One-shot :class:`EPEAccumulator` over a batch (``flow, gt (B,2,H,W)`` pixels, x first; masks
    ``(B,1,H,W)``): EPE per pixel set, pixel counts, ``magnitude_ratio`` and ``cosine`` (see there)."""
    acc = EPEAccumulator()
    acc.add(flow, gt, occluded, low_texture, valid)
    return acc.result()


def network_flow(model: FlowNetwork, a: torch.Tensor, b: torch.Tensor, hw: tuple[int, int], device: str
                 ) -> torch.Tensor:
    """Network input frames ``(1,3,h,w)`` in [0,1] → forward flow ``(1,2,H,W)`` pixels, x first, resized to
    ``hw`` = (H, W) with its components rescaled (ARFlow's protocol), on the CPU."""
    return resize_flow(model(a.to(device), b.to(device), with_backward=False)[0][0], hw).cpu()


@torch.no_grad()
def score_pair(model: FlowNetwork, acc: EPEAccumulator, zero: EPEAccumulator, a: torch.Tensor,
               b: torch.Tensor, gt: torch.Tensor, occluded: torch.Tensor | None, low: torch.Tensor | None,
               valid: torch.Tensor | None, device: str) -> torch.Tensor:
    """Score the flow of network inputs ``a, b (1,3,h,w)`` against ``gt (1,2,H,W)`` with the bool masks
    ``occluded``, ``low`` (low texture of frame 1) and ``valid`` ``(1,1,H,W)`` (None: all) into ``acc``,
    the swapped frames too (``swap_consistency``), and zero flow into ``zero``; → the prediction."""
    hw = tuple(gt.shape[-2:])
    pred = network_flow(model, a, b, hw, device)
    acc.add(pred, gt, occluded, low, valid)
    acc.add_swapped(pred, network_flow(model, b, a, hw, device))
    zero.add(torch.zeros_like(gt), gt, occluded, low, valid)
    return pred


@torch.no_grad()
def evaluate_gt_pairs(model: FlowNetwork, pairs: Iterable[GTPair], device: str = "cpu",
                      on_pair: Callable[[int, GTPair, torch.Tensor], None] | None = None) -> dict:
    """EPE of ``model`` and of zero flow on scored pairs (frames at the network's size, ground truth with
    its occluded, low-texture and valid masks) → ``{"pairs", "model", "zero_flow"}``, each an
    :meth:`EPEAccumulator.result` (the model's with ``swap_consistency``). The one scorer of the
    fine-tuning (before, every epoch, after) and of the prepared pairs in ``flow_pretrain``'s metrics. The
    model runs in eval mode and is given back in its mode; ``on_pair(i, pair, prediction)`` sees each."""
    was_training = model.training
    model.eval()
    acc, zero, n = EPEAccumulator(), EPEAccumulator(), 0
    for n, g in enumerate(pairs, start=1):
        pred = score_pair(model, acc, zero, g.img1, g.img2, g.flow, g.occluded, g.low_texture, g.valid,
                          device)
        if on_pair is not None:
            on_pair(n - 1, g, pred)
    model.train(was_training)
    return flow_scores(acc, zero, n)


def flow_scores(acc: EPEAccumulator, zero: EPEAccumulator, pairs: int) -> dict:
    """The one result layout of every flow scorer: ``{"pairs", "model", "zero_flow"}``."""
    return {"pairs": pairs, "model": acc.result(), "zero_flow": zero.result()}
