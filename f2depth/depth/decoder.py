"""Monodepth2's depth decoder (single output scale, as P²Net trains it) and the disparity → depth map."""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from f2depth.geometry import MAX_DEPTH, MIN_DEPTH

#: Decoder channels per level, fine to coarse (Monodepth2).
NUM_CH_DEC = (16, 32, 64, 128, 256)
UPSAMPLE_MODES = ("nearest", "bilinear")


class ConvBlock(nn.Module):
    """Reflection-padded 3×3 convolution followed by ELU."""

    def __init__(self, in_ch: int, out_ch: int) -> None:
        super().__init__()
        self.pad = nn.ReflectionPad2d(1)
        self.conv = nn.Conv2d(in_ch, out_ch, 3)
        self.nonlin = nn.ELU(inplace=True)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.nonlin(self.conv(self.pad(x)))


class DepthDecoder(nn.Module):
    """U-Net decoder with skips: encoder features → sigmoid disparity at full input resolution.

    For level i = 4…0: ``upconv_i_0`` (ConvBlock), ×2 upsampling (``upsample_mode``: "nearest" as in
    training, or "bilinear" with align_corners=False as P²Net's evaluation scripts), concatenation with
    encoder feature i−1 (i > 0), ``upconv_i_1``; then ``dispconv`` (reflection-padded 3×3 conv) + sigmoid.
    forward: features [(B,64,H/2,W/2), …, (B,512,H/32,W/32)] → disp (B,1,H,W) in (0, 1).
    """

    def __init__(self, num_ch_enc=(64, 64, 128, 256, 512), upsample_mode: str = "nearest") -> None:
        super().__init__()
        if upsample_mode not in UPSAMPLE_MODES:
            raise ValueError(f"upsample_mode={upsample_mode!r}: use one of {UPSAMPLE_MODES}")
        self.upsample_mode = upsample_mode
        self.num_ch_enc = tuple(num_ch_enc)
        blocks = {}
        for i in range(4, -1, -1):
            in_ch = self.num_ch_enc[-1] if i == 4 else NUM_CH_DEC[i + 1]
            blocks[f"upconv_{i}_0"] = ConvBlock(in_ch, NUM_CH_DEC[i])
            skip = self.num_ch_enc[i - 1] if i > 0 else 0
            blocks[f"upconv_{i}_1"] = ConvBlock(NUM_CH_DEC[i] + skip, NUM_CH_DEC[i])
        self.convs = nn.ModuleDict(blocks)
        self.disp_pad = nn.ReflectionPad2d(1)
        self.dispconv = nn.Conv2d(NUM_CH_DEC[0], 1, 3)

    def _up(self, x: torch.Tensor) -> torch.Tensor:
        if self.upsample_mode == "nearest":
            return F.interpolate(x, scale_factor=2, mode="nearest")
        return F.interpolate(x, scale_factor=2, mode="bilinear", align_corners=False)

    def forward(self, features: list[torch.Tensor]) -> torch.Tensor:
        x = features[-1]
        for i in range(4, -1, -1):
            x = self._up(self.convs[f"upconv_{i}_0"](x))
            if i > 0:
                x = torch.cat((x, features[i - 1]), dim=1)
            x = self.convs[f"upconv_{i}_1"](x)
        return torch.sigmoid(self.dispconv(self.disp_pad(x)))


def disp_to_depth(disp: torch.Tensor, min_depth: float = MIN_DEPTH,
                  max_depth: float = MAX_DEPTH) -> tuple[torch.Tensor, torch.Tensor]:
    """Monodepth2's map of the sigmoid output to depth.

    disp (B,1,H,W) in [0, 1] → (scaled_disp = 1/max + (1/min − 1/max)·disp, depth = 1/scaled_disp), so
    depth lies in [min_depth, max_depth] metres.
    """
    min_disp = 1.0 / max_depth
    max_disp = 1.0 / min_depth
    scaled = min_disp + (max_disp - min_disp) * disp
    return scaled, 1.0 / scaled


def sigmoid_input_for_depth(depth: float, min_depth: float = MIN_DEPTH,
                            max_depth: float = MAX_DEPTH) -> float:
    """The pre-sigmoid value x whose ``disp_to_depth(sigmoid(x))`` is ``depth`` metres.

    Inverse of ``disp_to_depth``: disp = (1/depth − 1/max) / (1/min − 1/max), x = log(disp / (1 − disp)).
    ``depth`` must lie strictly between min_depth and max_depth (ValueError otherwise).
    """
    if not min_depth < depth < max_depth:
        raise ValueError(f"depth {depth} m must lie strictly between min_depth {min_depth} and "
                         f"max_depth {max_depth}")
    disp = (1.0 / depth - 1.0 / max_depth) / (1.0 / min_depth - 1.0 / max_depth)
    return math.log(disp / (1.0 - disp))
