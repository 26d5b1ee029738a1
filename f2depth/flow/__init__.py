"""Optical flow (ARFlow, Liu et al., CVPR 2020; its code github.com/lliuz/ARFlow): ``net`` holds the network
the frozen teacher of depth training needs (the flow-network interface and its registry, ARFlow's PWC-Lite,
its cost volume, checkpoints); the rest trains and scores it: census, unsupervised loss, the patch loss,
pretraining (``chairs`` generates its FlyingChairs-style pairs on the fly), fine-tuning and evaluation. The
names below are imported from their module on first use, so importing one module of this package loads no
other."""

from f2depth.lazy import lazy_getattr

_HOMES = {"NETWORKS": "net.checkpoint", "CheckpointError": "net.checkpoint",
          "build_network": "net.checkpoint", "load_flow_model": "net.checkpoint",
          "read_flow_checkpoint": "net.checkpoint", "save_flow_model": "net.checkpoint",
          "FlowNetwork": "net.network", "PWCLite": "net.pwclite"}
__all__ = sorted(_HOMES)

__getattr__ = lazy_getattr(__name__, _HOMES)
