"""Regression guard of issue #16: every characterization group (tests/characterization.py) must give the
values stored in tests/data/characterization.json.

A failure lists the values that moved. If the change of behaviour is intended, rewrite the store with
``python tests/characterization.py --write`` and say so in the commit message; otherwise the change is a
regression.

Tolerances (relative; a ``….sum`` is compared relative to its ``….abs_sum`` when both are stored, see
``characterization.compare``). Run to run on one machine every group is bit-identical; between 1 and 2–4
threads (float32 reductions split differently) the largest relative differences measured were 6.5e-8 for
the depth step's losses, 4.7e-6 for its weights and BatchNorm statistics, 1.3e-5 for its gradient sums
(the decoder's output bias: one scalar summed over every pixel), 4e-8 for the evaluation's metrics (float32
network) and 2e-15 for the float64 groups. The tolerances sit well above those and far below what a
changed constant, reduction or convention moves (≥ 1e-3 in the checks done when they were chosen).
"""

from __future__ import annotations

import re

import characterization as C
import pytest

#: Per group: (key pattern, rtol) pairs, the first pattern that matches a key (re.search) wins.
TOLERANCES: dict[str, list[tuple[str, float]]] = {
    "depth_losses": [("", 1e-6)],
    "geometry": [("", 1e-6)],
    "flow_losses": [("", 1e-6)],
    "metrics": [("", 1e-6)],
    # the loss after one step of a random network: float32 reductions in an order that the CPU kernels choose
    "depth_train_step": [(r"^\w+\.g\.", 1e-4), (r"^\w+\.[wb]\.", 3e-5),
                         (r"^\w+\.(log\.(ph|total)|loss)$", 1e-5), ("", 1e-6)],
    "flow_finetune_step": [("", 1e-6)],
    "evaluation": [(r"sq_rel$", 1e-5), ("", 1e-6)],  # sq_rel: a tiny mean of squares, float32 round-off
    "keypoints_prepare": [("", 1e-6)],
}


def rtol_of(group: str, key: str) -> float:
    return next(rtol for pattern, rtol in TOLERANCES[group] if re.search(pattern, key))


@pytest.fixture(scope="module")
def stored() -> dict[str, C.Values]:
    return C.load_store()


def test_every_group_is_stored_and_has_a_tolerance(stored):
    assert list(stored) == list(C.GROUPS) == list(TOLERANCES), (
        f"groups: stored {list(stored)}, computed {list(C.GROUPS)}, with tolerances {list(TOLERANCES)}")


@pytest.mark.parametrize("group", list(C.GROUPS))
def test_group_matches_stored_values(group, stored):
    lines = C.compare(C.compute(group), stored[group], lambda key: rtol_of(group, key))
    assert not lines, (f"{group}: {len(lines)} characterization value(s) changed (rewrite the store only for "
                       "an intended change):\n" + "\n".join(lines[:40]))


def test_compare_reports_missing_extra_and_moved_values():
    stored = {"a": 1.0, "b.sum": 1e-9, "b.abs_sum": 2.0, "gone": 3.0}
    computed = {"a": 1.0 + 2e-6, "b.sum": 1e-9 + 1e-7, "b.abs_sum": 2.0, "new": 4.0}
    lines = C.compare(computed, stored, rtol=1e-6)
    assert lines[0] == ("keys differ: missing (stored, not computed) ['gone']; "
                        "extra (computed, not stored) ['new']")
    assert len(lines) == 2 and lines[1].startswith("a: computed")  # b.sum is within 1e-6 of its abs_sum
    assert C.compare(stored, stored, rtol=0.0) == []
