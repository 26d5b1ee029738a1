"""Optical flow: the flow-network interface and its registry, ARFlow's PWC-Lite, its cost volume, census,
warp, unsupervised loss, checkpoints and evaluation (ARFlow, Liu et al., CVPR 2020; its
code github.com/lliuz/ARFlow)."""

from f2depth.colour import flow_to_color
from f2depth.flow.census import census_distance
from f2depth.flow.checkpoint import (
    NETWORKS,
    CheckpointError,
    build_network,
    load_flow_model,
    read_flow_checkpoint,
    save_flow_model,
)
from f2depth.flow.correlation import correlation, correlation_reference
from f2depth.flow.evaluation import EPEAccumulator, epe_stats, low_texture_mask
from f2depth.flow.loss import SINTEL_FT, SINTEL_RAW, FlowLossConfig, flow_loss, non_occluded_masks
from f2depth.flow.network import FlowNetwork
from f2depth.flow.pwclite import PWCLite
from f2depth.flow.warp import warp
from f2depth.geometry import resize_flow

__all__ = [
    "NETWORKS",
    "SINTEL_FT",
    "SINTEL_RAW",
    "CheckpointError",
    "EPEAccumulator",
    "FlowLossConfig",
    "FlowNetwork",
    "PWCLite",
    "build_network",
    "census_distance",
    "correlation",
    "correlation_reference",
    "epe_stats",
    "flow_loss",
    "flow_to_color",
    "load_flow_model",
    "low_texture_mask",
    "non_occluded_masks",
    "read_flow_checkpoint",
    "resize_flow",
    "save_flow_model",
    "warp",
]
