"""DepthCNN + PoseCNN (Monodepth2 / P²Net architecture) with torchvision-compatible ResNet encoders."""

from f2depth.depth.decoder import disp_to_depth
from f2depth.depth.model import (
    DepthModel,
    DepthModelConfig,
    load_checkpoint,
    model_from_checkpoint,
    read_checkpoint,
    save_checkpoint,
)

__all__ = ["DepthModel", "DepthModelConfig", "disp_to_depth", "load_checkpoint", "model_from_checkpoint",
           "read_checkpoint", "save_checkpoint"]
