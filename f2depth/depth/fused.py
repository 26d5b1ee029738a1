"""An inference copy of a DepthModel: every BatchNorm folded into the convolution before it, and the depth
decoder's nearest ×2 upsampling, skip concatenation and reflection padding written as one pass.

In eval mode a BatchNorm is an affine map per channel, ``y = γ (x − μ) / √(σ² + ε) + β``, so after a
convolution ``x = W ∗ u + b`` it folds into that convolution: ``W' = W · s``, ``b' = (b − μ) · s + β`` with
``s = γ / √(σ² + ε)`` per output channel. The copy computes the same depth (to float rounding, ~1e-6
relative) without the BatchNorm passes over the encoder's activations; the training model is untouched.

Each ``upconv_i_1`` of Monodepth2's decoder reads ``reflection_pad(cat(upsample(x), skip))``: three passes
that copy the same values. :class:`InferenceDecoder` writes the upsampled ``x`` and the skip features once
into a padded buffer and fills its one-pixel border by reflection: bit-identical values, two passes over
the decoder's largest tensors fewer (at 288×384 on one thread the decoder took 80 ms instead of 92;
docs/experiments/2026-12-06-inference-decoder.md).
"""

from __future__ import annotations

import copy

import torch
import torch.nn.functional as F
from torch import nn

from f2depth.depth.decoder import DepthDecoder
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


def upsample_concat_pad(x: torch.Tensor, skip: torch.Tensor | None) -> torch.Tensor:
    """``reflection_pad(cat(nearest_upsample_2x(x), skip), 1)`` in one buffer (channels-last strides).

    ``x (B,C1,h,w)``, ``skip (B,C2,2h,2w)`` or None → ``(B,C1+C2,2h+2,2w+2)``."""
    b, c1, h, w = x.shape
    hh, ww = 2 * h, 2 * w
    c2 = 0 if skip is None else skip.shape[1]
    if skip is not None and tuple(skip.shape[-2:]) != (hh, ww):
        raise ValueError(f"upsample_concat_pad: skip of {tuple(skip.shape)} does not match 2× "
                         f"{tuple(x.shape)}")
    out = torch.empty(b, c1 + c2, hh + 2, ww + 2, dtype=x.dtype, device=x.device,
                      memory_format=torch.channels_last)
    inner = out[:, :c1, 1 : hh + 1, 1 : ww + 1].unflatten(2, (h, 2)).unflatten(4, (w, 2))
    inner.copy_(x[:, :, :, None, :, None].expand(b, c1, h, 2, w, 2))
    if skip is not None:
        out[:, c1:, 1 : hh + 1, 1 : ww + 1] = skip
    out[:, :, 0, 1 : ww + 1] = out[:, :, 2, 1 : ww + 1]  # reflection: padded row 0 = image row 1
    out[:, :, hh + 1, 1 : ww + 1] = out[:, :, hh - 1, 1 : ww + 1]
    out[:, :, :, 0] = out[:, :, :, 2]
    out[:, :, :, ww + 1] = out[:, :, :, ww - 1]
    return out


class InferenceDecoder(nn.Module):
    """A nearest-upsampling :class:`~f2depth.depth.decoder.DepthDecoder` run with
    :func:`upsample_concat_pad` (module docstring); the same submodules and parameter names.

    forward: features [(B,64,H/2,W/2), …, (B,512,H/32,W/32)] → disp (B,1,H,W) in (0, 1)."""

    def __init__(self, decoder: DepthDecoder) -> None:
        super().__init__()
        if decoder.upsample_mode != "nearest":
            raise ValueError(f"InferenceDecoder: only nearest upsampling, got {decoder.upsample_mode!r}")
        self.upsample_mode, self.num_ch_enc = decoder.upsample_mode, decoder.num_ch_enc
        self.convs, self.dispconv = decoder.convs, decoder.dispconv

    def forward(self, features: list[torch.Tensor]) -> torch.Tensor:
        x = features[-1]
        for i in range(4, -1, -1):
            first, second = self.convs[f"upconv_{i}_0"], self.convs[f"upconv_{i}_1"]
            x = first.nonlin(first.conv(F.pad(x, (1, 1, 1, 1), mode="reflect")))
            x = second.nonlin(second.conv(upsample_concat_pad(x, features[i - 1] if i > 0 else None)))
        return torch.sigmoid(self.dispconv(F.pad(x, (1, 1, 1, 1), mode="reflect")))


class ContiguousInput(nn.Sequential):
    """An ``nn.Sequential`` fed NCHW (contiguous) tensors whatever layout its input comes in; its modules
    and parameter names are those of the Sequential it wraps."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return super().forward(x.contiguous())


def cpu_layout(model: DepthModel) -> DepthModel:
    """Set the memory layout of an inference copy for a CPU, in place → ``model``: channels-last weights
    (oneDNN's faster layout for the depth network), except the depth encoder's ``layer4``, which runs in
    NCHW: at 1/32 of the input (9×12 at 288×384) oneDNN's NCHW convolutions beat its channels-last ones.
    Measured at 288×384, batch 1, one thread, ten interleaved rounds: 152.1 against 155.2 ms (best of
    each; docs/experiments/2026-12-06-speed-cuts.md)."""
    model.to(memory_format=torch.channels_last)
    encoder = model.depth_encoder
    encoder.layer4 = ContiguousInput(*encoder.layer4).to(memory_format=torch.contiguous_format)
    return model


def inference_copy(model: DepthModel) -> DepthModel:
    """A deep copy of ``model`` in eval mode with its encoders' BatchNorms folded and, with nearest
    upsampling, the :class:`InferenceDecoder` (module docstring); only for inference (the copy has no
    BatchNorm statistics to train)."""
    out = copy.deepcopy(model).eval()
    for net in (out.depth_encoder, out.pose_encoder):
        _fold_resnet(net)
    if out.depth_decoder.upsample_mode == "nearest":
        out.depth_decoder = InferenceDecoder(out.depth_decoder)
    return out
