"""Flow checkpoints: ours (any registered flow network) and foreign state dicts (ARFlow's releases).

Everything goes through ``torch.load(..., weights_only=True)``: no pickled code is ever executed.

:data:`NETWORKS` names every :class:`~f2depth.flow.net.network.FlowNetwork` implementation; a checkpoint of
ours records the name and the network's ``architecture()`` and is rebuilt through this registry.

Ours: ``{"format": "f2depth.flow", "version": 2, "network", "network_kwargs", "state_dict", "config",
"params"}`` (docs/formats.md); the earlier ``{"format": "f2depth.pwclite", "version": 1, …}`` files
(no network key) are PWC-Lite and still load.

Foreign files (ARFlow's code: ``trainer/base_trainer.py``, ``utils/torch_utils.py``) are
``torch.save({'epoch', 'state_dict'})`` dicts in the legacy (pre-1.6) or zip serialisation;
``'model_state_dict'`` or a bare state dict are accepted too, and a ``module.`` prefix (DataParallel) is
stripped. They hold no network name: the caller says which network they are for (PWC-Lite by default).
Loading is strict: missing, unexpected and mis-shaped keys are all listed in one :class:`CheckpointError`.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import torch

from f2depth.errors import CheckpointError
from f2depth.flow.net.network import FlowNetwork
from f2depth.flow.net.pwclite import PWCLite
from f2depth.io import damaged_weights, load_weights, torch_save, weights_digest

#: Every flow network by the name that params.yaml (``flow_pretrain.network``) and checkpoints use.
NETWORKS: dict[str, type[FlowNetwork]] = {"pwclite": PWCLite}
DEFAULT_NETWORK = "pwclite"
FORMAT = "f2depth.flow"
VERSION = 2
LEGACY = ("f2depth.pwclite", 1)  # PWC-Lite checkpoints written before the network was recorded
_FIX_ARFLOW = ("pass an ARFlow PWC-Lite checkpoint such as Sintel/pwclite_raw.tar or pwclite_ar.tar "
               "(2-frame model), or one of our models/flow_*.pt")


def build_network(name: str, **kwargs: Any) -> FlowNetwork:
    """A fresh (randomly initialised) network of :data:`NETWORKS` by name."""
    if name not in NETWORKS:
        raise ValueError(f"unknown flow network {name!r}; f2depth.flow.net.checkpoint.NETWORKS has "
                         f"{sorted(NETWORKS)}")
    return NETWORKS[name](**kwargs)


def network_name(model: FlowNetwork) -> str:
    """The registry name of ``model``'s class (exactly that class, not a subclass)."""
    for name, cls in NETWORKS.items():
        if type(model) is cls:
            return name
    raise ValueError(f"{type(model).__name__} is not a registered flow network; add it to "
                     "f2depth.flow.net.checkpoint.NETWORKS")


def _torch_load(path: str | os.PathLike) -> Any:
    p = Path(path)
    if p.is_dir():
        raise CheckpointError(f"{p}: is a directory, not a checkpoint file; {_FIX_ARFLOW}")
    if not p.is_file():
        raise CheckpointError(f"{p}: flow checkpoint not found; check the params.yaml key that names it "
                              "(flow_pretrain.checkpoint, flow_finetune.pretrained or "
                              "variants.<name>.flow)")
    try:
        return load_weights(p, "an f2depth or ARFlow checkpoint", _FIX_ARFLOW)
    except ValueError as exc:
        raise CheckpointError(str(exc)) from exc


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


def check_state_dict(sd: Mapping[str, torch.Tensor], model: FlowNetwork, path: str | os.PathLike) -> None:
    """Raise :class:`CheckpointError` listing missing, unexpected and mis-shaped keys (all at once)."""
    expected = model.state_dict()
    name = network_name(model)
    missing = [k for k in expected if k not in sd]
    unexpected = [k for k in sd if k not in expected]
    misshaped = [f"{k} {tuple(sd[k].shape)} ({name} needs {tuple(v.shape)})"
                 for k, v in expected.items() if k in sd and tuple(sd[k].shape) != tuple(v.shape)]
    if not (missing or unexpected or misshaped):
        return
    parts = [f"{path}: state dict does not fit the flow network '{name}'"]
    for title, keys in (("missing", missing), ("unexpected", unexpected), ("mis-shaped", misshaped)):
        if keys:
            shown = ", ".join(keys[:12]) + (f", … ({len(keys) - 12} more)" if len(keys) > 12 else "")
            parts.append(f"{len(keys)} {title} key(s): {shown}")
    hint = _FIX_ARFLOW
    mv_keys = ("flow_estimators.conv1.0.weight", "context_networks.convs.0.0.weight")
    if name == "pwclite" and any(k.startswith(mv_keys) for k in misshaped):
        hint = "this looks like ARFlow's 3-frame (_mv) model, which is not supported; " + _FIX_ARFLOW
    raise CheckpointError("; ".join(parts) + "; " + hint)


def save_flow_model(path: str | os.PathLike, model: FlowNetwork, config: Mapping[str, Any] | None = None,
                    params: Mapping[str, Any] | None = None) -> None:
    """Write our checkpoint atomically: format, version, the network's registry name and
    ``architecture()``, CPU state dict, ``config`` (how it was made) and the ``params`` section that made
    it (plain YAML types only); ``weights_sha256`` (:func:`f2depth.io.weights_digest` of the state dict)
    lets loaders refuse a file damaged after it was written."""
    state = {k: v.detach().cpu().contiguous() for k, v in model.state_dict().items()}
    torch_save(path, {"format": FORMAT, "version": VERSION, "network": network_name(model),
                      "network_kwargs": dict(model.architecture()), "state_dict": state,
                      "weights_sha256": weights_digest(state), "config": dict(config or {}),
                      "params": dict(params or {})})


def _network_of(obj: Mapping[str, Any], path: str | os.PathLike) -> tuple[str, dict[str, Any]]:
    """(name, kwargs) of the network an object with a ``format`` key holds."""
    found = (obj["format"], obj.get("version"))
    if found == LEGACY:
        return DEFAULT_NETWORK, {}
    if found[0] not in (FORMAT, LEGACY[0]):
        raise CheckpointError(f"{path}: checkpoint format '{found[0]}', expected '{FORMAT}'; "
                              "pass a flow model (models/flow_*.pt), not a depth model")
    if found != (FORMAT, VERSION):
        raise CheckpointError(f"{path}: {found[0]} version {found[1]!r}, this code reads {FORMAT} version "
                              f"{VERSION} and {LEGACY[0]} version {LEGACY[1]}; re-create it with "
                              "`dvc repro flow_pretrain`")
    name = obj.get("network")
    if name not in NETWORKS:
        raise CheckpointError(f"{path}: flow network {name!r} is not in f2depth.flow.net.checkpoint.NETWORKS "
                              f"({sorted(NETWORKS)})")
    return name, dict(obj.get("network_kwargs") or {})


def read_flow_checkpoint(path: str | os.PathLike, network: str = DEFAULT_NETWORK
                         ) -> tuple[FlowNetwork, dict[str, Any]]:
    """Our checkpoint or a foreign state dict → (network with its weights, eval mode, CPU; metadata
    ``{"format", "version", "network", "network_kwargs", "config", "params"}``).

    Ours rebuild the network they record; a foreign file is read into a fresh ``network`` (a name in
    :data:`NETWORKS`), and its metadata says ``format = "foreign"`` (``epoch`` where the file has one).
    """
    obj = _torch_load(path)
    if isinstance(obj, Mapping) and "format" in obj:
        name, kwargs = _network_of(obj, path)
        sd = extract_state_dict(obj.get("state_dict"), path)
        damage = damaged_weights(path, obj, "re-run the stage that wrote it (`dvc repro flow_pretrain`, "
                                            "`dvc repro flow_finetune`)")
        if damage:
            raise CheckpointError(damage)
        meta = {"format": obj["format"], "version": obj["version"], "network": name, "network_kwargs": kwargs,
                "config": dict(obj.get("config") or {}), "params": dict(obj.get("params") or {})}
    else:
        name, kwargs = network, {}
        sd = extract_state_dict(obj, path)
        meta = {"format": "foreign", "version": None, "network": name, "network_kwargs": kwargs,
                "config": {}, "params": {}, "epoch": obj.get("epoch") if isinstance(obj, Mapping) else None}
    model = build_network(name, **kwargs)
    check_state_dict(sd, model, path)
    model.load_state_dict(sd)
    return model.eval(), meta


def load_flow_model(path: str | os.PathLike, network: str = DEFAULT_NETWORK) -> FlowNetwork:
    """Our ``models/flow_*.pt`` (its recorded network) or a foreign state dict such as ARFlow's
    ``*.pth.tar`` (read into ``network``, PWC-Lite by default) → the network, eval mode, CPU."""
    return read_flow_checkpoint(path, network)[0]
