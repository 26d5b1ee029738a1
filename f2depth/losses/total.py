"""L_depth = L_ph + λ1·L_sm + λ2·L_spp + λ_rigid·L_rigid + λ3·L_feature, and a NaN/inf guard."""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

#: Term names, in logging order, and the weight attribute of each (None = weight 1).
TERMS = {"ph": None, "sm": "lambda1", "spp": "lambda2", "rigid": "lambda_rigid", "feature": "lambda3"}


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


@dataclass(frozen=True)
class LossWeights:
    """Weights of L_depth (params.yaml top level: lambda1, lambda2, lambda3, lambda_rigid)."""

    lambda1: float = 0.001
    lambda2: float = 0.05
    lambda3: float = 3.0
    lambda_rigid: float = 1.0

    def weight(self, term: str) -> float:
        if term not in TERMS:
            raise KeyError(f"unknown loss term {term!r}; known: {list(TERMS)}")
        attr = TERMS[term]
        return 1.0 if attr is None else float(getattr(self, attr))


def check_finite(terms: dict[str, torch.Tensor | float], context: str = "") -> None:
    """Raise NonFiniteLossError naming the first term (in TERMS order, then the rest) that is NaN/inf."""
    ordered = [k for k in TERMS if k in terms] + [k for k in terms if k not in TERMS]
    for name in ordered:
        value = terms[name]
        v = float(value.detach()) if isinstance(value, torch.Tensor) else float(value)
        if not math.isfinite(v):
            raise NonFiniteLossError(name, v, context)


def total_loss(
    terms: dict[str, torch.Tensor], weights: LossWeights, context: str = ""
) -> tuple[torch.Tensor, dict[str, float]]:
    """Weighted sum of the given terms → (loss, {term: float, ..., "total": float}).

    ``terms`` holds scalar tensors named from TERMS ("ph" required); a term may be left out only if its
    weight is 0 (e.g. no flow losses for the P²Net baseline). Checks every term with ``check_finite``.
    """
    unknown = sorted(set(terms) - set(TERMS))
    if unknown:
        raise KeyError(f"unknown loss terms {unknown}; known: {list(TERMS)}")
    if "ph" not in terms:
        raise KeyError("the photometric term 'ph' is required")
    absent = [t for t in TERMS if t not in terms and weights.weight(t) != 0.0]
    if absent:
        raise KeyError(f"loss terms {absent} have non-zero weights but were not computed")
    check_finite(terms, context)
    loss = sum(weights.weight(name) * value for name, value in terms.items() if weights.weight(name) != 0.0)
    logs = {name: float(value.detach()) for name, value in terms.items()}
    logs["total"] = float(loss.detach())
    if not math.isfinite(logs["total"]):
        raise NonFiniteLossError("total", logs["total"], context)
    return loss, logs
