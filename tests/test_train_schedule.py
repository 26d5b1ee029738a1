"""Tests for f2depth.train.schedule: the paper's piecewise-constant lr scaled to the epoch count."""

from __future__ import annotations

import pytest

from f2depth.train.schedule import LRSchedule, flow_weight_factor, scale_phases
from f2depth.train.step import StepConfig

PAPER_LR = [1e-4, 1e-5, 1e-6]
PAPER_EPOCHS = [27, 15, 2]


@pytest.mark.parametrize(
    ("epochs", "phases"),
    [(44, [27, 15, 2]), (88, [54, 30, 4]), (8, [4, 3, 1]), (22, [14, 7, 1]), (4, [2, 1, 1]), (3, [1, 1, 1]),
     (2, [1, 1, 0]), (1, [1, 0, 0]), (0, [0, 0, 0])],
)
def test_scaled_phases(epochs, phases):
    got = scale_phases(PAPER_EPOCHS, epochs)
    assert got == phases
    assert sum(got) == epochs
    if epochs >= 3:
        assert min(got) >= 1


def test_every_phase_used_and_ordered_for_all_small_runs():
    for epochs in range(3, 60):
        phases = scale_phases(PAPER_EPOCHS, epochs)
        assert sum(phases) == epochs and min(phases) >= 1
        assert phases[0] >= phases[1] >= phases[2]  # the paper's shape survives the rounding


def test_lr_per_epoch():
    s = LRSchedule.scaled(PAPER_LR, PAPER_EPOCHS, 8)
    assert [s.lr(e) for e in range(8)] == [1e-4] * 4 + [1e-5] * 3 + [1e-6]
    assert s.lr(20) == 1e-6 and s.epochs == 8
    short = LRSchedule.scaled(PAPER_LR, PAPER_EPOCHS, 2)
    assert [short.lr(e) for e in range(3)] == [1e-4, 1e-5, 1e-5]  # the dropped phase is never used
    paper = LRSchedule.scaled(PAPER_LR, PAPER_EPOCHS, 44)
    assert paper.lr(26) == 1e-4 and paper.lr(27) == 1e-5 and paper.lr(41) == 1e-5 and paper.lr(42) == 1e-6


def test_errors():
    with pytest.raises(ValueError, match="one epoch count per rate"):
        LRSchedule.scaled([1e-4], PAPER_EPOCHS, 8)
    with pytest.raises(ValueError, match="positive"):
        LRSchedule.scaled([1e-4, 0.0, 1e-6], PAPER_EPOCHS, 8)
    with pytest.raises(ValueError, match="positive sum"):
        scale_phases([0, 0], 4)
    with pytest.raises(ValueError, match="epoch must be >= 0"):
        LRSchedule.scaled(PAPER_LR, PAPER_EPOCHS, 8).lr(-1)


def test_the_flow_terms_fade_linearly_to_zero_and_only_they():
    """train_depth.flow_fade_epochs: 1 in epoch 1, 1 − (epoch − 1)/N after, 0 from epoch N + 1; null keeps the
    paper's constant weights. The factor scales L_rigid's and L_feature's weights and nothing else."""
    assert [flow_weight_factor(e, 4) for e in range(1, 8)] == [1.0, 0.75, 0.5, 0.25, 0.0, 0.0, 0.0]
    assert [flow_weight_factor(e, None) for e in (1, 30)] == [1.0, 1.0]
    with pytest.raises(ValueError, match="flow_fade_epochs"):
        flow_weight_factor(1, 0)
    cfg = StepConfig({"smooth": 1e-3, "planar": 0.05, "rigid": 0.1, "feature": 0.3}, min_area=10)
    assert cfg.with_flow_factor(1.0) is cfg
    half = cfg.with_flow_factor(0.5)
    assert half.weights == {"smooth": 1e-3, "planar": 0.05, "rigid": 0.05, "feature": 0.15}
    assert cfg.weights["rigid"] == 0.1 and half.min_area == 10  # the original is left as it was
