"""The frozen flow network that supervises depth training (the paper §3.2, §3.3): any
:class:`~f2depth.flow.network.FlowNetwork`, rebuilt from its checkpoint (PWC-Lite in the paper).

Eval mode, ``requires_grad=False`` on every weight and ``torch.no_grad`` around every call: nothing
reaches its weights and it keeps no autograd graph. Per batch it computes, once:

* the flow target (frame 0) → source (+1) at the input resolution: the finest level of the network's
  forward flow. PWC-Lite needs H and W to be multiples of 64; for other sizes ``PWCLite.forward`` resizes
  both images bilinearly up to the next multiples of 64, runs there, and resizes the flow back with its
  u, v rescaled (ARFlow's protocol; 96×128 runs at 128×128, 288×384 at 320×384);
* the network's feature pyramid (PWC-Lite: six levels, 16…192 channels, finest first) of both frames,
  computed on the images at the training size as given (PWC-Lite: level i is ⌈H/2^(i+1)⌉ × ⌈W/2^(i+1)⌉);
  ``feature_synthesis_loss`` resizes the rigid flow to each level. This is a second pass of PWC-Lite's
  feature extractor: the pyramid inside ``forward`` belongs to the 64-multiple-resized images, which
  differ from the training-size frames at 96×128 and 288×384 (the extra pass is a small share of the
  teacher's time).

Inputs are the un-augmented (but flipped) frames: like every other loss input, the supervision sees the
real colours. Outputs are float32 whatever autocast is active.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import torch

from f2depth.flow import FlowNetwork, load_flow_model


@dataclass
class TeacherOutput:
    """flow (B,2,H,W) pixels, x first, target → source; feats_tgt / feats_src: the pyramid levels
    (B,C_l,h_l,w_l) (PWC-Lite: six) or empty lists when features were not requested."""

    flow: torch.Tensor
    feats_tgt: list[torch.Tensor]
    feats_src: list[torch.Tensor]


class FlowTeacher:
    """Callable wrapper: ``teacher(target, source, features=True) → TeacherOutput``.

    Not an ``nn.Module`` on purpose: ``model.train()``, optimizers, DDP and checkpoints of the depth model
    never see it.
    """

    def __init__(self, net: FlowNetwork, device: str | torch.device = "cpu") -> None:
        self.net = net.to(device).eval()
        for p in self.net.parameters():
            p.requires_grad_(False)
        self.device = torch.device(device)

    @classmethod
    def load(cls, path: str | os.PathLike, device: str | torch.device = "cpu") -> FlowTeacher:
        """From one of our ``models/flow_*.pt`` (or an ARFlow checkpoint), via ``load_flow_model``."""
        return cls(load_flow_model(path), device)

    @torch.no_grad()
    def __call__(self, target: torch.Tensor, source: torch.Tensor, features: bool = True) -> TeacherOutput:
        """target, source (B,3,H,W) RGB in [0, 1] → TeacherOutput."""
        self.net.eval()
        flows, _ = self.net(target, source, with_backward=False)
        flow = flows[0].float().contiguous()
        if not features:
            return TeacherOutput(flow, [], [])
        both = self.net.features(torch.cat((target, source), dim=0))
        b = target.shape[0]
        feats_tgt = [f[:b].float().contiguous() for f in both]
        feats_src = [f[b:].float().contiguous() for f in both]
        return TeacherOutput(flow, feats_tgt, feats_src)
