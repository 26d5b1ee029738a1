"""The chairs route (f2depth.flow.bootstrap) in ``cpu_ranks`` data-parallel CPU processes at one thread each
(docs/flow_pretrain.md, "Threads and processes").

Every rank builds the same network, texture pool and start, renders its part of each global batch (the
draws of the whole batch, so the data are the one-process run's) and averages its gradients with the
others' (f2depth.data_parallel); rank 0 also scores the held-out pairs, writes the resume file and keeps
the weight average. The parent gets rank 0's weights and result, and replays the epochs to its logger.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import torch

from f2depth import data_parallel, processes
from f2depth.flow.bootstrap import BootstrapConfig, heldout_pairs, pretrain_chairs
from f2depth.flow.chairs import texture_pool
from f2depth.flow.net.checkpoint import build_network
from f2depth.flow.net.network import FlowNetwork
from f2depth.formats.images import read_image


def chairs_pool(cfg: BootstrapConfig, seed: int, frames: Sequence[str]) -> torch.Tensor:
    """The textures of the generated pairs: procedural ones plus crops of the training ``frames``."""
    return texture_pool(cfg.data, np.random.default_rng([seed, 7]), [read_image(path) for path in frames])


def _rank(rank: int, world: int, port: int, cfg: BootstrapConfig, seed: int, network: str,
          frames: Sequence[str], resume_dir: str | None) -> dict[str, Any] | None:
    """One rank's process → rank 0: ``{"state": its weights, "result": pretrain_chairs' result, "heldout":
    the held-out generated pairs it scored}``."""
    group = data_parallel.join(rank, world, port)
    try:
        pool = chairs_pool(cfg, seed, frames)
        torch.manual_seed(seed)
        model = build_network(network)
        test = heldout_pairs(cfg, seed, pool) if group.main else ()
        result = pretrain_chairs(model, pool, cfg, seed, network, test, resume_dir, "cpu",
                                 on_epoch=lambda row: processes.epoch_done(), progress=False, group=group)
    finally:
        data_parallel.leave(group)
    return {"state": model.state_dict(), "result": result, "heldout": test} if group.main else None


def pretrain_in_ranks(model: FlowNetwork, cfg: BootstrapConfig, seed: int, network: str,
                      frames: Sequence[str], resume_dir: str | None,
                      on_epoch: Callable[[dict[str, Any]], None] | None = None
                      ) -> tuple[dict[str, Any], tuple[torch.Tensor, ...]]:
    """:func:`f2depth.flow.bootstrap.pretrain_chairs` in ``cfg.cpu_ranks`` 1-thread processes (module
    docstring): ``model`` (built as the ranks build theirs) left holding the result's weights → (its result,
    the held-out generated pairs of :func:`~f2depth.flow.bootstrap.heldout_pairs` it was scored on);
    ``on_epoch(row)`` for each epoch of the history afterwards."""
    world = cfg.cpu_ranks or 1
    port = data_parallel.free_port()
    jobs = [(rank, world, port, cfg, seed, network, list(frames), resume_dir) for rank in range(world)]
    done = processes.run_jobs(_rank, jobs, n_threads=1, total_epochs=cfg.total_epochs,
                              desc="flow_pretrain", concurrent=True)[0]
    model.load_state_dict(done["state"])
    if on_epoch is not None:
        for row in done["result"]["history"]:
            on_epoch(row)
    return done["result"], done["heldout"]
