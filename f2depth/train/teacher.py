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

**Memo** (``memo_mb``, params.yaml ``train_depth.teacher_memo_mb``). The network is frozen and its inputs
are the un-augmented frames, so a training pair's outputs are the same in every epoch: with a budget the
teacher keeps each pair's outputs, keyed by a digest of the two images' bytes (never by a dataset index, so
no other set can be served a wrong entry), and runs the network only on the pairs of a batch it has not
seen. The CPU default's 24 tuples (48 with flips, 0.8 MB each at 96×128) fit in a few tens of MB and the
network then runs in the first epochs only; a set larger than the budget keeps the first pairs it meets.
A pair first met in another batch gives the outputs of that batch's run, which may differ from this
batch's in float rounding only (PWC-Lite has no batch statistics).
"""

from __future__ import annotations

import hashlib
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
    never see it. ``memo_mb`` > 0 keeps each pair's outputs up to that many MB (module docstring).
    """

    def __init__(self, net: FlowNetwork, device: str | torch.device = "cpu", memo_mb: float = 0.0) -> None:
        self.net = net.to(device).eval()
        for p in self.net.parameters():
            p.requires_grad_(False)
        self.device = torch.device(device)
        self.memo_bytes = int(memo_mb * 2**20)
        self.memo: dict[bytes, _Entry] = {}
        self.memo_used = 0  # bytes held
        self.memo_hits = 0  # pairs served from the memo

    @classmethod
    def load(cls, path: str | os.PathLike, device: str | torch.device = "cpu", memo_mb: float = 0.0
             ) -> FlowTeacher:
        """From one of our ``models/flow_*.pt`` (or an ARFlow checkpoint), via ``load_flow_model``."""
        return cls(load_flow_model(path), device, memo_mb)

    @torch.no_grad()
    def __call__(self, target: torch.Tensor, source: torch.Tensor, features: bool = True) -> TeacherOutput:
        """target, source (B,3,H,W) RGB in [0, 1] → TeacherOutput."""
        if self.memo_bytes <= 0:
            return self._run(target, source, features)
        keys = [_pair_key(t, s, features) for t, s in zip(target, source)]
        missing = [i for i, key in enumerate(keys) if key not in self.memo]
        fresh: dict[bytes, _Entry] = {}
        if missing:
            index = torch.tensor(missing, device=target.device)
            out = self._run(target[index], source[index], features)
            for j, i in enumerate(missing):
                entry = _Entry(out.flow[j].clone(), [f[j].clone() for f in out.feats_tgt],
                               [f[j].clone() for f in out.feats_src])
                fresh[keys[i]] = entry
                if self.memo_used + entry.nbytes <= self.memo_bytes:
                    self.memo[keys[i]] = entry
                    self.memo_used += entry.nbytes
            if len(missing) == len(keys):
                return out
        entries = [fresh.get(key) or self.memo[key] for key in keys]
        self.memo_hits += len(keys) - len(missing)
        levels = len(entries[0].feats_tgt)
        return TeacherOutput(torch.stack([e.flow for e in entries]),
                             [torch.stack([e.feats_tgt[k] for e in entries]) for k in range(levels)],
                             [torch.stack([e.feats_src[k] for e in entries]) for k in range(levels)])

    def _run(self, target: torch.Tensor, source: torch.Tensor, features: bool) -> TeacherOutput:
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


@dataclass
class _Entry:
    """One pair's outputs in the memo: flow (2,H,W), pyramid levels (C_l,h_l,w_l)."""

    flow: torch.Tensor
    feats_tgt: list[torch.Tensor]
    feats_src: list[torch.Tensor]

    @property
    def nbytes(self) -> int:
        return sum(t.numel() * t.element_size() for t in (self.flow, *self.feats_tgt, *self.feats_src))


def _pair_key(target: torch.Tensor, source: torch.Tensor, features: bool) -> bytes:
    """A digest of one pair's two images (3,H,W) — dtype, shape and bytes — and whether features are kept."""
    h = hashlib.blake2b(digest_size=16)
    for image in (target, source):
        h.update(f"{image.dtype}{tuple(image.shape)}".encode())
        h.update(image.detach().contiguous().cpu().view(torch.uint8).numpy().tobytes())
    h.update(b"f" if features else b"-")
    return h.digest()
