"""Monodepth2's ResNet encoder: normalised input → five feature levels."""

from __future__ import annotations

import torch

from f2depth.depth.resnet import FEATURE_CHANNELS, ResNet

#: Input normalisation of Monodepth2 / P²Net: (x − 0.45) / 0.225 for images in [0, 1].
INPUT_MEAN = 0.45
INPUT_STD = 0.225


class ResnetEncoder(ResNet):
    """ResNet feature encoder on ``num_input_images`` stacked RGB images in [0, 1].

    Parameter names are torchvision's (``conv1.weight``, ``layer1.0.conv1.weight``, …; no ``fc``).
    forward: x (B, 3·num_input_images, H, W) in [0, 1], H and W multiples of 32 → five features
    [(B,64,H/2,W/2), (B,64,H/4,W/4), (B,128,H/8,W/8), (B,256,H/16,W/16), (B,512,H/32,W/32)].
    """

    num_ch_enc = FEATURE_CHANNELS

    def __init__(self, num_layers: int = 18, num_input_images: int = 1) -> None:
        super().__init__(num_layers, in_channels=3 * num_input_images, num_classes=None)
        self.num_input_images = num_input_images

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        if x.shape[1] != self.in_channels:
            raise ValueError(f"encoder expects {self.in_channels} channels, got input of shape "
                             f"{tuple(x.shape)}")
        return self.features((x - INPUT_MEAN) / INPUT_STD)
