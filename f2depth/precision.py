"""Mixed precision, one home for depth training, flow pretraining and fine-tuning (``train_depth.amp``,
``flow_pretrain.chairs.amp``, ``flow_finetune.amp``; off in the paper's profile: P²Net and ARFlow train in
float32).

The networks run under ``torch.autocast`` — float16 on CUDA, with a GradScaler against underflowing
gradients; bfloat16 on a CPU, which needs no scaler —; the geometry and the losses run in float32. On a
CPU with bfloat16 units (AVX512-BF16, AMX) oneDNN's bfloat16 convolutions run about twice as fast as its
float32 ones; on one without, autocast falls back to float32 with a warning.
"""

from __future__ import annotations

import functools
import warnings
from contextlib import AbstractContextManager, nullcontext

import torch


def amp_dtype(device: torch.device | str) -> torch.dtype:
    """The autocast dtype of mixed precision on ``device``: float16 on CUDA, bfloat16 elsewhere."""
    return torch.float16 if torch.device(device).type == "cuda" else torch.bfloat16


@functools.cache
def bfloat16_units() -> bool:
    """Whether this CPU computes bfloat16 in hardware (AVX512-BF16 or AMX, as oneDNN sees it); without them
    oneDNN emulates bfloat16 and autocast runs slower than float32. Asked once per process."""
    return bool(torch.backends.mkldnn.is_available() and torch.ops.mkldnn._is_mkldnn_bf16_supported())


def autocast(device: torch.device | str, enabled: bool) -> AbstractContextManager:
    """The networks' mixed-precision context on ``device``; nothing when not ``enabled``, and nothing
    (float32, with one warning) on a CPU without :func:`bfloat16_units`, where bfloat16 is only slower."""
    if not enabled:
        return nullcontext()
    dev = torch.device(device)
    if dev.type == "cpu" and not bfloat16_units():
        warnings.warn("amp: this CPU has no bfloat16 units, so the networks run in float32 (set the stage's "
                      "amp: false to say so in params.yaml)", stacklevel=2)
        return nullcontext()
    return torch.autocast(device_type=dev.type, dtype=amp_dtype(dev))


def full_precision(device: torch.device | str) -> AbstractContextManager:
    """Autocast switched off (losses and geometry inside an autocast region run in float32)."""
    return torch.autocast(device_type=torch.device(device).type, enabled=False)


def grad_scaler(device: torch.device | str, enabled: bool) -> torch.amp.GradScaler:
    """A GradScaler for float16 on CUDA; a disabled (pass-through) one otherwise."""
    return torch.amp.GradScaler("cuda", enabled=enabled and torch.device(device).type == "cuda")


def backward_and_step(loss: torch.Tensor, optimizer: torch.optim.Optimizer,
                      scaler: torch.amp.GradScaler | None = None) -> None:
    """Back-propagate ``loss`` and update, through ``scaler`` when it is an enabled (CUDA float16) one."""
    if scaler is not None and scaler.is_enabled():
        scaler.scale(loss).backward()
        scaler.step(optimizer)
        scaler.update()
    else:
        loss.backward()
        optimizer.step()
