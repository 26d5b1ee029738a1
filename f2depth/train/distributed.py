"""torchrun / DistributedDataParallel support for depth training.

``torchrun --nproc_per_node=N stages/train_depth.py --variant full`` sets RANK, WORLD_SIZE, LOCAL_RANK,
MASTER_ADDR and MASTER_PORT; ``init_from_env`` reads them and initialises the process group — under
torchrun always, also at world size 1, so that ``--nproc_per_node=1`` runs the DDP code path it stands
for; a plain ``python`` call has no process group. Backend: gloo on CPU, nccl on CUDA (device
``cuda:<LOCAL_RANK>``).

Each rank reads ``global batch / world size`` items of every global batch (``data.rank_indices``), so the
global batch and the data order do not depend on the number of processes; DDP averages the gradients.
Per-epoch loss means are averaged over the ranks (``all_reduce_mean``); only rank 0 validates, writes
files and logs. BatchNorm: on CUDA with several ranks the model is converted to SyncBatchNorm (batch
statistics over the global batch, as a one-GPU run); on CPU (gloo) PyTorch has no SyncBatchNorm, so each
rank normalises over its own part of the batch.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import torch
import torch.distributed as dist
from torch import nn

from f2depth.data_parallel import mean_over_ranks
from f2depth.losses import NonFiniteLossError
from f2depth.losses.total import PHOTOMETRIC
from f2depth.params import resolve_device
from f2depth.train.step import TERMS

#: Codes of NaN/inf terms exchanged between ranks (0 = all finite).
_TERM_CODES = [PHOTOMETRIC, *TERMS, "total"]


@dataclass(frozen=True)
class DistContext:
    rank: int = 0
    world_size: int = 1
    local_rank: int = 0
    device: torch.device = torch.device("cpu")
    process_group: bool = False  # launched by torchrun: a process group exists (also at world size 1)

    @property
    def distributed(self) -> bool:
        return self.process_group or self.world_size > 1

    @property
    def is_main(self) -> bool:
        return self.rank == 0


def init_from_env(device: str = "auto") -> DistContext:
    """The process's rank and device from the torchrun environment; initialises the process group when
    WORLD_SIZE > 1. ``device`` is params' ``device`` (auto | cpu | cuda | cuda:N)."""
    launched = "RANK" in os.environ and "WORLD_SIZE" in os.environ
    world = int(os.environ.get("WORLD_SIZE", "1"))
    rank = int(os.environ.get("RANK", "0"))
    local = int(os.environ.get("LOCAL_RANK", "0"))
    name = resolve_device(device)
    if name.startswith("cuda"):
        dev = torch.device("cuda", local) if launched else torch.device(name)
        torch.cuda.set_device(dev)
    else:
        dev = torch.device(name)
    if (launched or world > 1) and not dist.is_initialized():
        dist.init_process_group("nccl" if dev.type == "cuda" else "gloo", rank=rank, world_size=world)
    return DistContext(rank, world, local, dev, process_group=dist.is_initialized())


def cleanup(ctx: DistContext) -> None:
    if ctx.distributed and dist.is_initialized():
        dist.destroy_process_group()


def barrier(ctx: DistContext) -> None:
    if ctx.distributed:
        dist.barrier()


def wrap_model(model: nn.Module, ctx: DistContext, sync_bn: bool = True) -> nn.Module:
    """Move to the device; under DDP wrap it (SyncBatchNorm first when on CUDA and ``sync_bn``)."""
    model = model.to(ctx.device)
    if not ctx.distributed:
        return model
    if sync_bn and ctx.device.type == "cuda":
        model = nn.SyncBatchNorm.convert_sync_batchnorm(model)
    ids = [ctx.device.index] if ctx.device.type == "cuda" else None
    return nn.parallel.DistributedDataParallel(model, device_ids=ids)


def unwrap(model: nn.Module) -> nn.Module:
    return model.module if isinstance(model, nn.parallel.DistributedDataParallel) else model


def all_reduce_mean(values: dict[str, float], ctx: DistContext) -> dict[str, float]:
    """Mean over ranks of each value (every rank must pass the same keys)."""
    if not ctx.distributed:
        return dict(values)
    return mean_over_ranks(values, ctx.world_size, ctx.device if ctx.device.type == "cuda" else "cpu")


def agree_finite(error: NonFiniteLossError | None, ctx: DistContext) -> None:
    """Raise on every rank when any rank's loss was NaN/inf. A failing rank raises its own error; the
    others name the failing term (the latest in logging order when several ranks fail)."""
    if not ctx.distributed:
        if error is not None:
            raise error
        return
    code = 0
    if error is not None:
        code = _TERM_CODES.index(error.term) + 1 if error.term in _TERM_CODES else len(_TERM_CODES) + 1
    t = torch.tensor([code], dtype=torch.int64, device=ctx.device if ctx.device.type == "cuda" else "cpu")
    dist.all_reduce(t, op=dist.ReduceOp.MAX)
    worst = int(t.item())
    if worst == 0:
        return
    if error is not None:
        raise error
    term = _TERM_CODES[worst - 1] if worst <= len(_TERM_CODES) else "unknown"
    raise NonFiniteLossError(term, float("nan"), f"reported by another rank; this is rank {ctx.rank}")
