"""Bounds of ``f2depth export`` (no torch import: the command line checks its options with them).

Opsets: below 9 the depth decoder's nearest upsampling has no ONNX form; 20 is the newest opset the
TorchScript exporter of torch 2.x writes (``torch.onnx._constants.ONNX_TORCHSCRIPT_EXPORTER_MAX_OPSET``),
and every opset in 9..20 passes the parity check. Sizes: each side a multiple of 32 in [64, 4096] (at 32
the encoder's last feature map is 1×1 and its reflection padding fails) and at most 2048×2048 pixels in
all; the export and its parity check peak at about 1.9 GB of memory at 1024×1024, growing by about
1.2 GB per further megapixel (32000×32000 was killed by the kernel at 23 GB).
"""

from __future__ import annotations

DEFAULT_OPSET = 17
MIN_OPSET, MAX_OPSET = 9, 20
MIN_SIDE, MAX_SIDE = 64, 4096
MAX_EXPORT_PIXELS = 2048 * 2048


def check_export_size(height: int, width: int) -> None:
    """ValueError unless both sides are multiples of 32 in [MIN_SIDE, MAX_SIDE] and the image has at most
    MAX_EXPORT_PIXELS pixels."""
    h, w = int(height), int(width)
    if h <= 0 or w <= 0 or h % 32 or w % 32:
        raise ValueError(f"export size {h}×{w}: height and width must be positive multiples of 32")
    if not (MIN_SIDE <= h <= MAX_SIDE and MIN_SIDE <= w <= MAX_SIDE):
        raise ValueError(f"export size {h}×{w}: each side must lie in {MIN_SIDE}..{MAX_SIDE} (the encoder "
                         "downsamples by 32 and needs at least 2×2 features)")
    if h * w > MAX_EXPORT_PIXELS:
        raise ValueError(f"export size {h}×{w}: at most {MAX_EXPORT_PIXELS} pixels (e.g. 2048×2048); "
                         "larger exports need tens of GB of memory")


def check_opset(opset: int) -> None:
    """ValueError unless ``opset`` is in MIN_OPSET..MAX_OPSET."""
    if not MIN_OPSET <= int(opset) <= MAX_OPSET:
        raise ValueError(f"ONNX opset {opset} is not supported: use {MIN_OPSET}..{MAX_OPSET} "
                         f"(default {DEFAULT_OPSET})")
