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
