"""An inference copy of a DepthModel: every BatchNorm folded into the convolution before it.

In eval mode a BatchNorm is an affine map per channel, ``y = γ (x − μ) / √(σ² + ε) + β``, so after a
convolution ``x = W ∗ u + b`` it folds into that convolution: ``W' = W · s``, ``b' = (b − μ) · s + β`` with
``s = γ / √(σ² + ε)`` per output channel. The copy computes the same depth (to float rounding, ~1e-6
relative) without the BatchNorm passes over the encoder's activations; the training model is untouched.
"""

from __future__ import annotations

import copy

import torch
from torch import nn

from f2depth.depth.model import DepthModel
from f2depth.depth.resnet import ResNet


@torch.no_grad()
def fold_batchnorm(conv: nn.Conv2d, bn: nn.BatchNorm2d) -> nn.Conv2d:
    """A new convolution computing ``bn(conv(x))`` of an eval-mode ``bn`` (its running statistics)."""
    scale = bn.weight / torch.sqrt(bn.running_var + bn.eps)
    fused = nn.Conv2d(conv.in_channels, conv.out_channels, conv.kernel_size, conv.stride, conv.padding,
                      conv.dilation, conv.groups, bias=True, padding_mode=conv.padding_mode).to(conv.weight)
    fused.weight.copy_(conv.weight * scale.reshape(-1, 1, 1, 1))
    bias = conv.bias if conv.bias is not None else torch.zeros_like(bn.running_mean)
    fused.bias.copy_((bias - bn.running_mean) * scale + bn.bias)
    return fused


def _fold_resnet(net: ResNet) -> None:
    """Fold every (convolution, BatchNorm) pair of a torchvision-named ResNet in place (BN → Identity)."""
    net.conv1, net.bn1 = fold_batchnorm(net.conv1, net.bn1), nn.Identity()
    for name in ("layer1", "layer2", "layer3", "layer4"):
        for block in getattr(net, name):
            block.conv1, block.bn1 = fold_batchnorm(block.conv1, block.bn1), nn.Identity()
            block.conv2, block.bn2 = fold_batchnorm(block.conv2, block.bn2), nn.Identity()
            if block.downsample is not None:
                block.downsample = nn.Sequential(fold_batchnorm(block.downsample[0], block.downsample[1]))


def inference_copy(model: DepthModel) -> DepthModel:
    """A deep copy of ``model`` in eval mode with its encoders' BatchNorms folded (module docstring); only
    for inference (the copy has no BatchNorm statistics to train)."""
    out = copy.deepcopy(model).eval()
    for net in (out.depth_encoder, out.pose_encoder):
        _fold_resnet(net)
    return out
