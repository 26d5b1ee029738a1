"""ResNet-18/34 backbone with torchvision's parameter names, and ImageNet weight loading by path.

The module tree mirrors ``torchvision.models.resnet`` (``conv1``, ``bn1``, ``layer1.0.conv1``, …,
``layer2.0.downsample.0``, …, ``fc``), so a torchvision ``resnet18`` state_dict file loads with strict
name and shape checks. Written from the architecture of He et al. 2016 (BasicBlock, no bottleneck).
"""

from __future__ import annotations

import os
from pathlib import Path

import torch
from torch import nn

from f2depth.errors import CheckpointError
from f2depth.io import load_weights

#: Blocks per stage for the supported depths (BasicBlock networks).
BLOCKS = {18: (2, 2, 2, 2), 34: (3, 4, 6, 3)}
#: Output channels of the five feature levels (stem, layer1..layer4).
FEATURE_CHANNELS = (64, 64, 128, 256, 512)


class BasicBlock(nn.Module):
    """Two 3×3 convolutions with batch norm and an identity (or 1×1 strided) shortcut."""

    def __init__(self, in_ch: int, out_ch: int, stride: int = 1) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(in_ch, out_ch, 3, stride=stride, padding=1, bias=False)
        self.bn1 = nn.BatchNorm2d(out_ch)
        self.relu = nn.ReLU(inplace=True)
        self.conv2 = nn.Conv2d(out_ch, out_ch, 3, stride=1, padding=1, bias=False)
        self.bn2 = nn.BatchNorm2d(out_ch)
        self.downsample: nn.Module | None = None
        if stride != 1 or in_ch != out_ch:
            self.downsample = nn.Sequential(nn.Conv2d(in_ch, out_ch, 1, stride=stride, bias=False),
                                            nn.BatchNorm2d(out_ch))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        identity = x if self.downsample is None else self.downsample(x)
        out = self.relu(self.bn1(self.conv1(x)))
        out = self.bn2(self.conv2(out))
        return self.relu(out + identity)


class ResNet(nn.Module):
    """ResNet-18/34 (BasicBlock) with torchvision's names.

    ``in_channels`` is 3 for one image, 6 for two stacked images (PoseCNN). ``num_classes=None`` omits
    ``fc`` (and the unused classifier parameters); the feature extractor never uses it.
    ``features(x (B,C,H,W)) -> [f1 (B,64,H/2,W/2), f2 (B,64,H/4), f3 (B,128,H/8), f4 (B,256,H/16),
    f5 (B,512,H/32)]``.
    """

    def __init__(self, num_layers: int = 18, in_channels: int = 3, num_classes: int | None = None) -> None:
        super().__init__()
        if num_layers not in BLOCKS:
            raise ValueError(f"num_layers={num_layers} is not supported; use one of {sorted(BLOCKS)}")
        self.num_layers = num_layers
        self.in_channels = in_channels
        self.conv1 = nn.Conv2d(in_channels, 64, 7, stride=2, padding=3, bias=False)
        self.bn1 = nn.BatchNorm2d(64)
        self.relu = nn.ReLU(inplace=True)
        self.maxpool = nn.MaxPool2d(3, stride=2, padding=1)
        in_ch = 64
        for i, (n, out_ch) in enumerate(zip(BLOCKS[num_layers], FEATURE_CHANNELS[1:]), start=1):
            stride = 1 if i == 1 else 2
            blocks = [BasicBlock(in_ch, out_ch, stride)] + [BasicBlock(out_ch, out_ch) for _ in range(n - 1)]
            setattr(self, f"layer{i}", nn.Sequential(*blocks))
            in_ch = out_ch
        if num_classes is not None:
            self.avgpool = nn.AdaptiveAvgPool2d(1)
            self.fc = nn.Linear(512, num_classes)
        self.reset_parameters()

    def reset_parameters(self) -> None:
        """torchvision's random init: Kaiming-normal (fan_out, relu) convs, BN weight 1 and bias 0."""
        for m in self.modules():
            if isinstance(m, nn.Conv2d):
                nn.init.kaiming_normal_(m.weight, mode="fan_out", nonlinearity="relu")
            elif isinstance(m, nn.BatchNorm2d):
                nn.init.ones_(m.weight)
                nn.init.zeros_(m.bias)

    def features(self, x: torch.Tensor) -> list[torch.Tensor]:
        f1 = self.relu(self.bn1(self.conv1(x)))
        f2 = self.layer1(self.maxpool(f1))
        f3 = self.layer2(f2)
        f4 = self.layer3(f3)
        f5 = self.layer4(f4)
        return [f1, f2, f3, f4, f5]

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if not hasattr(self, "fc"):
            raise RuntimeError("this ResNet was built without a classifier (num_classes=None); "
                               "use features()")
        return self.fc(torch.flatten(self.avgpool(self.features(x)[-1]), 1))

    def load_imagenet(self, state_dict: dict[str, torch.Tensor], source: str = "state_dict") -> None:
        """Copy ImageNet weights (torchvision names) into this network, checking every name and shape.

        For ``in_channels = 3k`` the first convolution is the ImageNet one repeated k times along the
        input channels and divided by k (Monodepth2's multi-image encoder). ``fc.*`` is used only if
        this network has a classifier. Missing ``num_batches_tracked`` entries (older torchvision files)
        are allowed. Raises ValueError naming ``source`` on missing, unexpected or mis-shaped entries.
        """
        own = self.state_dict()
        missing = [k for k in own if k not in state_dict and not k.endswith("num_batches_tracked")]
        unexpected = [k for k in state_dict if k not in own and not k.startswith("fc.")]
        if missing or unexpected:
            raise ValueError(f"{source}: not a torchvision resnet{self.num_layers} state_dict "
                             f"(missing {missing[:5]}{'…' if len(missing) > 5 else ''}, "
                             f"unexpected {unexpected[:5]}{'…' if len(unexpected) > 5 else ''}); "
                             f"give the path of a torchvision resnet{self.num_layers} ImageNet .pth file")
        new = {}
        for key, value in own.items():
            if key not in state_dict:
                continue
            src = state_dict[key]
            if key == "conv1.weight" and self.in_channels != src.shape[1]:
                if src.ndim != 4 or self.in_channels % src.shape[1] != 0:
                    raise ValueError(f"{source}: conv1.weight has shape {tuple(src.shape)}, cannot fill "
                                     f"{self.in_channels} input channels")
                k = self.in_channels // src.shape[1]
                src = torch.cat([src] * k, dim=1) / k
            if tuple(src.shape) != tuple(value.shape):
                raise ValueError(f"{source}: {key} has shape {tuple(src.shape)}, expected "
                                 f"{tuple(value.shape)}; is this a resnet{self.num_layers} checkpoint?")
            new[key] = src.to(value.dtype)
        self.load_state_dict(new, strict=False)


def load_imagenet_resnet(path: str | os.PathLike, num_layers: int = 18) -> dict[str, torch.Tensor]:
    """Read a torchvision ``resnet{num_layers}`` ImageNet state_dict file (``torch.save`` of a dict).

    Returns the state_dict after checking that it holds exactly the backbone's tensors (plus ``fc``).
    """
    path = Path(path)
    fix = (f"set train_depth.imagenet_weights to a torchvision resnet{num_layers} .pth file, or to null for "
           "random initialisation")
    if not path.is_file():
        raise FileNotFoundError(f"{path}: ImageNet weights not found; {fix}")
    try:  # torch's advice to load with weights_only=False (running the file's pickled code) is not passed on
        obj = load_weights(path, f"a torchvision resnet{num_layers} state_dict", fix)
    except ValueError as exc:
        raise CheckpointError(str(exc)) from None
    if isinstance(obj, dict) and "state_dict" in obj and isinstance(obj["state_dict"], dict):
        obj = obj["state_dict"]
    if not isinstance(obj, dict) or not all(isinstance(v, torch.Tensor) for v in obj.values()):
        raise CheckpointError(path, f"expected a dict of tensors (a torchvision resnet{num_layers} "
                                    "state_dict)", fix)
    try:  # names and shapes against a reference network with a 1000-class classifier
        ResNet(
            num_layers, 3, num_classes=obj["fc.weight"].shape[0] if "fc.weight" in obj else None
        ).load_imagenet(obj, source=str(path))
    except (ValueError, RuntimeError) as exc:
        raise CheckpointError(f"{' '.join(str(exc).split())}; {fix}") from None
    return obj

