"""Data parallelism across 1-thread CPU processes (f2depth.data_parallel) and the chairs route run on it
(f2depth.flow.chairs_ranks, `flow_pretrain.chairs.cpu_ranks`): the ranks' averaged gradient is the whole
batch's, a rank's share of the generated data is that part of the one-process batch, and two ranks give
the same weights whatever thread count the calling process runs."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from test_flow_bootstrap import small_config

from f2depth import data_parallel, processes
from f2depth.flow.bootstrap import heldout_pairs
from f2depth.flow.chairs import render_pairs, texture_pool
from f2depth.flow.chairs_ranks import chairs_pool, pretrain_in_ranks
from f2depth.flow.net.checkpoint import build_network


def _batch() -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(3)
    return torch.randn(8, 5, generator=g), torch.randn(8, 1, generator=g)


def _model() -> torch.nn.Module:
    torch.manual_seed(0)
    return torch.nn.Sequential(torch.nn.Linear(5, 4), torch.nn.Tanh(), torch.nn.Linear(4, 1))


def _rank_gradients(rank: int, world: int, port: int, poison_rank: int | None) -> tuple[list, bool]:
    """One rank: the gradient of the mean squared error on its half of :func:`_batch`, averaged."""
    group = data_parallel.join(rank, world, port)
    try:
        x, y = _batch()
        part = group.part(len(x))
        model = _model()
        loss = ((model(x[part]) - y[part]) ** 2).mean()
        if rank == poison_rank:
            loss = loss * float("nan")
        finite = bool(torch.isfinite(loss))
        if finite:
            loss.backward()
        params = list(model.parameters())
        agreed = group.average_gradients(params, finite)
    finally:
        data_parallel.leave(group)
    return [p.grad.clone() if p.grad is not None else None for p in params], agreed


def test_averaged_gradients_are_the_whole_batch_gradient():
    """Two ranks, each on half the batch: after averaging every rank holds the gradient of the loss over
    the whole batch (a mean over equal halves), to rounding."""
    port = data_parallel.free_port()
    got = processes.run_jobs(_rank_gradients, [(r, 2, port, None) for r in range(2)], n_threads=1,
                             total_epochs=0, desc="ranks", progress=False, concurrent=True)
    x, y = _batch()
    model = _model()
    ((model(x) - y) ** 2).mean().backward()
    for grads, agreed in got:
        assert agreed
        for g, p in zip(grads, model.parameters()):
            torch.testing.assert_close(g, p.grad, rtol=1e-5, atol=1e-7)
    assert all(torch.equal(a, b) for a, b in zip(got[0][0], got[1][0]))  # bit-identical on both ranks


def test_a_non_finite_loss_on_one_rank_stops_every_rank():
    port = data_parallel.free_port()
    got = processes.run_jobs(_rank_gradients, [(r, 2, port, 1) for r in range(2)], n_threads=1,
                             total_epochs=0, desc="ranks", progress=False, concurrent=True)
    assert [agreed for _, agreed in got] == [False, False]


def test_a_batch_that_does_not_split_is_refused():
    with pytest.raises(ValueError, match="divisible by 3"):
        data_parallel.Group(0, 3).part(8)
    with pytest.raises(ValueError, match="multiple of cpu_ranks"):
        small_config(batch_size=3, cpu_ranks=2)


def test_a_ranks_share_of_the_generated_pairs_is_that_part_of_the_whole_batch():
    """render_pairs(part=...) draws every pair of the batch (the stream moves on as for all of them) and
    renders only the part: the ranks together train on exactly the one-process run's pairs."""
    cfg = small_config()
    pool = texture_pool(cfg.data, np.random.default_rng(0))
    whole_rng, part_rng = np.random.default_rng(5), np.random.default_rng(5)
    whole = render_pairs(cfg.data, pool, whole_rng, 4)
    part = render_pairs(cfg.data, pool, part_rng, 4, slice(2, 4))
    for w, p in zip(whole, part):
        assert torch.equal(w[2:4], p)
    assert whole_rng.random() == part_rng.random()


def _pretrained(threads: int) -> tuple[dict, dict]:
    torch.set_num_threads(threads)
    cfg = small_config(batch_size=4, steps_per_epoch=3, epochs=2, cpu_ranks=2)
    model = build_network("pwclite")
    rows: list[dict] = []
    result, heldout = pretrain_in_ranks(model, cfg, 0, "pwclite", [], None, on_epoch=rows.append)
    assert all(torch.equal(a, b) for a, b in zip(heldout, heldout_pairs(cfg, 0, chairs_pool(cfg, 0, []))))
    assert [r["epoch"] for r in rows] == [1, 2, 3] == [r["epoch"] for r in result["history"]]
    return {k: v.clone() for k, v in model.state_dict().items()}, result


def test_two_ranks_give_the_same_weights_whatever_threads_the_caller_runs():
    """cpu_ranks: 2 trains in two 1-thread processes, so the calling process's thread count (here 1, then
    2) changes nothing: bit-identical weights. And the ranks learn: the held-out EPE falls below zero
    flow's (the per-pixel check of the bootstrap, f2depth.flow.bootstrap, on this route)."""
    before = torch.get_num_threads()
    try:
        one, result = _pretrained(1)
        two, _ = _pretrained(2)
    finally:
        torch.set_num_threads(before)
    assert one.keys() == two.keys()
    assert all(torch.equal(one[k], two[k]) for k in one)
    final = result["final"]
    assert final["heldout_epe"] < 0.97 * final["heldout_zero_epe"]
    assert result["averaged_epochs"] == 1
