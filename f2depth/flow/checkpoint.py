"""Reading ARFlow checkpoints and reading/writing our own PWC-Lite checkpoints.

Everything goes through ``torch.load(..., weights_only=True)``: no pickled code is ever executed.

ARFlow files (ARFlow's code: ``trainer/base_trainer.py``, ``utils/torch_utils.py``) are
``torch.save({'epoch', 'state_dict'})`` dicts in the legacy (pre-1.6) or zip serialisation;
``'model_state_dict'`` or a bare state dict are accepted too, and a ``module.`` prefix (DataParallel) is
stripped. Loading is strict: missing, unexpected and mis-shaped keys
are all listed in one :class:`CheckpointError`.

Ours: ``{"format": "f2depth.pwclite", "version": 1, "state_dict", "config", "params"}`` (docs/formats.md).
"""

from __future__ import annotations

import os
import pickle
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import torch

from f2depth.flow.pwclite import PWCLite

FORMAT = "f2depth.pwclite"
VERSION = 1
_FIX_ARFLOW = ("pass an ARFlow PWC-Lite checkpoint such as Sintel/pwclite_raw.tar or pwclite_ar.tar "
               "(2-frame model), or one of our models/flow_*.pt")


class CheckpointError(ValueError):
    """A checkpoint file is missing, unreadable or does not fit PWC-Lite; the message names the file."""


def _torch_load(path: str | os.PathLike) -> Any:
    p = Path(path)
    if p.is_dir():
        raise CheckpointError(f"{p}: is a directory, not a checkpoint file; {_FIX_ARFLOW}")
    if not p.is_file():
        raise CheckpointError(f"{p}: flow checkpoint not found; check the params.yaml key that names it "
                              "(flow_pretrain.checkpoint, flow_finetune.pretrained or "
                              "variants.<name>.flow_model)")
    try:
        return torch.load(p, map_location="cpu", weights_only=True)
    except (pickle.UnpicklingError, RuntimeError, EOFError, ValueError, OSError, AttributeError,
            TypeError, KeyError, IndexError) as exc:
        text = " ".join(re.sub(r"\x1b\[[0-9;]*m", "", str(exc)).split())
        # torch's advice to load with weights_only=False (running pickled code) is never passed on
        found = re.search(r"Unsupported global: GLOBAL (\S+)", text)
        if found:
            raise CheckpointError(f"{p}: not an f2depth or ARFlow checkpoint: it holds pickled Python "
                                  f"objects ({found.group(1)}), which a weights_only load refuses and "
                                  f"f2depth never unpickles; {_FIX_ARFLOW}") from exc
        reason = re.search(r"WeightsUnpickler error: (.*?) Check the documentation", text)
        first = (f"WeightsUnpickler: {reason.group(1)}" if reason
                 else text[:200] if text and "weights_only" not in text else type(exc).__name__)
        raise CheckpointError(f"{p}: not a PyTorch checkpoint ({first}); {_FIX_ARFLOW}") from exc


def _is_state_dict(obj: Any) -> bool:
    return isinstance(obj, Mapping) and len(obj) > 0 and all(
        isinstance(k, str) and isinstance(v, torch.Tensor) for k, v in obj.items())


def extract_state_dict(obj: Any, path: str | os.PathLike = "<checkpoint>") -> dict[str, torch.Tensor]:
    """The state dict inside a loaded ARFlow-style object, ``module.`` prefixes removed."""
    sd = obj
    if isinstance(obj, Mapping):
        for key in ("state_dict", "model_state_dict"):
            if key in obj:
                sd = obj[key]
                break
    if not _is_state_dict(sd):
        kind = (f"a dict with keys {sorted(map(str, obj))[:8]}" if isinstance(obj, Mapping)
                else type(obj).__name__)
        raise CheckpointError(f"{path}: not a checkpoint: expected a state dict of tensors or a dict with "
                              f"'state_dict', found {kind}; {_FIX_ARFLOW}")
    if all(k.startswith("module.") for k in sd):
        sd = {k[len("module."):]: v for k, v in sd.items()}
    return dict(sd)


def check_state_dict(sd: Mapping[str, torch.Tensor], model: torch.nn.Module, path: str | os.PathLike) -> None:
    """Raise :class:`CheckpointError` listing missing, unexpected and mis-shaped keys (all at once)."""
    expected = model.state_dict()
    missing = [k for k in expected if k not in sd]
    unexpected = [k for k in sd if k not in expected]
    misshaped = [f"{k} {tuple(sd[k].shape)} (PWC-Lite needs {tuple(v.shape)})"
                 for k, v in expected.items() if k in sd and tuple(sd[k].shape) != tuple(v.shape)]
    if not (missing or unexpected or misshaped):
        return
    parts = [f"{path}: state dict does not fit ARFlow's 2-frame PWC-Lite"]
    for title, keys in (("missing", missing), ("unexpected", unexpected), ("mis-shaped", misshaped)):
        if keys:
            shown = ", ".join(keys[:12]) + (f", … ({len(keys) - 12} more)" if len(keys) > 12 else "")
            parts.append(f"{len(keys)} {title} key(s): {shown}")
    hint = _FIX_ARFLOW
    mv_keys = ("flow_estimators.conv1.0.weight", "context_networks.convs.0.0.weight")
    if any(k.startswith(mv_keys) for k in misshaped):
        hint = "this looks like a 3-frame (_mv) model, which is not supported; " + _FIX_ARFLOW
    raise CheckpointError("; ".join(parts) + "; " + hint)


def load_arflow_state_dict(path: str | os.PathLike) -> dict[str, torch.Tensor]:
    """Read and validate the PWC-Lite state dict of an ARFlow checkpoint file."""
    sd = extract_state_dict(_torch_load(path), path)
    check_state_dict(sd, PWCLite(), path)
    return sd


def load_arflow_checkpoint(path: str | os.PathLike) -> PWCLite:
    """An ARFlow ``*.pth.tar`` → :class:`PWCLite` with its weights (eval mode, CPU)."""
    model = PWCLite()
    model.load_state_dict(load_arflow_state_dict(path))
    return model.eval()


def save_flow_model(path: str | os.PathLike, model: PWCLite, config: Mapping[str, Any] | None = None,
                    params: Mapping[str, Any] | None = None) -> None:
    """Write our checkpoint atomically: format, version, CPU state dict, ``config`` (how it was made) and
    the ``params`` section that made it (plain YAML types only)."""
    from f2depth.io import torch_save

    state = {k: v.detach().cpu().contiguous() for k, v in model.state_dict().items()}
    torch_save(path, {"format": FORMAT, "version": VERSION, "state_dict": state,
                      "config": dict(config or {}), "params": dict(params or {})})


def read_flow_checkpoint(path: str | os.PathLike) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
    """Either kind of file → (validated state dict, metadata ``{"format", "version", "config", "params"}``;
    ARFlow files get ``format = "arflow"``)."""
    obj = _torch_load(path)
    if isinstance(obj, Mapping) and "format" in obj:
        if obj["format"] != FORMAT:
            raise CheckpointError(f"{path}: checkpoint format '{obj['format']}', expected '{FORMAT}'; "
                                  "pass a flow model (models/flow_*.pt), not a depth model")
        if obj.get("version") != VERSION:
            raise CheckpointError(f"{path}: {FORMAT} version {obj.get('version')!r}, this code reads version "
                                  f"{VERSION}; re-create it with `dvc repro flow_pretrain`")
        sd = extract_state_dict(obj.get("state_dict"), path)
        meta = {"format": FORMAT, "version": VERSION, "config": dict(obj.get("config") or {}),
                "params": dict(obj.get("params") or {})}
    else:
        sd = extract_state_dict(obj, path)
        meta = {"format": "arflow", "version": None, "config": {}, "params": {},
                "epoch": obj.get("epoch") if isinstance(obj, Mapping) else None}
    check_state_dict(sd, PWCLite(), path)
    return sd, meta


def load_flow_model(path: str | os.PathLike) -> PWCLite:
    """Our ``models/flow_*.pt`` or an ARFlow ``*.pth.tar`` → :class:`PWCLite` (eval mode, CPU)."""
    sd, _ = read_flow_checkpoint(path)
    model = PWCLite()
    model.load_state_dict(sd)
    return model.eval()
