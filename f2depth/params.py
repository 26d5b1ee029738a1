"""Reading ``params.yaml``: stage scripts take their section from here and nothing else."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import yaml

DEFAULT_PARAMS = Path("params.yaml")


class ParamsError(ValueError):
    """A parameter is missing or has a wrong value; the message names the key and the file."""


def load(path: str | os.PathLike = DEFAULT_PARAMS) -> dict[str, Any]:
    p = Path(path)
    if not p.is_file():
        raise ParamsError(f"{p}: parameter file not found (run from the repository root or pass its path)")
    with p.open() as fh:
        data = yaml.safe_load(fh) or {}
    if not isinstance(data, dict):
        raise ParamsError(f"{p}: expected a mapping at the top level")
    data["_file"] = str(p)
    return data


def get(params: dict[str, Any], dotted: str, default: Any = ...) -> Any:
    """``get(p, "train_depth.epochs")``; raises :class:`ParamsError` naming the key when absent."""
    node: Any = params
    for part in dotted.split("."):
        if not isinstance(node, dict) or part not in node:
            if default is not ...:
                return default
            raise ParamsError(f"{params.get('_file', 'params.yaml')}: missing parameter '{dotted}'")
        node = node[part]
    return node


def resolve_device(name: str) -> str:
    """``auto`` → ``cuda`` when available else ``cpu``; anything else is returned as given."""
    import torch

    if name == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    if name.startswith("cuda") and not torch.cuda.is_available():
        raise ParamsError(f"device '{name}' requested but CUDA is not available; set device: cpu or auto")
    return name


#: The pretrained starts of the paper's model: params key → what file it must name.
PRETRAINED_STARTS = {
    "train_depth.imagenet_weights": "a torchvision resnet18 ImageNet state_dict (.pth), the start of both "
                                    "ResNet-18s (P²Net's weights_init: pretrained)",
    "flow_pretrain.checkpoint": "ARFlow's 2-frame Sintel model Sintel/pwclite_ar.tar (pwclite_ar_mv is a "
                                "3-frame model and does not load), the start of the flow network",
}


def pretrained_starts(params: dict[str, Any], keys: tuple[str, ...]) -> dict[str, str | None]:
    """The pretrained weight files ``keys`` (of :data:`PRETRAINED_STARTS`) name, None where random.

    With ``allow_random_init: false`` (the ``paper`` profile) every key must name an existing file: the
    paper starts both ResNets from ImageNet and PWC-Lite from ARFlow's Sintel model, so a run without them
    would not be the paper's model. Raises :class:`ParamsError` (one line: the key, the file expected and
    the opt-out) before any work is done. With ``allow_random_init: true`` (the CPU default) an unset key
    means a random start.
    """
    path = params.get("_file", "params.yaml")
    allow = get(params, "allow_random_init")
    if not isinstance(allow, bool):
        raise ParamsError(f"{path}: allow_random_init must be true or false, got {allow!r}")
    out: dict[str, str | None] = {}
    for key in keys:
        value = get(params, key, None)
        if value in (None, ""):
            if not allow:
                raise ParamsError(f"{path}: {key} is not set; the paper's model needs "
                                  f"{PRETRAINED_STARTS[key]}. Point {key} at that file, or set "
                                  "allow_random_init: true to train from random weights")
            out[key] = None
            continue
        if not Path(value).is_file():
            raise ParamsError(f"{path}: {key} = {value}: file not found; it must be {PRETRAINED_STARTS[key]}")
        out[key] = str(value)
    return out
