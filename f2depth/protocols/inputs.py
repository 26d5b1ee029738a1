"""What every test set shares when it is scored: the network input, batched prediction.

The samples themselves (:class:`~f2depth.formats.samples.EvalSample`, the ``SampleSet`` interface) live with
the data, in ``f2depth.formats.samples``.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Iterator, Sequence
from typing import TypeVar

import numpy as np
import torch

from f2depth.depth.predict import PredictDisp, predict_disparity, predict_with_and_without_pp
from f2depth.formats.images import resize_rgb

T = TypeVar("T")
log = logging.getLogger(__name__)


def report_skipped(title: str, skipped: Sequence[str], evaluated: int) -> None:
    """Log one warning line when images were left out because no ground-truth pixel is valid."""
    if skipped:
        log.warning("%s: %d of %d test images skipped: no valid ground-truth pixel (first: %s); the metrics "
                    "are over the other %d", title, len(skipped), len(skipped) + evaluated, skipped[0],
                    evaluated)


def to_input(rgb: np.ndarray, hw: tuple[int, int], interpolation: str = "area") -> torch.Tensor:
    """rgb (H,W,3) uint8 → network input (3,h,w) float32 in [0,1] (no normalisation: the encoder does it)."""
    small = resize_rgb(rgb, hw, interpolation)
    return torch.from_numpy(np.ascontiguousarray(small.transpose(2, 0, 1))).float().div_(255.0)


def batched(items: Iterable[T], size: int) -> Iterator[list[T]]:
    """Consecutive chunks of at most ``size`` items."""
    if size < 1:
        raise ValueError(f"batch_size must be ≥ 1, got {size}")
    chunk: list[T] = []
    for item in items:
        chunk.append(item)
        if len(chunk) == size:
            yield chunk
            chunk = []
    if chunk:
        yield chunk


def run_batch(predict_disp: PredictDisp, inputs: Sequence[torch.Tensor], *,
              device: str | torch.device = "cpu", post_process: bool = False,
              out_hw: tuple[int, int] | None = None, upsample: str = "nearest") -> np.ndarray:
    """Stack inputs (3,h,w) → predict (with PP) → disp (B,H,W) float32 NumPy at ``out_hw`` (or h,w)."""
    with torch.no_grad():
        disp = predict_disparity(predict_disp, torch.stack(list(inputs), 0).to(device),
                                 post_process=post_process, out_hw=out_hw, upsample=upsample)
    return _numpy(disp)


def run_batch_with_and_without_pp(predict_disp: PredictDisp, inputs: Sequence[torch.Tensor], *,
                                  device: str | torch.device = "cpu", out_hw: tuple[int, int] | None = None,
                                  upsample: str = "nearest") -> tuple[np.ndarray, np.ndarray]:
    """:func:`run_batch` without and with PP from one forward pass
    (:func:`~f2depth.depth.predict.predict_with_and_without_pp`) → two disp (B,H,W) arrays."""
    with torch.no_grad():
        plain, pp = predict_with_and_without_pp(predict_disp, torch.stack(list(inputs), 0).to(device),
                                                out_hw=out_hw, upsample=upsample)
    return _numpy(plain), _numpy(pp)


def _numpy(disp: torch.Tensor) -> np.ndarray:
    return disp[:, 0].detach().float().cpu().numpy()
