"""ONNX export of the depth network (img (B,3,H,W) in [0,1] → depth (B,1,H,W) metres, dynamic batch)
with a parity check against PyTorch before the file is put in place."""

from __future__ import annotations

import io
import os
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn

from f2depth.depth import DepthModel
from f2depth.inference.backends import ONNX_FORMAT, ONNX_INPUT, ONNX_OUTPUT, ONNX_VERSION, OnnxBackend
from f2depth.inference.limits import DEFAULT_OPSET, check_export_size, check_opset
from f2depth.inference.optional import require
from f2depth.io import atomic_path

#: parity tolerance: max |Δdepth| / depth between onnxruntime and PyTorch (float32 round-off is ~1e-6)
PARITY_RTOL = 1e-4


class ExportError(RuntimeError):
    """The export failed or its parity check did not pass; nothing was written."""


class DepthNetwork(nn.Module):
    """The depth half of a DepthModel as one graph: img (B,3,H,W) in [0,1] → depth (B,1,H,W) metres."""

    def __init__(self, model: DepthModel) -> None:
        super().__init__()
        self.model = model

    def forward(self, img: torch.Tensor) -> torch.Tensor:
        return self.model.predict_depth(img)


@dataclass(frozen=True)
class Parity:
    """onnxruntime vs PyTorch on ``batch`` random images of size ``hw``: max |Δ| (m) and max |Δ|/depth."""

    batch: int
    hw: tuple[int, int]
    max_abs: float
    max_rel: float


def parity_check(model: DepthModel, backend: OnnxBackend, batch: int = 2, seed: int = 0) -> Parity:
    """Run both on the same random batch (a batch size other than the export's 1, so the dynamic batch
    axis is exercised too)."""
    h, w = backend.input_hw
    x = torch.rand(batch, 3, h, w, generator=torch.Generator().manual_seed(seed))
    with torch.inference_mode():
        ref = model.predict_depth(x).float()
    got = backend.depth(x)
    diff = (got - ref).abs()
    return Parity(batch, (h, w), float(diff.max()), float((diff / ref.abs().clamp_min(1e-12)).max()))


def _onnx_bytes(model: DepthModel, hw: tuple[int, int], opset: int) -> bytes:
    buf = io.BytesIO()
    dummy = torch.rand(1, 3, *hw, generator=torch.Generator().manual_seed(0))
    with warnings.catch_warnings():
        # the legacy (TorchScript) exporter is used because the dynamo one needs onnxscript; its
        # deprecation, tracer and constant-folding notes say nothing about this graph
        warnings.simplefilter("ignore")
        try:
            torch.onnx.export(DepthNetwork(model).eval(), (dummy,), buf, dynamo=False, opset_version=opset,
                              input_names=[ONNX_INPUT], output_names=[ONNX_OUTPUT],
                              dynamic_axes={ONNX_INPUT: {0: "batch"}, ONNX_OUTPUT: {0: "batch"}})
        except RuntimeError as exc:  # the exporter's own errors (torch.onnx.OnnxExporterError is one)
            first = str(exc).strip().splitlines()[0][:200] if str(exc).strip() else type(exc).__name__
            raise ExportError(f"torch.onnx.export failed at {hw[0]}×{hw[1]}, opset {opset} ({first}); "
                              "nothing written") from None
    return buf.getvalue()


def export_onnx(model: DepthModel, path: str | os.PathLike, height: int | None = None,
                width: int | None = None, opset: int = DEFAULT_OPSET, source: str = "",
                rtol: float = PARITY_RTOL) -> Parity:
    """Export ``model``'s depth network at (height, width) (default: its training size) to ``path``.
    Sizes and opsets outside the bounds of ``f2depth.inference.limits`` → ValueError.

    The graph gets f2depth metadata (format, version, size, depth range, source checkpoint) that
    ``OnnxBackend`` checks. The file is written to a temporary name, checked with ``onnx.checker`` and
    run by onnxruntime against PyTorch; only if max |Δ|/depth ≤ ``rtol`` is it renamed onto ``path``
    (else :class:`ExportError` and nothing is left behind).
    """
    onnx = require("onnx", "ONNX export")
    require("onnxruntime", "the ONNX export's parity check")
    h = int(height if height is not None else model.config.height)
    w = int(width if width is not None else model.config.width)
    check_export_size(h, w)
    check_opset(opset)
    model = model.eval().cpu()
    proto = onnx.load_from_string(_onnx_bytes(model, (h, w), opset))
    meta = {"format": ONNX_FORMAT, "version": str(ONNX_VERSION), "height": str(h), "width": str(w),
            "trained_height": str(model.config.height), "trained_width": str(model.config.width),
            "min_depth": repr(model.config.min_depth), "max_depth": repr(model.config.max_depth),
            "source": str(source), "config": repr(model.config.to_dict())}
    for key, value in meta.items():
        entry = proto.metadata_props.add()
        entry.key, entry.value = key, value
    proto.producer_name = "f2depth"
    try:
        onnx.checker.check_model(proto)
    except onnx.checker.ValidationError as exc:
        raise ExportError(f"{path}: exported graph fails onnx.checker ({exc})") from None
    dest = Path(path)
    with atomic_path(dest) as tmp:
        tmp.write_bytes(proto.SerializeToString())
        parity = parity_check(model, OnnxBackend(tmp))
        if not np.isfinite(parity.max_rel) or parity.max_rel > rtol:
            raise ExportError(f"{dest}: ONNX parity check failed: max |Δdepth| {parity.max_abs:.3g} m, "
                              f"relative {parity.max_rel:.3g} > {rtol:g}; nothing written "
                              "(try another --opset)")
    return parity
