"""L_depth = L_ph + Σ weight[term]·L_term, and a NaN/inf guard.

The paper's eq. (11), L_ph + λ1·L_sm + λ2·L_spp + L_rigid + λ3·L_feature, with each λ under the name of its
term (params.yaml ``lambda1``, ``lambda2``, ``lambda_rigid``, ``lambda3``: f2depth.train.step.WEIGHT_KEYS);
terms and weights are matched by name.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import torch

#: The unweighted term every sum has: P²Net's photometric loss L_ph (weight 1).
PHOTOMETRIC = "ph"


class NonFiniteLossError(FloatingPointError):
    """A loss term became NaN or infinite; ``term`` names it."""

    def __init__(self, term: str, value: float, context: str = "") -> None:
        self.term = term
        self.value = value
        where = f" ({context})" if context else ""
        super().__init__(
            f"loss term '{term}' is {value}{where}; stopping. Lower the learning rate, check the inputs of "
            f"this term (depth range, poses, flow checkpoint) or resume from the last good checkpoint"
        )


def check_finite(terms: Mapping[str, torch.Tensor | float], context: str = "") -> None:
    """Raise NonFiniteLossError naming the first term (in the order given) that is NaN/inf."""
    for name, value in terms.items():
        v = float(value.detach()) if isinstance(value, torch.Tensor) else float(value)
        if not math.isfinite(v):
            raise NonFiniteLossError(name, v, context)


def total_loss(
    terms: Mapping[str, torch.Tensor], weights: Mapping[str, float], context: str = ""
) -> tuple[torch.Tensor, dict[str, float]]:
    """L_ph + Σ weights[name]·terms[name] → (loss, {term: float, ..., "total": float}).

    ``terms`` holds scalar tensors by name, the photometric term ``"ph"`` (weight 1) required; every other
    term needs a weight in ``weights`` (term → weight, f2depth.train.settings.loss_weights). A term whose
    weight is 0 is logged but left out of the sum; a weighted term may be left out of ``terms`` only if its
    weight is 0 (e.g. no flow losses for the P²Net baseline). Terms are summed in the order of ``terms``.
    Checks every term with ``check_finite``.
    """
    if PHOTOMETRIC not in terms:
        raise KeyError(f"the photometric term {PHOTOMETRIC!r} is required")
    unweighted = [name for name in terms if name != PHOTOMETRIC and name not in weights]
    if unweighted:
        raise KeyError(f"loss terms {unweighted} have no weight; "
                       "give each one (f2depth.train.step.WEIGHT_KEYS)")
    absent = [name for name, w in weights.items() if name not in terms and w != 0.0]
    if absent:
        raise KeyError(f"loss terms {absent} have non-zero weights but were not computed")
    check_finite(terms, context)

    def weight(name: str) -> float:
        return 1.0 if name == PHOTOMETRIC else float(weights[name])

    loss = sum(weight(name) * value for name, value in terms.items() if weight(name) != 0.0)
    logs = {name: float(value.detach()) for name, value in terms.items()}
    logs["total"] = float(loss.detach())
    if not math.isfinite(logs["total"]):
        raise NonFiniteLossError("total", logs["total"], context)
    return loss, logs
