"""Depth-training losses: P²Net's L_ph, L_sm, L_spp and F²Depth's L_rigid, L_feature, and their sum."""

from f2depth.losses.flow_losses import feature_synthesis_loss, resize_flow, rigid_flow_loss
from f2depth.losses.photometric import patch_photometric_errors, patch_photometric_loss
from f2depth.losses.planar import fit_planes, planar_depth, planar_loss
from f2depth.losses.smoothness import edge_aware_smoothness
from f2depth.losses.ssim import ssim_dense, ssim_samples
from f2depth.losses.total import NonFiniteLossError, check_finite, total_loss

__all__ = [
    "NonFiniteLossError",
    "check_finite",
    "edge_aware_smoothness",
    "feature_synthesis_loss",
    "fit_planes",
    "patch_photometric_errors",
    "patch_photometric_loss",
    "planar_depth",
    "planar_loss",
    "resize_flow",
    "rigid_flow_loss",
    "ssim_dense",
    "ssim_samples",
    "total_loss",
]
