"""An inference copy of a DepthModel: every BatchNorm folded into the convolution before it, and the depth
decoder's nearest ×2 upsampling folded into the convolution that reads it.

In eval mode a BatchNorm is an affine map per channel, ``y = γ (x − μ) / √(σ² + ε) + β``, so after a
convolution ``x = W ∗ u + b`` it folds into that convolution: ``W' = W · s``, ``b' = (b − μ) · s + β`` with
``s = γ / √(σ² + ε)`` per output channel. The copy computes the same depth (to float rounding, ~1e-6
relative) without the BatchNorm passes over the encoder's activations; the training model is untouched.

Each ``upconv_i_1`` of Monodepth2's decoder is a 3×3 convolution of ``reflection_pad(cat(up(x), skip))``
with ``up`` the nearest ×2 upsampling. Its part on ``up(x)`` needs no upsampled tensor: the output pixel
``(2i+a, 2j+b)`` reads low-resolution rows ``i−1, i`` (a = 0) or ``i, i+1`` (a = 1), with the 3×3 kernel's
rows summed to two (``[w0, w1+w2]`` or ``[w0+w1, w2]``), and the same for columns; reflection padding of
the upsampled map is replicate padding of ``x``. So the four output phases are one 2×2 convolution of the
replicate-padded ``x`` with 4× the output channels (:func:`phase_kernels`), 16 instead of 36 products
per output and input channel at a quarter of the positions; the skip part stays a 3×3 convolution at full
resolution, and the phases are added into its output (:class:`InferenceDecoder`). The same depth to float
rounding (~1e-6 relative); docs/experiments/2026-12-06-speed-cuts.md has the timings.
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


PHASES = ((0, 0), (0, 1), (1, 0), (1, 1))


def phase_kernels(weight: torch.Tensor) -> torch.Tensor:
    """A 3×3 kernel ``(O,C,3,3)`` applied to a nearest-×2-upsampled input → the ``(4O,C,2,2)`` kernel of its
    four output phases on the input itself (module docstring), phase ``(a, b)`` of :data:`PHASES` in
    channels ``[k·O, (k+1)·O)``."""
    def halves(w: torch.Tensor, phase: int, dim: int) -> torch.Tensor:
        w0, w1, w2 = w.unbind(dim)
        pair = (w0, w1 + w2) if phase == 0 else (w0 + w1, w2)
        return torch.stack(pair, dim)

    return torch.cat([halves(halves(weight, a, 2), b, 3) for a, b in PHASES], 0)


class InferenceDecoder(nn.Module):
    """A nearest-upsampling :class:`~f2depth.depth.decoder.DepthDecoder` with each ``upconv_i_1``'s
    upsampling folded into its convolution (module docstring); the same submodules and parameter names (the
    phase kernels are buffers outside the state dict, made when the decoder is built).

    forward: features [(B,64,H/2,W/2), …, (B,512,H/32,W/32)] → disp (B,1,H,W) in (0, 1)."""

    def __init__(self, decoder: DepthDecoder) -> None:
        super().__init__()
        if decoder.upsample_mode != "nearest":
            raise ValueError(f"InferenceDecoder: only nearest upsampling, got {decoder.upsample_mode!r}")
        self.upsample_mode, self.num_ch_enc = decoder.upsample_mode, decoder.num_ch_enc
        self.convs, self.dispconv = decoder.convs, decoder.dispconv
        with torch.no_grad():
            for i in range(5):
                conv = self.convs[f"upconv_{i}_1"].conv
                up = self.convs[f"upconv_{i}_0"].conv.out_channels  # channels of up(x); the rest: the skip
                self.register_buffer(f"phase_{i}", phase_kernels(conv.weight[:, :up]), persistent=False)
                if i > 0:  # upconv_0_1 reads no skip
                    self.register_buffer(f"skip_{i}", conv.weight[:, up:].clone(), persistent=False)

    def upconv(self, i: int, x: torch.Tensor, skip: torch.Tensor | None) -> torch.Tensor:
        """``upconv_i_1``'s convolution (before its ELU) of ``reflection_pad(cat(up(x), skip))``:
        ``x (B,C,h,w)``, ``skip (B,S,2h,2w)`` or None → ``(B,O,2h,2w)``."""
        bias = self.convs[f"upconv_{i}_1"].conv.bias
        b, _, h, w = x.shape
        if skip is not None and tuple(skip.shape[-2:]) != (2 * h, 2 * w):
            raise ValueError(f"InferenceDecoder: skip of {tuple(skip.shape)} does not match 2× "
                             f"{tuple(x.shape)}")
        o = bias.shape[0]
        x = F.pad(x, (1, 1, 1, 1), mode="replicate")
        if skip is None:  # the phases are the whole output: the bias goes into them
            phases = F.conv2d(x, getattr(self, f"phase_{i}"), bias.repeat(4))  # (B,4O,h+1,w+1)
            out = torch.empty(b, o, 2 * h, 2 * w, dtype=x.dtype, device=x.device,
                              memory_format=torch.channels_last)
        else:
            phases = F.conv2d(x, getattr(self, f"phase_{i}"))
            out = F.conv2d(F.pad(skip, (1, 1, 1, 1), mode="reflect"), getattr(self, f"skip_{i}"), bias)
        for k, (a, c) in enumerate(PHASES):
            at, part = out[:, :, a::2, c::2], phases[:, k * o:(k + 1) * o, a:a + h, c:c + w]
            if skip is None:
                at.copy_(part)
            else:
                at.add_(part)
        return out

    def forward(self, features: list[torch.Tensor]) -> torch.Tensor:
        x = features[-1]
        for i in range(4, -1, -1):
            first, second = self.convs[f"upconv_{i}_0"], self.convs[f"upconv_{i}_1"]
            x = first.nonlin(first.conv(F.pad(x, (1, 1, 1, 1), mode="reflect")))
            x = second.nonlin(self.upconv(i, x, features[i - 1] if i > 0 else None))
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
