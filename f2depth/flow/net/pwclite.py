"""PWC-Lite, the flow network of ARFlow (Liu et al., CVPR 2020; ARFlow's ``models/pwclite.py``).

Module and parameter names, shapes and registration order equal ARFlow's (2-frame model,
``reduce_dense=True``, ``upsample=True``), so ARFlow ``state_dict``s load by name *and* by position
(60 tensors, 2,236,660 parameters).

Inputs are RGB images in [0, 1] without normalisation. ARFlow needs H and W to be multiples of 64; for
other sizes :meth:`PWCLite.forward` bilinearly resizes both images (``align_corners=True``) up to the next
multiples of 64, runs the network there, and resizes every output flow back with its u and v components
rescaled by the width and height ratios — ARFlow's own evaluation protocol (Sintel 436×1024 → 448×1024,
``resize_flow``). Sizes that are already multiples of 64 are processed untouched.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from f2depth.flow.net.correlation import correlation
from f2depth.flow.net.network import FlowNetwork
from f2depth.geometry import resize_flow, warp

PYRAMID_CHANNELS = (16, 32, 64, 96, 128, 192)
N_FLOWS = 5  # decoded levels: 1/64 ... 1/4
MULTIPLE = 64
CORR_CHANNELS = 81


def conv(ch_in: int, ch_out: int, kernel_size: int = 3, stride: int = 1, dilation: int = 1,
         relu: bool = True) -> nn.Sequential:
    """ARFlow's ``conv``: Conv2d (bias, 'same' padding) + LeakyReLU(0.1); the Sequential gives the ``.0.``."""
    layers: list[nn.Module] = [nn.Conv2d(ch_in, ch_out, kernel_size, stride, dilation=dilation, bias=True,
                                         padding=((kernel_size - 1) * dilation) // 2)]
    if relu:
        layers.append(nn.LeakyReLU(0.1, inplace=True))
    return nn.Sequential(*layers)


class FeatureExtractor(nn.Module):
    """Six levels of (stride-2 conv, conv), channels 3→16→32→64→96→128→192; returns finest first."""

    def __init__(self, channels: tuple[int, ...] = (3, *PYRAMID_CHANNELS)) -> None:
        super().__init__()
        self.convs = nn.ModuleList(nn.Sequential(conv(c_in, c_out, stride=2), conv(c_out, c_out))
                                   for c_in, c_out in zip(channels[:-1], channels[1:]))

    def forward(self, img: torch.Tensor) -> list[torch.Tensor]:
        """``img (B,3,H,W)`` → six maps, level i ``(B, C_i, ⌈H/2^(i+1)⌉, ⌈W/2^(i+1)⌉)``, finest first."""
        feats = []
        x = img
        for block in self.convs:
            x = block(x)
            feats.append(x)
        return feats


class FlowEstimatorReduce(nn.Module):
    """ARFlow's shared decoder: 'reduced' dense connections, returns (32-channel features, flow residual)."""

    feat_dim = 32

    def __init__(self, ch_in: int) -> None:
        super().__init__()
        self.conv1 = conv(ch_in, 128)
        self.conv2 = conv(128, 128)
        self.conv3 = conv(128 + 128, 96)
        self.conv4 = conv(128 + 96, 64)
        self.conv5 = conv(96 + 64, 32)
        self.predict_flow = conv(64 + 32, 2, relu=False)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        x1 = self.conv1(x)
        x2 = self.conv2(x1)
        x3 = self.conv3(torch.cat([x1, x2], 1))
        x4 = self.conv4(torch.cat([x2, x3], 1))
        x5 = self.conv5(torch.cat([x3, x4], 1))
        return x5, self.predict_flow(torch.cat([x4, x5], 1))


class ContextNetwork(nn.Module):
    """Dilated context network (dilations 1, 2, 4, 8, 16, 1, 1), shared by all levels → flow residual."""

    def __init__(self, ch_in: int) -> None:
        super().__init__()
        spec = [(ch_in, 128, 1), (128, 128, 2), (128, 128, 4), (128, 96, 8), (96, 64, 16), (64, 32, 1)]
        layers = [conv(c_in, c_out, dilation=d) for c_in, c_out, d in spec]
        layers.append(conv(32, 2, relu=False))
        self.convs = nn.Sequential(*layers)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.convs(x)


class PWCLite(FlowNetwork):
    """ARFlow's 2-frame PWC-Lite, the :class:`~f2depth.flow.net.network.FlowNetwork` named ``pwclite``.

    ``flows_fw, flows_bw = model(img1, img2, with_backward=True)``: images ``(B,3,H,W)`` in [0, 1] →
    two lists of five flows ``(B,2,h_i,w_i)``, finest first, level i at ``(⌈H/2^i⌉, ⌈W/2^i⌉)`` in pixels of
    its own resolution (level 0: input resolution, input pixels). ``flows_bw`` is frame 2 → frame 1 and
    is ``None`` when ``with_backward=False``.

    ``channels_last`` (default) keeps weights and activations in NHWC strides, which oneDNN's CPU
    convolutions run about 25 % faster; the results differ from NCHW only by float rounding (the
    reference outputs are matched within 1e-4 either way). It is a memory layout, not architecture:
    ``architecture()`` is empty and a model rebuilt from a checkpoint is channels-last.

    The pyramid that ``forward`` decodes is computed on the images resized to multiples of 64, so it
    equals :meth:`features` of the input only when H and W already are multiples of 64.
    """

    def __init__(self, channels_last: bool = True) -> None:
        super().__init__()
        self.feature_pyramid_extractor = FeatureExtractor()
        ch_in = 32 + CORR_CHANNELS + 2
        self.flow_estimators = FlowEstimatorReduce(ch_in)
        self.context_networks = ContextNetwork(FlowEstimatorReduce.feat_dim + 2)
        self.conv_1x1 = nn.ModuleList(conv(c, 32, kernel_size=1) for c in PYRAMID_CHANNELS[::-1][:N_FLOWS])
        self.leaky_relu = nn.LeakyReLU(0.1, inplace=True)
        self.memory_format = torch.channels_last if channels_last else torch.contiguous_format
        self.to(memory_format=self.memory_format)

    def features(self, img: torch.Tensor) -> list[torch.Tensor]:
        """The six pyramid levels of ``img (B,3,H,W)`` in [0,1], finest first (16, 32, 64, 96, 128, 192 ch).

        Computed on the image as given (any size): level i is ``(⌈H/2^(i+1)⌉, ⌈W/2^(i+1)⌉)``.
        """
        return self.feature_pyramid_extractor(img.contiguous(memory_format=self.memory_format))

    def flow_levels(self) -> int:
        return N_FLOWS

    def feature_module(self) -> nn.Module:
        return self.feature_pyramid_extractor

    def flow_heads(self) -> list[nn.Conv2d]:
        """The decoder's ``predict_flow`` and the context network's last convolution."""
        return [self.flow_estimators.predict_flow[0], self.context_networks.convs[-1][0]]

    def decode(self, pyr1: list[torch.Tensor], pyr2: list[torch.Tensor]) -> list[torch.Tensor]:
        """ARFlow ``forward_2_frames`` on two pyramids (finest first) → five flows 1/4…1/64, finest first."""
        flow: torch.Tensor | None = None
        flows = []
        for level in range(N_FLOWS):
            x1 = pyr1[len(pyr1) - 1 - level]
            x2 = pyr2[len(pyr2) - 1 - level]
            if flow is None:
                b, _, h, w = x1.shape
                flow = x1.new_zeros(b, 2, h, w)
                x2_warped = x2
            else:
                flow = F.interpolate(flow * 2, scale_factor=2, mode="bilinear", align_corners=True)
                x2_warped = warp(x2, flow)
            cost = self.leaky_relu(correlation(x1, x2_warped))
            feat, dflow = self.flow_estimators(torch.cat([cost, self.conv_1x1[level](x1), flow], 1))
            flow = flow + dflow
            flow = flow + self.context_networks(torch.cat([feat, flow], 1))
            flows.append(flow)
        return flows[::-1]

    def forward(self, img1: torch.Tensor, img2: torch.Tensor, with_backward: bool = True
                ) -> tuple[list[torch.Tensor], list[torch.Tensor] | None]:
        if img1.shape != img2.shape or img1.dim() != 4 or img1.shape[1] != 3:
            raise ValueError(f"PWCLite: expected two (B,3,H,W) images, got {tuple(img1.shape)} and "
                             f"{tuple(img2.shape)}")
        b, _, h, w = img1.shape
        size = (-(-h // MULTIPLE) * MULTIPLE, -(-w // MULTIPLE) * MULTIPLE)
        x = torch.cat([img1, img2], 0)
        if size != (h, w):
            x = F.interpolate(x, size=size, mode="bilinear", align_corners=True)
        x = x.contiguous(memory_format=self.memory_format)
        pyr = self.feature_pyramid_extractor(x)
        first = [p[:b] for p in pyr]
        second = [p[b:] for p in pyr]
        if with_backward:  # both directions in one batch of 2B through the shared decoder
            flows = self.decode(pyr, [torch.cat([s, f], 0) for f, s in zip(first, second)])
        else:
            flows = self.decode(first, second)
        outs = []
        for i, f in enumerate(flows):
            f = F.interpolate(f * 4, scale_factor=4, mode="bilinear", align_corners=True)
            if size != (h, w):
                f = resize_flow(f, (-(-h // 2**i), -(-w // 2**i)))
            outs.append(f)
        if not with_backward:
            return outs, None
        return [f[:b] for f in outs], [f[b:] for f in outs]
