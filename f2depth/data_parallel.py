"""Data parallelism across 1-thread CPU processes on one machine (gloo): each rank computes the gradient of
its part of the global batch, the ranks average the gradients, and every rank takes the same optimizer
step, so every rank holds the same weights after every step.

Why (docs/flow_pretrain.md, "Threads and processes"): a 2-thread step on 2 cores collapses beside one busy
process (every parallel operation waits for the displaced thread), while two 1-thread ranks only share
the cores; and a rank's arithmetic runs at one thread, so the result does not depend on the machine's
core count or load. With two ranks the average is exact in either order (a + b = b + a in floating
point), so a rerun gives the same bits.

:data:`SINGLE` is the one-process group (no communication); :func:`join` makes a process rank ``rank`` of
a ``world``-process group that meets on ``127.0.0.1:port`` (:func:`free_port`).
"""

from __future__ import annotations

import socket
from dataclasses import dataclass
from datetime import timedelta

import torch
import torch.distributed as dist


@dataclass(frozen=True)
class Group:
    """This process's place in a data-parallel run: rank ``rank`` of ``world`` processes."""

    rank: int = 0
    world: int = 1

    @property
    def main(self) -> bool:
        """Rank 0: the process that measures, saves and logs."""
        return self.rank == 0

    def part(self, n: int) -> slice:
        """This rank's items of a global batch of ``n`` (``n`` divisible by ``world``)."""
        if n % self.world:
            raise ValueError(f"a batch of {n} does not split into {self.world} equal parts; use a batch size "
                             f"divisible by {self.world}")
        size = n // self.world
        return slice(self.rank * size, (self.rank + 1) * size)

    def average_gradients(self, params: list[torch.Tensor], finite: bool) -> bool:
        """Replace each parameter's ``.grad`` by its mean over the ranks (a missing one counts as zeros)
        → whether every rank's loss was ``finite`` (when not, the gradients are left as they are: no rank
        may step)."""
        if self.world == 1:
            return finite
        grads = [p.grad if p.grad is not None else torch.zeros_like(p) for p in params]
        flat = torch.cat([g.reshape(-1) for g in grads] + [torch.tensor([0.0 if finite else 1.0])])
        dist.all_reduce(flat, op=dist.ReduceOp.SUM)
        if flat[-1].item() > 0:
            return False
        flat /= self.world
        offset = 0
        for p, g in zip(params, grads):
            n = g.numel()
            if p.grad is not None:  # every rank's graph reached the same parameters
                p.grad.copy_(flat[offset:offset + n].view_as(g))
            offset += n
        return True

    def mean(self, values: dict[str, float]) -> dict[str, float]:
        """The mean over the ranks of each value (every rank passes the same keys)."""
        return mean_over_ranks(values, self.world)

    def broadcast(self, module: torch.nn.Module) -> None:
        """Every rank takes rank 0's parameters and buffers (after rank 0 alone changed them)."""
        if self.world > 1:
            for t in [*module.parameters(), *module.buffers()]:
                dist.broadcast(t.data, src=0)

    def barrier(self) -> None:
        if self.world > 1:
            dist.barrier()


SINGLE = Group()


def mean_over_ranks(values: dict[str, float], world: int, device: torch.device | str = "cpu"
                    ) -> dict[str, float]:
    """The mean over the ``world`` ranks of the default process group of each value (every rank passes the
    same keys; ``device``: where the reduction runs, a CUDA device under NCCL)."""
    if world == 1 or not values:
        return dict(values)
    keys = sorted(values)
    t = torch.tensor([values[k] for k in keys], dtype=torch.float64, device=device)
    dist.all_reduce(t, op=dist.ReduceOp.SUM)
    return {k: float(v) / world for k, v in zip(keys, t.tolist())}


def free_port() -> int:
    """A TCP port on 127.0.0.1 that is free now (the group's meeting point)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def join(rank: int, world: int, port: int) -> Group:
    """Join the ``world``-process gloo group on ``127.0.0.1:port`` as ``rank`` → its :class:`Group`."""
    if world > 1:
        dist.init_process_group("gloo", init_method=f"tcp://127.0.0.1:{port}", rank=rank, world_size=world,
                                timeout=timedelta(minutes=10))  # a rank that died stops the others
    return Group(rank, world)


def leave(group: Group) -> None:
    if group.world > 1 and dist.is_initialized():
        dist.destroy_process_group()
