"""What the protocols share: reading fields of a sample, making the network input, running a batch.

Samples are plain objects: attributes are read by name (dataclasses, namedtuples, simple classes),
then mapping keys, and as a last resort a position in a plain tuple (the loaders' documented order).
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Iterator, Sequence
from typing import Any, TypeVar

import numpy as np
import torch

from f2depth.data.errors import DataError
from f2depth.data.images import resize_rgb
from f2depth.eval.metrics import PredictDisp, predict_disparity

T = TypeVar("T")
log = logging.getLogger(__name__)

def field(sample: Any, name: str, position: int | None = None, aliases: Sequence[str] = ()) -> Any:
    """``sample.<name>`` (or an alias), else ``sample[name]``, else ``sample[position]`` for plain tuples.

    Attributes that are methods (``tuple.index``) or None do not count as present.
    """
    for key in (name, *aliases):
        value = getattr(sample, key, None)
        if value is not None and not callable(value):  # skips tuple.index / tuple.count methods
            return value
    if isinstance(sample, dict):
        for key in (name, *aliases):
            if key in sample:
                return sample[key]
    plain_tuple = isinstance(sample, tuple) and not hasattr(sample, "_fields")
    if plain_tuple and position is not None and position < len(sample):
        return sample[position]
    raise TypeError(
        f"evaluation sample of type {type(sample).__name__} has no field '{name}'"
        + (f" (or {', '.join(aliases)})" if aliases else "")
        + "; give it that attribute (see the protocol's docstring for the fields it reads)"
    )


def check_rgb(rgb: Any, what: str) -> np.ndarray:
    """rgb (H,W,3) uint8 → the same array, or a TypeError/ValueError that says what is wrong."""
    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"{what}: rgb must be (H,W,3), got {rgb.shape}")
    if rgb.dtype != np.uint8:
        raise ValueError(f"{what}: rgb must be uint8 (0..255), got {rgb.dtype}")
    return rgb


def nonfinite_count(values: Any) -> int:
    """Number of NaN or ±inf entries of a ground-truth array (0 for integer arrays)."""
    arr = np.asarray(values)
    return int(np.count_nonzero(~np.isfinite(arr))) if np.issubdtype(arr.dtype, np.floating) else 0


def check_finite_gt(values: Any, what: str) -> None:
    """DataError naming ``what`` and the count when ground truth holds NaN or ±inf: every loader marks
    missing depth with 0, so a non-finite value is damage and would otherwise silently drop pixels (or
    a whole image) from the metrics."""
    bad = nonfinite_count(values)
    if bad:
        raise DataError(what, f"ground truth has {bad} non-finite value(s) (NaN or inf) of "
                              f"{np.asarray(values).size}", "missing depth must be 0; check the test data")


def report_skipped(protocol: str, skipped: Sequence[Any], evaluated: int) -> None:
    """Log one warning line when images were left out because no ground-truth pixel is valid."""
    if skipped:
        log.warning("%s: %d of %d test images skipped: no valid ground-truth pixel (first: %s); the metrics "
                    "are over the other %d", protocol, len(skipped), len(skipped) + evaluated, skipped[0],
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


def run_batch(
    predict_disp: PredictDisp,
    inputs: Sequence[torch.Tensor],
    *,
    device: str | torch.device = "cpu",
    post_process: bool = False,
    out_hw: tuple[int, int] | None = None,
    upsample: str = "nearest",
) -> np.ndarray:
    """Stack inputs (3,h,w) → predict (with PP) → disp (B,H,W) float32 NumPy at ``out_hw`` (or h,w)."""
    x = torch.stack(list(inputs), 0).to(device)
    with torch.no_grad():
        disp = predict_disparity(predict_disp, x, post_process=post_process, out_hw=out_hw, upsample=upsample)
    return disp[:, 0].detach().float().cpu().numpy()
