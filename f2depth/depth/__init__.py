"""DepthCNN + PoseCNN (Monodepth2 / P²Net architecture) with torchvision-compatible ResNet encoders."""

from f2depth.depth.decoder import DepthDecoder, disp_to_depth
from f2depth.depth.encoder import ResnetEncoder
from f2depth.depth.model import (
    DepthModel,
    DepthModelConfig,
    load_checkpoint,
    read_checkpoint,
    save_checkpoint,
)
from f2depth.depth.pose import PoseDecoder
from f2depth.depth.resnet import ResNet, load_imagenet_resnet, load_imagenet_resnet18

__all__ = [
    "DepthDecoder",
    "DepthModel",
    "DepthModelConfig",
    "PoseDecoder",
    "ResNet",
    "ResnetEncoder",
    "disp_to_depth",
    "load_checkpoint",
    "load_imagenet_resnet",
    "load_imagenet_resnet18",
    "read_checkpoint",
    "save_checkpoint",
]
