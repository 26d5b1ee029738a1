"""The paper's piecewise-constant learning rate, scaled to the epoch count of a run.

F²Depth (the paper §4.1): 1e-4 for 27 epochs, 1e-5 for the next 15, 1e-6 for the last 2 (44 epochs);
``train_depth.lr`` holds the rates and ``train_depth.lr_epochs`` the epochs spent at each. When a run has a
different number of epochs the phase boundaries are scaled proportionally and rounded:

* boundary k (end of phase k) = ``round(epochs · (e_1 + … + e_k) / (e_1 + … + e_n))`` (round half to
  even, Python's ``round``), so the phase lengths always add up to ``epochs``;
* when ``epochs`` ≥ the number of phases, a phase that rounds to 0 epochs takes one epoch from the
  longest phase (the latest of equally long ones), so every rate is used for at least one epoch;
* with fewer epochs than phases the later phases are dropped (their length stays 0).

Examples with the paper's phases: 44 → [27, 15, 2]; 8 → [4, 3, 1]; 3 → [1, 1, 1]; 2 → [1, 1, 0].
The rate is constant within an epoch (set at the start of each epoch, epochs counted from 0).

:func:`flow_weight_factor` is the other schedule of a run: the factor on the flow terms' weights
(``train_depth.flow_fade_epochs``; docs/method.md §9).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass


def scale_phases(lr_epochs: Sequence[int], epochs: int) -> list[int]:
    """Phase lengths for a run of ``epochs`` epochs (module docstring). lr_epochs: the paper's lengths."""
    lengths = [int(e) for e in lr_epochs]
    if not lengths or any(e < 0 for e in lengths) or sum(lengths) == 0:
        raise ValueError(f"lr_epochs must be epoch counts >= 0 with a positive sum, got {lengths}")
    if epochs < 0:
        raise ValueError(f"epochs must be >= 0, got {epochs}")
    total = sum(lengths)
    if epochs == total:
        return lengths
    bounds, acc = [], 0
    for e in lengths:
        acc += e
        bounds.append(round(epochs * acc / total))
    phases = [b - a for a, b in zip([0, *bounds[:-1]], bounds)]
    if epochs >= len(phases):
        for i, n in enumerate(phases):
            if n == 0:
                donor = max(range(len(phases)), key=lambda j: (phases[j], j))
                phases[donor] -= 1
                phases[i] = 1
    return phases


def flow_weight_factor(epoch: int, fade_epochs: int | None) -> float:
    """The factor on the weights of L_rigid and L_feature in epoch ``epoch`` (counted from 1): 1 in every
    epoch without a fade (``None``, the paper); with a fade of N epochs it falls linearly, 1 − (epoch − 1)/N,
    from 1 in epoch 1 to 0 from epoch N + 1 on."""
    if fade_epochs is None:
        return 1.0
    if fade_epochs < 1:
        raise ValueError(f"flow_fade_epochs must be >= 1 or null, got {fade_epochs}")
    return max(0.0, 1.0 - (epoch - 1) / fade_epochs)


@dataclass(frozen=True)
class LRSchedule:
    """Piecewise-constant learning rate: ``rates[k]`` for ``phases[k]`` epochs."""

    rates: tuple[float, ...]
    phases: tuple[int, ...]

    @classmethod
    def scaled(cls, rates: Sequence[float], lr_epochs: Sequence[int], epochs: int) -> LRSchedule:
        """The paper's schedule (rates, lr_epochs) scaled to ``epochs`` (see ``scale_phases``)."""
        if not rates or any(float(r) <= 0 for r in rates):
            raise ValueError(f"lr must be a list of positive learning rates, got {list(rates)}")
        if len(rates) != len(lr_epochs):
            raise ValueError(f"lr has {len(rates)} rates but lr_epochs {len(lr_epochs)} phases; give one "
                             "epoch count per rate (the paper: lr [1e-4, 1e-5, 1e-6], lr_epochs [27, 15, 2])")
        return cls(tuple(float(r) for r in rates), tuple(scale_phases(lr_epochs, epochs)))

    @property
    def epochs(self) -> int:
        return sum(self.phases)

    def lr(self, epoch: int) -> float:
        """Learning rate of epoch ``epoch`` (0-based); epochs past the end keep the last used rate."""
        if epoch < 0:
            raise ValueError(f"epoch must be >= 0, got {epoch}")
        end = 0
        last = self.rates[0]
        for rate, n in zip(self.rates, self.phases):
            if n == 0:
                continue
            end += n
            last = rate
            if epoch < end:
                return rate
        return last

    def as_dict(self) -> dict[str, list]:
        return {"rates": list(self.rates), "phases": list(self.phases)}
