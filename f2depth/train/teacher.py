"""The frozen flow network that supervises depth training (the paper §3.2, §3.3): any
:class:`~f2depth.flow.net.network.FlowNetwork`, rebuilt from its checkpoint (PWC-Lite in the paper).

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
from f2depth.flow.loss import non_occluded_by_consistency


@dataclass
class TeacherOutput:
    """flow (B,2,H,W) pixels, x first, target → source; feats_tgt / feats_src: the pyramid levels
    (B,C_l,h_l,w_l) (PWC-Lite: six) or empty lists when features were not requested; valid (B,1,H,W) {0, 1}:
    where the network's flows target → source and back agree (``consistency_mask``), None: everywhere."""

    flow: torch.Tensor
    feats_tgt: list[torch.Tensor]
    feats_src: list[torch.Tensor]
    valid: torch.Tensor | None = None


class FlowTeacher:
    """Callable wrapper: ``teacher(target, source, features=True) → TeacherOutput``.

    Not an ``nn.Module`` on purpose: ``model.train()``, optimizers, DDP and checkpoints of the depth model
    never see it. ``memo_mb`` > 0 keeps each pair's outputs up to that many MB (module docstring).
    ``consistency_mask``: also run the flow source → target and mark where the two disagree (ARFlow's
    forward–backward check, :func:`f2depth.flow.loss.non_occluded_by_consistency`) as not valid.
    """

    def __init__(self, net: FlowNetwork, device: str | torch.device = "cpu", memo_mb: float = 0.0,
                 consistency_mask: bool = False) -> None:
        self.consistency_mask = consistency_mask
        self.net = net.to(device).eval()
        for p in self.net.parameters():
            p.requires_grad_(False)
        self.device = torch.device(device)
        self.memo_bytes = int(memo_mb * 2**20)
        self.memo: dict[bytes, _Entry] = {}
        self.memo_used = 0  # bytes held
        self.memo_hits = 0  # pairs served from the memo

    @classmethod
    def load(cls, path: str | os.PathLike, device: str | torch.device = "cpu", memo_mb: float = 0.0,
             consistency_mask: bool = False) -> FlowTeacher:
        """From one of our ``models/flow_*.pt`` (or an ARFlow checkpoint), via ``load_flow_model``."""
        return cls(load_flow_model(path), device, memo_mb, consistency_mask)

    @torch.no_grad()
    def __call__(self, target: torch.Tensor, source: torch.Tensor, features: bool = True) -> TeacherOutput:
        """target, source (B,3,H,W) RGB in [0, 1] → TeacherOutput."""
        if self.memo_bytes <= 0:
            return self._run(target, source, features)
        keys = _pair_keys(target, source, features)
        missing = [i for i, key in enumerate(keys) if key not in self.memo]
        self.memo_hits += len(keys) - len(missing)
        if not missing:
            return _stack([self.memo[key] for key in keys])
        whole = len(missing) == len(keys)
        out = self._run(target if whole else target[missing], source if whole else source[missing], features)
        ran = {i: _Entry(out.flow[j], [f[j] for f in out.feats_tgt], [f[j] for f in out.feats_src],
                         None if out.valid is None else out.valid[j])
               for j, i in enumerate(missing)}
        for i, entry in ran.items():
            self._keep(keys[i], entry)
        if whole:
            return out
        return _stack([ran[i] if i in ran else self.memo[key] for i, key in enumerate(keys)])

    @torch.no_grad()
    def flow(self, target: torch.Tensor, source: torch.Tensor) -> torch.Tensor:
        """target, source (B,3,H,W) RGB in [0, 1] → the flow target → source (B,2,H,W) pixels, x first,
        computed now: the memo is neither read nor filled (a diagnosis must not change what training is
        served)."""
        return self._run(target, source, features=False).flow

    def _keep(self, key: bytes, entry: _Entry) -> None:
        """Memoise a copy of ``entry`` (views of a batch) when the budget has room and the key is new."""
        if key not in self.memo and self.memo_used + entry.nbytes <= self.memo_bytes:
            self.memo[key] = _Entry(entry.flow.clone(), [f.clone() for f in entry.feats_tgt],
                                    [f.clone() for f in entry.feats_src],
                                    None if entry.valid is None else entry.valid.clone())
            self.memo_used += entry.nbytes

    def _run(self, target: torch.Tensor, source: torch.Tensor, features: bool) -> TeacherOutput:
        self.net.eval()
        flows, back = self.net(target, source, with_backward=self.consistency_mask)
        flow = flows[0].float().contiguous()
        valid = None
        if self.consistency_mask:
            valid = non_occluded_by_consistency(flow, back[0].float())[0].contiguous()
        if not features:
            return TeacherOutput(flow, [], [], valid)
        both = self.net.features(torch.cat((target, source), dim=0))
        b = target.shape[0]
        feats_tgt = [f[:b].float().contiguous() for f in both]
        feats_src = [f[b:].float().contiguous() for f in both]
        return TeacherOutput(flow, feats_tgt, feats_src, valid)


@dataclass
class _Entry:
    """One pair's outputs in the memo: flow (2,H,W), pyramid levels (C_l,h_l,w_l)."""

    flow: torch.Tensor
    feats_tgt: list[torch.Tensor]
    feats_src: list[torch.Tensor]
    valid: torch.Tensor | None

    @property
    def nbytes(self) -> int:
        mask = () if self.valid is None else (self.valid,)
        return sum(t.numel() * t.element_size() for t in (self.flow, *self.feats_tgt, *self.feats_src, *mask))


def _stack(entries: list[_Entry]) -> TeacherOutput:
    """One batch of memo entries, in order."""
    levels = range(len(entries[0].feats_tgt))
    valid = None if entries[0].valid is None else torch.stack([e.valid for e in entries])
    return TeacherOutput(torch.stack([e.flow for e in entries]),
                         [torch.stack([e.feats_tgt[k] for e in entries]) for k in levels],
                         [torch.stack([e.feats_src[k] for e in entries]) for k in levels], valid)


def _pair_keys(target: torch.Tensor, source: torch.Tensor, features: bool) -> list[bytes]:
    """A digest per pair of the batch ``target``, ``source`` (B,3,H,W): the images' dtype, shape and bytes and
    whether features are kept. One host copy per batch (none on a CPU)."""
    target, source = (x.detach().contiguous().cpu() for x in (target, source))
    head = f"{target.dtype}{tuple(target.shape[1:])}{source.dtype}{tuple(source.shape[1:])}{features}"
    keys = []
    for t, s in zip(target, source):
        h = hashlib.blake2b(head.encode(), digest_size=16)
        h.update(t.view(torch.uint8).numpy())
        h.update(s.view(torch.uint8).numpy())
        keys.append(h.digest())
    return keys
