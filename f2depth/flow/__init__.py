"""Optical flow: the flow-network interface and its registry, ARFlow's PWC-Lite, its cost volume, census,
unsupervised loss, checkpoints and evaluation (ARFlow, Liu et al., CVPR 2020; its code
github.com/lliuz/ARFlow). The names below are imported from their module on first use, so importing one
module of this package loads no other."""

import importlib

_HOMES = {"NETWORKS": "checkpoint", "CheckpointError": "checkpoint", "build_network": "checkpoint",
          "load_flow_model": "checkpoint", "read_flow_checkpoint": "checkpoint",
          "save_flow_model": "checkpoint", "FlowNetwork": "network", "PWCLite": "pwclite"}
__all__ = sorted(_HOMES)


def __getattr__(name: str):
    if name not in _HOMES:
        raise AttributeError(f"module 'f2depth.flow' has no attribute {name!r}")
    return getattr(importlib.import_module(f"f2depth.flow.{_HOMES[name]}"), name)
