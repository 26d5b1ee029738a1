"""Tests for f2depth.losses.total: weighting, logging and the NaN/inf guard."""

from __future__ import annotations

import dataclasses

import pytest
import torch

from f2depth.losses import LossWeights, NonFiniteLossError, check_finite, total_loss


def _terms(**over):
    terms = {
        "ph": torch.tensor(0.2, requires_grad=True),
        "sm": torch.tensor(1.5),
        "spp": torch.tensor(0.4),
        "rigid": torch.tensor(0.7),
        "feature": torch.tensor(0.05),
    }
    terms.update({k: torch.tensor(v) for k, v in over.items()})
    return terms


def test_weighted_sum_and_logs():
    w = LossWeights(lambda1=0.001, lambda2=0.05, lambda3=3.0, lambda_rigid=1.0)
    loss, logs = total_loss(_terms(), w)
    expected = 0.2 + 0.001 * 1.5 + 0.05 * 0.4 + 1.0 * 0.7 + 3.0 * 0.05
    assert loss.item() == pytest.approx(expected)
    assert logs == pytest.approx(
        {"ph": 0.2, "sm": 1.5, "spp": 0.4, "rigid": 0.7, "feature": 0.05, "total": expected}
    )
    assert all(isinstance(v, float) for v in logs.values())
    loss.backward()


def test_weights_are_frozen_and_baseline_may_omit_flow_terms():
    w = LossWeights(lambda1=0.001, lambda2=0.05, lambda3=0.0, lambda_rigid=0.0)
    with pytest.raises(dataclasses.FrozenInstanceError):
        w.lambda3 = 1.0  # type: ignore[misc]
    terms = _terms()
    del terms["rigid"], terms["feature"]
    loss, logs = total_loss(terms, w)
    assert set(logs) == {"ph", "sm", "spp", "total"}
    assert loss.item() == pytest.approx(0.2 + 0.0015 + 0.02)
    with pytest.raises(KeyError, match="non-zero weights"):
        total_loss(terms, LossWeights())
    with pytest.raises(KeyError, match="unknown loss terms"):
        total_loss({**_terms(), "census": torch.tensor(1.0)}, LossWeights())


def test_guard_names_the_bad_term():
    with pytest.raises(NonFiniteLossError, match="'spp' is nan") as info:
        total_loss(_terms(spp=float("nan")), LossWeights(), context="epoch 3 step 17")
    assert info.value.term == "spp" and "epoch 3 step 17" in str(info.value)
    with pytest.raises(NonFiniteLossError, match="'feature' is inf"):
        check_finite(_terms(feature=float("inf")))
    # A NaN term with weight 0 is still reported: it means a bug upstream.
    with pytest.raises(NonFiniteLossError, match="'rigid'"):
        total_loss(_terms(rigid=float("nan")), LossWeights(lambda_rigid=0.0))
    check_finite({"ph": 1.0, "sm": torch.tensor(0.0)})
