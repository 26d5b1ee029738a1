"""The epoch loop of depth training: schedule, data order, steps, validation, checkpoints, resume.

``fit`` trains a DepthModel for ``config.epochs`` epochs (epochs are numbered from 1; epoch 0 is the
untrained network's validation) and returns the per-epoch history. After every epoch rank 0 writes the
resumable state (``checkpoint.save_state``); with ``resume`` a matching state continues where it stopped.
Because the data order, the augmentation and the fill-up points depend only on (seed, epoch, index), the
optimizer state is restored exactly and the learning rate is a function of the epoch, a resumed CPU run
ends with the same weights as an uninterrupted one.
"""

from __future__ import annotations

import csv
import io
import random
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch.utils.data import DataLoader
from tqdm import tqdm

from f2depth.depth import DepthModel
from f2depth.io import write_text
from f2depth.losses.total import TERMS
from f2depth.precision import grad_scaler
from f2depth.train import checkpoint as ckpt
from f2depth.train.data import EpochView, TupleDataset, rank_indices
from f2depth.train.diagnostics import DIAGNOSTIC_KEYS
from f2depth.train.distributed import (
    DistContext,
    agree_finite,
    all_reduce_mean,
    barrier,
    unwrap,
    wrap_model,
)
from f2depth.train.schedule import LRSchedule
from f2depth.train.step import StepConfig, batch_to, train_step
from f2depth.train.teacher import FlowTeacher

#: Columns of history.csv (DVC plots, x = epoch); empty cells for values a row does not have.
HISTORY_COLUMNS = ["epoch", *TERMS, "total", "lr", "val_abs_rel", "val_a1", *DIAGNOSTIC_KEYS, "seconds",
                   "val_seconds"]


@dataclass(frozen=True)
class LoopConfig:
    epochs: int
    batch_size: int  # global batch: per-rank batch = batch_size / world size
    schedule: LRSchedule
    seed: int = 0
    workers: int = 0
    sync_bn: bool = True
    progress: bool = True

    def __post_init__(self) -> None:
        if self.epochs < 1 or self.batch_size < 1:
            raise ValueError(f"epochs and batch_size must be >= 1, got {self.epochs}, {self.batch_size}")
        if self.schedule.epochs != self.epochs:
            raise ValueError(f"the lr schedule covers {self.schedule.epochs} epochs, the run {self.epochs}")


@dataclass
class FitResult:
    history: list[dict[str, Any]]
    resumed_from: int = 0  # finished epochs taken from a checkpoint (0 = fresh start)
    resume_note: str = ""
    seconds: float = 0.0  # wall time of this call
    state: dict[str, Any] = field(default_factory=dict)


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
    Raises ``NonFiniteLossError`` (naming the term) when a loss becomes NaN/inf; the last checkpoint stays.
    """
    ctx = ctx or DistContext()
    t_start = time.perf_counter()
    result = FitResult(history=[])
    state, note = (None, "resume disabled") if not resume or checkpoint is None else ckpt.load_state(
        checkpoint, fingerprint)
    result.resume_note = note
    if state is not None:
        model.load_state_dict(state["model"])
        result.history = [dict(r) for r in state["history"]]
        result.resumed_from = int(state["epoch"])
    ddp = wrap_model(model, ctx, sync_bn=config.sync_bn)
    optimizer = torch.optim.Adam(ddp.parameters(), lr=config.schedule.lr(0))
    scaler = grad_scaler(ctx.device, step_config.amp)
    if state is not None:
        optimizer.load_state_dict(state["optimizer"])
        if state["scaler"] and scaler.is_enabled():
            scaler.load_state_dict(state["scaler"])
        ckpt.set_rng_state(state["rng"])
    elif validate is not None and ctx.is_main:
        t0 = time.perf_counter()
        result.history.append({"epoch": 0, **validate(model), "val_seconds": time.perf_counter() - t0})
    if ctx.is_main and on_epoch is not None:
        for row in result.history:
            on_epoch(row)

    def agree(error):
        agree_finite(error, ctx)

    for epoch in range(result.resumed_from + 1, config.epochs + 1):
        lr = config.schedule.lr(epoch - 1)
        for group in optimizer.param_groups:
            group["lr"] = lr
        ddp.train()
        t0 = time.perf_counter()
        sums: dict[str, float] = {}
        steps = 0
        loader = _loader(dataset, epoch, config, ctx)
        bar = tqdm(loader, desc=f"epoch {epoch}/{config.epochs}", leave=False,
                   disable=not (config.progress and ctx.is_main))
        for step, batch in enumerate(bar):
            batch = batch_to(batch, ctx.device)
            _, logs = train_step(ddp, optimizer, batch, teacher, step_config, scaler,
                                 context=f"epoch {epoch}, step {step}", agree=agree)
            for k, v in logs.items():
                sums[k] = sums.get(k, 0.0) + v
            steps += 1
            bar.set_postfix(loss=f"{logs['total']:.4f}")
        means = all_reduce_mean({k: v / max(steps, 1) for k, v in sums.items()}, ctx)
        row: dict[str, Any] = {"epoch": epoch, **means, "lr": lr, "seconds": time.perf_counter() - t0}
        if validate is not None and ctx.is_main:
            t1 = time.perf_counter()
            row.update(validate(unwrap(ddp)))
            row["val_seconds"] = time.perf_counter() - t1
        result.history.append(row)
        if ctx.is_main and checkpoint is not None:
            ckpt.save_state(
                checkpoint, fingerprint=fingerprint, epoch=epoch, model=unwrap(ddp),
                config=unwrap(ddp).config.to_dict(), optimizer=optimizer, scaler=scaler,
                sampler={"seed": config.seed, "epoch": epoch}, history=result.history,
            )  # fmt: skip
        barrier(ctx)
        if ctx.is_main and on_epoch is not None:
            on_epoch(row)
    result.seconds = time.perf_counter() - t_start
    return result


def history_csv(history: list[dict[str, Any]]) -> str:
    """The rows as CSV text with ``HISTORY_COLUMNS`` (floats with 6 significant digits, blanks for gaps)."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(HISTORY_COLUMNS)
    for row in history:
        w.writerow([_cell(row.get(c)) for c in HISTORY_COLUMNS])
    return buf.getvalue()


def _cell(v: Any) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return f"{v:.6g}"
    return str(v)


def write_history(path: str | Path, history: list[dict[str, Any]]) -> None:
    write_text(path, history_csv(history))
