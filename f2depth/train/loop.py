"""The epoch loop of depth training: schedule, data order, steps, validation, checkpoints, resume.

``fit`` trains a DepthModel for ``config.epochs`` epochs on the skeleton of every trainer
(:mod:`f2depth.epochs`: resume file, history rows, non-finite policy, per-epoch hooks). Epoch 0 is the
untrained network's validation. After every ``state_every``-th epoch and after the last, rank 0 writes
the resumable state (model, optimizer, grad scaler, RNG); with ``resume`` a matching state continues where
it stopped (a run killed between two states redoes the epochs since the last one). Because the data order,
the augmentation and the fill-up points depend only on (seed, epoch, index), the optimizer state is
restored exactly and the learning rate is a function of the epoch, a resumed CPU run ends with the same
weights as an uninterrupted one.
"""

from __future__ import annotations

import random
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch.utils.data import DataLoader

from f2depth.depth import DepthModel
from f2depth.epochs import EpochLoop, RNGState
from f2depth.losses.total import PHOTOMETRIC
from f2depth.precision import grad_scaler
from f2depth.train.data import EpochView, TupleDataset, rank_indices
from f2depth.train.diagnostics import DIAGNOSTIC_KEYS
from f2depth.train.distributed import DistContext, agree_finite, all_reduce_mean, barrier, unwrap, wrap_model
from f2depth.train.heldout import HELDOUT_KEYS
from f2depth.train.schedule import LRSchedule, flow_weight_factor
from f2depth.train.step import TERMS, StepConfig, batch_to, train_step
from f2depth.train.teacher import FlowTeacher

#: Columns of history.csv (DVC plots, x = epoch): what every training epoch measures, every loss term by
#: name among them (a term the variant is without, e.g. the flow terms of the P²Net baseline, stays empty).
HISTORY_COLUMNS = ["epoch", PHOTOMETRIC, *TERMS, "total", "steps", "skipped_steps", "lr", "seconds"]
#: Columns of validation.csv: what the measured epochs add (epoch 0, every ``val_every``-th, the last): NYU
#: validation, the held-out tuples' scores and the training-frame diagnostics, whichever the run has.
VALIDATION_COLUMNS = ["epoch", "val_abs_rel", "val_a1", *HELDOUT_KEYS, *DIAGNOSTIC_KEYS, "val_seconds"]
#: The history files of a run (f2depth.epochs.write_history: each holds the rows that measured its columns).
HISTORY_FILES = {"history.csv": HISTORY_COLUMNS, "validation.csv": VALIDATION_COLUMNS}


@dataclass(frozen=True)
class LoopConfig:
    epochs: int
    batch_size: int  # global batch: per-rank batch = batch_size / world size
    schedule: LRSchedule
    # the train_depth keys of the same names (f2depth.train.run.loop_config; params.yaml is their one default)
    workers: int
    sync_bn: bool
    val_every: int  # validate after every N-th epoch (and always before training and after the last)
    state_every: int  # write the resume state after every N-th epoch (and after the last)
    flow_fade_epochs: int | None  # the flow terms' weights fade to 0 over N epochs (None: constant)
    seed: int = 0
    progress: bool = True

    def __post_init__(self) -> None:
        if min(self.epochs, self.batch_size, self.val_every, self.state_every) < 1:
            raise ValueError(f"epochs, batch_size, val_every and state_every must be >= 1, got "
                             f"{self.epochs}, {self.batch_size}, {self.val_every}, {self.state_every}")
        if self.schedule.epochs != self.epochs:
            raise ValueError(f"the lr schedule covers {self.schedule.epochs} epochs, the run {self.epochs}")

    def validates_after(self, epoch: int) -> bool:
        """Whether the per-epoch measurement runs after ``epoch`` (1-based; 0 = before training)."""
        return epoch % self.val_every == 0 or epoch == self.epochs


@dataclass
class FitResult:
    history: list[dict[str, Any]]
    resumed_from: int = 0  # finished epochs taken from a checkpoint (0 = fresh start)
    resume_note: str = ""
    seconds: float = 0.0  # wall time of this call


def seed_everything(seed: int) -> None:
    """Seed torch, numpy and Python (do it before building the model: its initialisation draws)."""
    torch.manual_seed(seed)
    np.random.seed(seed & 0xFFFFFFFF)  # noqa: NPY002 (the legacy global generator, for third-party code)
    random.seed(seed)


def _loader(dataset: TupleDataset, epoch: int, config: LoopConfig, ctx: DistContext) -> DataLoader:
    idx = rank_indices(len(dataset), config.seed, epoch, config.batch_size, ctx.rank, ctx.world_size)
    return DataLoader(
        EpochView(dataset, epoch, idx), batch_size=config.batch_size // ctx.world_size, shuffle=False,
        drop_last=True, num_workers=config.workers, pin_memory=ctx.device.type == "cuda",
    )  # fmt: skip


def depth_optimizer(params: Iterable[torch.nn.Parameter], lr: float) -> torch.optim.Adam:
    """Depth training's Adam (P²Net's: default betas, no weight decay), fused: one kernel per step instead of
    a dozen passes over the 27 M parameters (the same update, other float rounding)."""
    return torch.optim.Adam(params, lr=lr, fused=True)


def fit(
    model: DepthModel,
    dataset: TupleDataset,
    teacher: FlowTeacher | None,
    step_config: StepConfig,
    config: LoopConfig,
    *,
    ctx: DistContext | None = None,
    checkpoint: str | Path | None = None,
    resume: bool = True,
    fingerprint: str = "",
    validate: Callable[[DepthModel], dict[str, float]] | None = None,
    on_epoch: Callable[[dict[str, Any]], None] | None = None,
) -> FitResult:
    """Train ``model`` in place (module docstring). ``on_epoch(row)`` runs on rank 0 after each epoch's
    checkpoint (and, on resume, once for every row already in the history, so loggers can replay them).
    A step whose loss is NaN/inf is skipped on every rank; an epoch of nothing else raises
    ``NonFiniteEpochError`` naming the term; the last checkpoint stays.
    """
    ctx = ctx or DistContext()
    t_start = time.perf_counter()
    ddp = wrap_model(model, ctx, sync_bn=config.sync_bn)
    optimizer = depth_optimizer(ddp.parameters(), config.schedule.lr(0))
    scaler = grad_scaler(ctx.device, step_config.amp)
    parts = {"model": unwrap(ddp), "optimizer": optimizer, "scaler": scaler, "rng": RNGState()}
    loop = EpochLoop("train_depth", config.epochs, parts, checkpoint, fingerprint, main=ctx.is_main,
                     progress=config.progress, state_every=config.state_every)
    if not loop.restore(resume) and validate is not None and ctx.is_main:
        t0 = time.perf_counter()
        loop.history.append({"epoch": 0, **validate(model), "val_seconds": time.perf_counter() - t0})

    def batches(epoch: int):
        for group in optimizer.param_groups:
            group["lr"] = config.schedule.lr(epoch - 1)
        ddp.train()
        return ((epoch, i, b) for i, b in enumerate(_loader(dataset, epoch, config, ctx)))

    def step(item: tuple[int, int, dict[str, torch.Tensor]]) -> dict[str, float]:
        epoch, i, batch = item
        weighted = step_config.with_flow_factor(flow_weight_factor(epoch, config.flow_fade_epochs))
        return train_step(ddp, optimizer, batch_to(batch, ctx.device), teacher, weighted, scaler,
                          context=f"epoch {epoch}, step {i}", agree=lambda error: agree_finite(error, ctx))[1]

    def end_epoch(row: dict[str, Any]) -> dict[str, Any]:
        out: dict[str, Any] = {"lr": config.schedule.lr(row["epoch"] - 1)}
        if validate is not None and config.validates_after(row["epoch"]):
            t1 = time.perf_counter()
            out.update(validate(unwrap(ddp)))
            out["val_seconds"] = time.perf_counter() - t1
        return out

    loop.run_epochs(batches, step, end_epoch=end_epoch, on_epoch=on_epoch,
                    reduce=lambda means: all_reduce_mean(means, ctx), barrier=lambda: barrier(ctx))
    return FitResult(loop.history, loop.resumed_from, loop.note, time.perf_counter() - t_start)
