"""Tests for f2depth.losses.total: weighting by name, logging and the NaN/inf guard."""

from __future__ import annotations

import pytest
import torch

from f2depth.losses import NonFiniteLossError, check_finite, total_loss

PAPER = {"smooth": 0.001, "planar": 0.05, "rigid": 1.0, "feature": 3.0}


def _terms(**over):
    terms = {
        "ph": torch.tensor(0.2, requires_grad=True),
        "smooth": torch.tensor(1.5),
        "planar": torch.tensor(0.4),
        "rigid": torch.tensor(0.7),
        "feature": torch.tensor(0.05),
    }
    terms.update({k: torch.tensor(v) for k, v in over.items()})
    return terms


def test_weighted_sum_and_logs():
    loss, logs = total_loss(_terms(), PAPER)
    expected = 0.2 + 0.001 * 1.5 + 0.05 * 0.4 + 1.0 * 0.7 + 3.0 * 0.05
    assert loss.item() == pytest.approx(expected)
    assert logs == pytest.approx(
        {"ph": 0.2, "smooth": 1.5, "planar": 0.4, "rigid": 0.7, "feature": 0.05, "total": expected}
    )
    assert all(isinstance(v, float) for v in logs.values())
    loss.backward()


def test_each_term_takes_the_weight_of_its_name():
    """The weights' order does not matter, only their names; a new term needs nothing but its weight."""
    shuffled = {"feature": 3.0, "rigid": 1.0, "planar": 0.05, "smooth": 0.001}
    assert total_loss(_terms(), shuffled)[0].item() == pytest.approx(total_loss(_terms(), PAPER)[0].item())
    loss, logs = total_loss({**_terms(), "census": torch.tensor(2.0)}, {**PAPER, "census": 0.5})
    assert loss.item() == pytest.approx(total_loss(_terms(), PAPER)[0].item() + 1.0) and logs["census"] == 2.0


def test_baseline_may_omit_flow_terms_and_every_term_needs_a_weight():
    terms = _terms()
    del terms["rigid"], terms["feature"]
    loss, logs = total_loss(terms, {**PAPER, "rigid": 0.0, "feature": 0.0})
    assert set(logs) == {"ph", "smooth", "planar", "total"}
    assert loss.item() == pytest.approx(0.2 + 0.0015 + 0.02)
    with pytest.raises(KeyError, match=r"\['rigid', 'feature'\] have non-zero weights but were not computed"):
        total_loss(terms, PAPER)
    with pytest.raises(KeyError, match=r"loss terms \['census'\] have no weight"):
        total_loss({**_terms(), "census": torch.tensor(1.0)}, PAPER)
    with pytest.raises(KeyError, match="the photometric term 'ph' is required"):
        total_loss({k: v for k, v in _terms().items() if k != "ph"}, PAPER)


def test_a_zero_weight_term_is_logged_but_not_summed():
    loss, logs = total_loss(_terms(), {**PAPER, "feature": 0.0})
    assert loss.item() == pytest.approx(0.2 + 0.0015 + 0.02 + 0.7) and logs["feature"] == pytest.approx(0.05)


def test_guard_names_the_bad_term():
    with pytest.raises(NonFiniteLossError, match="'planar' is nan") as info:
        total_loss(_terms(planar=float("nan")), PAPER, context="epoch 3 step 17")
    assert info.value.term == "planar" and "epoch 3 step 17" in str(info.value)
    with pytest.raises(NonFiniteLossError, match="'feature' is inf"):
        check_finite(_terms(feature=float("inf")))
    # A NaN term with weight 0 is still reported: it means a bug upstream.
    with pytest.raises(NonFiniteLossError, match="'rigid'"):
        total_loss(_terms(rigid=float("nan")), {**PAPER, "rigid": 0.0})
    check_finite({"ph": 1.0, "smooth": torch.tensor(0.0)})
