"""The depth network behind ``predict``: a PyTorch checkpoint or an ONNX export run by onnxruntime.

Both backends map img (B,3,h,w) float32 in [0, 1] at their fixed input size ``input_hw`` to
depth (B,1,h,w) in the network's nominal metres (``[min_depth, max_depth]``, relative: see
``f2depth.inference.predict``).
"""

from __future__ import annotations

import ast
import os
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import torch

from f2depth.depth import DepthModel, load_checkpoint
from f2depth.depth.fused import cpu_layout, inference_copy
from f2depth.errors import CheckpointError, DataError
from f2depth.inference.optional import require
from f2depth.params import resolve_device

#: metadata written into every ONNX export (``metadata_props``) and checked when one is loaded
ONNX_FORMAT = "f2depth.depth.onnx"
ONNX_VERSION = 1
ONNX_INPUT = "image"
ONNX_OUTPUT = "depth"


class DepthBackend(Protocol):
    name: str
    source: str
    input_hw: tuple[int, int]
    trained_hw: tuple[int, int] | None  # the model's training size (None: an export that does not say)
    min_depth: float
    max_depth: float

    def depth(self, img: torch.Tensor) -> torch.Tensor:
        """img (B,3,h,w) in [0,1] at ``input_hw`` → depth (B,1,h,w) on the CPU."""
        ...


MAX_MESSAGE = 300


def load_depth_model(path: str | os.PathLike, device: str = "cpu") -> DepthModel:
    """A DepthModel from a ``f2depth.depth`` checkpoint in eval mode; any problem → CheckpointError (a
    DataError; its message, which starts with the path, cut to ``MAX_MESSAGE`` characters)."""
    try:
        return load_checkpoint(path, map_location=device).eval()
    except CheckpointError as exc:  # missing; unreadable; wrong format, version, keys or shapes
        text = " ".join(str(exc).split())
        raise CheckpointError(text if len(text) <= MAX_MESSAGE else text[: MAX_MESSAGE - 1] + "…") from None


class TorchBackend:
    """A DepthModel (eval mode) on ``device``; inputs are moved there, outputs come back to the CPU."""

    name = "pytorch"

    def __init__(self, model: DepthModel, device: str = "cpu", source: str = "") -> None:
        # BatchNorm folded into the convolutions, channels-last (on a CPU the encoder's last stage in NCHW):
        # the training graph's depth to ~1e-6 relative, faster (benchmarks/bench_inference.py)
        copy = inference_copy(model).to(device)
        cpu = torch.device(device).type == "cpu"
        self.model = cpu_layout(copy) if cpu else copy.to(memory_format=torch.channels_last)
        self.device = device
        self.source = source
        self.input_hw = (model.config.height, model.config.width)
        self.trained_hw = self.input_hw
        self.min_depth, self.max_depth = model.config.min_depth, model.config.max_depth

    @classmethod
    def from_checkpoint(cls, path: str | os.PathLike, device: str = "cpu") -> TorchBackend:
        device = resolve_device(device)
        return cls(load_depth_model(path, device), device, str(path))

    def depth(self, img: torch.Tensor) -> torch.Tensor:
        with torch.inference_mode():
            x = img.to(self.device, memory_format=torch.channels_last)
            return self.model.predict_depth(x).float().cpu().contiguous()


class OnnxBackend:
    """An ONNX export (``f2depth export``) run by onnxruntime on the CPU or, with ``device`` cuda and the
    CUDA execution provider installed, on the GPU. ``threads``: onnxruntime's thread count (default: its
    own choice, all cores)."""

    name = "onnxruntime"

    def __init__(self, path: str | os.PathLike, device: str = "cpu", threads: int | None = None) -> None:
        ort = require("onnxruntime", "running an ONNX model (--onnx)")
        self.source = str(path)
        p = Path(path)
        if p.is_dir():
            raise DataError(p, "is a directory, not an ONNX model", "give the .onnx file written by "
                               "`f2depth export --format onnx`")
        if not p.is_file():
            raise DataError(p, "ONNX model not found", "create it with `f2depth export --format onnx`")
        providers = ["CPUExecutionProvider"]
        cuda = resolve_device(device).startswith("cuda")
        if cuda and "CUDAExecutionProvider" in ort.get_available_providers():
            providers.insert(0, "CUDAExecutionProvider")
        options = ort.SessionOptions()
        options.log_severity_level = 3  # errors only: keep onnxruntime's warnings off the terminal
        if threads is not None:
            options.intra_op_num_threads = options.inter_op_num_threads = int(threads)
        try:
            self.session = ort.InferenceSession(str(p), sess_options=options, providers=providers)
        except Exception as exc:  # onnxruntime raises its own pybind exception types
            first = str(exc).strip().splitlines()[0][:200] if str(exc).strip() else type(exc).__name__
            raise DataError(p, f"not a loadable ONNX model ({first})",
                            "create it with `f2depth export --format onnx`") from None
        meta = self.session.get_modelmeta().custom_metadata_map
        self._check(p, meta)
        self.input_hw = (int(meta["height"]), int(meta["width"]))
        self.trained_hw = _trained_hw(meta)
        self.min_depth, self.max_depth = float(meta["min_depth"]), float(meta["max_depth"])

    def _check(self, p: Path, meta: dict[str, Any]) -> None:
        if meta.get("format") != ONNX_FORMAT:
            raise DataError(p, f"ONNX model without f2depth metadata (format {meta.get('format')!r}, "
                               f"expected {ONNX_FORMAT!r})", "export it with `f2depth export --format onnx`")
        if meta.get("version") != str(ONNX_VERSION):
            raise DataError(p, f"ONNX export version {meta.get('version')!r} is not supported (expected "
                               f"{ONNX_VERSION})", "re-export it with this version of f2depth")
        missing = [k for k in ("height", "width", "min_depth", "max_depth") if k not in meta]
        if missing:
            raise DataError(p, f"ONNX metadata lacks {missing}", "re-export it with `f2depth export`")
        inputs, outputs = self.session.get_inputs(), self.session.get_outputs()
        if [i.name for i in inputs] != [ONNX_INPUT] or [o.name for o in outputs] != [ONNX_OUTPUT]:
            raise DataError(p, f"unexpected ONNX inputs/outputs {[i.name for i in inputs]} → "
                               f"{[o.name for o in outputs]}", "re-export it with `f2depth export`")
        shape = inputs[0].shape
        if len(shape) != 4 or shape[1:] != [3, int(meta["height"]), int(meta["width"])]:
            raise DataError(p, f"ONNX input shape {shape} does not match its metadata", "re-export it")

    def depth(self, img: torch.Tensor) -> torch.Tensor:
        x = np.ascontiguousarray(img.detach().cpu().numpy(), dtype=np.float32)
        (out,) = self.session.run([ONNX_OUTPUT], {ONNX_INPUT: x})
        return torch.from_numpy(out)


def _trained_hw(meta: dict[str, Any]) -> tuple[int, int] | None:
    """The training size an export's metadata records (``trained_height``/``trained_width``, or exports
    before those: the ``config`` dict's height and width), None when it has neither."""
    if "trained_height" in meta and "trained_width" in meta:
        return int(meta["trained_height"]), int(meta["trained_width"])
    try:
        config = ast.literal_eval(meta.get("config", ""))
        return int(config["height"]), int(config["width"])
    except (ValueError, SyntaxError, TypeError, KeyError, MemoryError, RecursionError):
        return None


def size_mismatch(backend: DepthBackend) -> str | None:
    """One warning line when ``backend`` runs the network at another size than the model was trained at (an
    export with --height/--width): its depth then differs from the model's, so ``--model`` and ``--onnx``
    disagree on the same input. None when the sizes agree or the export does not record its training size."""
    trained = getattr(backend, "trained_hw", None)
    if trained is None or tuple(trained) == tuple(backend.input_hw):
        return None
    (h, w), (th, tw) = backend.input_hw, trained
    return (f"{backend.source or backend.name} runs the network at {h}×{w}, but the model was trained at "
            f"{th}×{tw}: its depth is not the model's (the network sees objects at other sizes), so it "
            "differs from `--model`'s on the same input; export at the training size (`f2depth export` "
            "without --height/--width) for the model's depth")


def load_backend(model: str | os.PathLike | None = None, onnx: str | os.PathLike | None = None,
                 device: str = "cpu", threads: int | None = None) -> TorchBackend | OnnxBackend:
    """Exactly one of ``model`` (a ``f2depth.depth`` checkpoint) or ``onnx`` (an export; ``threads``:
    onnxruntime's thread count, see :class:`OnnxBackend`)."""
    if (model is None) == (onnx is None):
        raise ValueError("give exactly one of model= (checkpoint) or onnx= (ONNX export)")
    if onnx is not None:
        return OnnxBackend(onnx, device, threads)
    return TorchBackend.from_checkpoint(model, device)
