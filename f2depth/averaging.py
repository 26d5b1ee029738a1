"""Averaging a model's weights over the ends of its last epochs (Polyak & Juditsky, 1992; over epoch ends
as in stochastic weight averaging, Izmailov et al., UAI 2018).

The chairs bootstrap of the flow network (f2depth.flow.bootstrap, ``flow_pretrain.chairs.average_epochs``)
keeps the mean of its last phase-B epochs: at the CPU default's length the network's outputs still swing
from one epoch to the next (docs/flow_pretrain.md), and the mean of the last few epochs' weights is a
steadier teacher than any one of them.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import nn


class WeightAverage:
    """The running mean of a model's floating-point state (parameters and float buffers) over the epoch
    ends it is given: ``add(model)`` after an epoch, ``copy_to(model)`` to load the mean. ``state_dict`` and
    ``load_state_dict`` make it one of the parts of a resume state (f2depth.epochs)."""

    def __init__(self) -> None:
        self.count = 0
        self.mean: dict[str, torch.Tensor] = {}

    @torch.no_grad()
    def add(self, model: nn.Module) -> None:
        self.count += 1
        for name, value in model.state_dict().items():
            if not value.is_floating_point():
                continue
            if name not in self.mean:
                self.mean[name] = value.detach().clone()
            else:
                self.mean[name].add_(value.detach() - self.mean[name], alpha=1.0 / self.count)

    @torch.no_grad()
    def copy_to(self, model: nn.Module) -> None:
        """Load the mean into ``model`` (its integer buffers, if any, stay as they are)."""
        if not self.count:
            raise ValueError("WeightAverage.copy_to: no epoch was added")
        model.load_state_dict({**model.state_dict(), **self.mean})

    def state_dict(self) -> dict[str, Any]:
        return {"count": self.count, "mean": dict(self.mean)}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.count = int(state["count"])
        self.mean = dict(state["mean"])
