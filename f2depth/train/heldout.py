"""Validation on the prepared set's held-out tuples (``prepare.val_share``): what training reports for
scenes without a labeled test set, such as your own video (docs/ingest.md).

Every measured epoch (and before training), on the held-out tuples without augmentation, with the same
fill-up points every time:

* ``heldout_ph``: P²Net's patch photometric loss — the training term L_ph (``f2depth.losses``, minimum
  over the two sources) — with the depth and the poses the networks predict (PoseCNN refining the
  geometric priors when training uses them). Lower is better. Its floor, ``identity_ph``, is the same loss
  with both sources left where they are (identity poses: what a network that sees no camera motion
  scores; a depth is irrelevant then). SC-Depth validates its own videos the same way (its ``val_mode:
  photo``). A low value says the depth *and* the poses explain the held-out frames; it does not measure
  depth alone (a plane with the right poses explains a far wall well).
* With ground truth for every held-out target (the synthetic rooms): ``heldout_a1``, ``heldout_abs_rel`` —
  δ<1.25 and AbsRel, median-scaled per image (``f2depth.train.diagnostics.depth_accuracy``) — the room's own
  held-out frames scored; floor: a constant depth (``constant_depth``).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch
from torch import nn
from torch.utils.data import DataLoader, Subset

from f2depth.formats.prepared import PreparedSet
from f2depth.keypoints import KeypointFile
from f2depth.poses.store import PosePriors
from f2depth.train.data import DataConfig, TupleDataset
from f2depth.train.diagnostics import depth_accuracy
from f2depth.train.step import NetOutput, batch_to, network_forward, photometric_term
from f2depth.train.validate import CACHE_MAX, evaluating

#: The keys :class:`HeldOutValidator` returns (history.csv columns).
HELDOUT_KEYS = ("heldout_ph", "heldout_a1", "heldout_abs_rel")
#: The fill-up points of the held-out tuples: one fixed draw, the same for every seed and epoch.
POINTS_SEED = 0

Predict = Callable[[dict[str, torch.Tensor]], NetOutput]


class HeldOutValidator:
    """``validator(model) → {"heldout_ph"[, "heldout_a1", "heldout_abs_rel"]}`` on at most ``max_tuples``
    evenly spread held-out tuples of ``prepared`` (module docstring)."""

    def __init__(self, prepared: PreparedSet, keypoints: KeypointFile | str, num_points: int,
                 priors: PosePriors | None = None, device: torch.device | str = "cpu",
                 max_tuples: int | None = 20, batch_size: int = 4) -> None:
        self.device = torch.device(device)
        dataset = TupleDataset(prepared, keypoints, DataConfig(num_points=num_points, augment=False),
                               seed=POINTS_SEED, priors=priors, held_out=True)
        n = len(dataset)
        keep = (np.unique(np.linspace(0, n - 1, int(max_tuples)).round().astype(int)).tolist()
                if max_tuples is not None and max_tuples < n else list(range(n)))
        self.tuples = [dataset.tuples[i] for i in keep]
        loader = DataLoader(Subset(dataset, keep), batch_size=batch_size, shuffle=False)
        self._batches = list(loader) if len(keep) <= CACHE_MAX else None
        self._loader = loader
        targets = [t.target for t in self.tuples]
        gts = [prepared.gt(f) for f in targets] if all(prepared.has_gt(f) for f in targets) else None
        self.depth_gt = np.stack([g[0] for g in gts]) if gts else None

    def __len__(self) -> int:
        return len(self.tuples)

    def batches(self):
        return self._batches if self._batches is not None else self._loader

    @torch.no_grad()
    def __call__(self, model: nn.Module) -> dict[str, float]:
        with evaluating(model):
            out = self.score(lambda batch: network_forward(model, batch))
        return out

    @torch.no_grad()
    def score(self, predict: Predict) -> dict[str, float]:
        """The held-out metrics of any ``predict(batch) → NetOutput`` (depth (B,1,H,W) metres, T_prev /
        T_next (B,4,4) src_T_tgt)."""
        total, count, depths = 0.0, 0, []
        for batch in self.batches():
            batch = batch_to(batch, self.device)
            net = predict(batch)
            total += float(photometric_term(batch, net.depth, net.T_prev, net.T_next)) * len(net.depth)
            count += len(net.depth)
            depths.append(net.depth[:, 0].float().cpu().numpy())
        out = {"heldout_ph": total / count}
        if self.depth_gt is not None:
            acc = depth_accuracy(np.concatenate(depths), self.depth_gt)
            out.update(heldout_a1=acc["train_a1"], heldout_abs_rel=acc["train_abs_rel"])
        return out

    def floors(self) -> dict[str, float | None]:
        """``identity_ph`` (both sources unwarped) and, with ground truth, the constant depth's δ1 and
        AbsRel (median scaling makes every constant the same)."""
        def still(batch: dict[str, torch.Tensor]) -> NetOutput:
            b, _, h, w = batch["target"].shape
            depth = torch.ones(b, 1, h, w, device=self.device)
            eye = torch.eye(4, device=self.device).expand(b, 4, 4)
            return NetOutput(depth, depth, eye, eye)

        s = self.score(still)
        return {"identity_ph": s["heldout_ph"], "constant_a1": s.get("heldout_a1"),
                "constant_abs_rel": s.get("heldout_abs_rel")}

