"""Unsupervised pretraining of a flow network (PWC-Lite) with ARFlow's schedule, resumable (ARFlow's code:
``configs/sintel_raw.json``, ``configs/sintel_ft.json``, ``trainer/base_trainer.py``).

Schedule: ``raw_epochs`` epochs with the ``sintel_raw`` loss (0.15·L1 + 0.85·SSIM, range-map occlusion),
then ``census_epochs`` with the ``sintel_ft`` loss (census, forward–backward occlusion) — ARFlow's
``stage1`` switch. Adam, constant lr, betas (0.9, 0.999), eps 1e-7, weight decay 1e-6 on weights and 0 on
biases; batches of frame pairs resized to the training size, horizontal flip and frame-order swap.

Initialisation (``init``): ``msra`` (default) draws every convolution from Kaiming-normal (fan-in) with
zero biases — the body of ARFlow's ``init_weights``, which never runs there (ARFlow's ``models/pwclite.py``);
``pytorch`` keeps PyTorch's default, i.e. what ARFlow really trains from. With the default the pyramid
features are so small that the cost volume is ~1e-3 of the decoder's other inputs and the output
hardly depends on the images for the first hundreds of steps. With MSRA the correlation peak is at the
true shift only on average over the image; per pixel it is at chance, and a CPU-sized run of this schedule
settles on one image-independent field (docs/flow_pretrain.md). The CPU default therefore takes the
supervised chairs route (f2depth.flow.bootstrap).

The epoch loop, resume (``<resume_dir>/last.pt``, deleted by :func:`clear_resume` once the model is
written) and the non-finite policy (a NaN/inf step is skipped and counted) are :mod:`f2depth.epochs`.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import torch

from f2depth.epochs import EpochLoop, clear_state, epoch_generator
from f2depth.epochs import fingerprint as hash_settings
from f2depth.flow.augment import flip_and_swap
from f2depth.flow.loss import SINTEL_FT, SINTEL_RAW, flow_loss
from f2depth.flow.net.network import FlowNetwork, make_optimizer, msra_init
from f2depth.formats.sintel import SintelPair, SintelPairs
from f2depth.precision import backward_and_step

HISTORY_COLUMNS = ("epoch", "loss", "photometric", "smooth", "flow_mean", "noc_fraction", "steps",
                   "skipped_steps", "census", "seconds")


@dataclass(frozen=True)
class PretrainConfig:
    """The training keys of the ``flow_pretrain`` section (ranges checked by f2depth.params.section)."""

    height: int = field(default=96, metadata={"min": 1})
    width: int = field(default=128, metadata={"min": 1})
    raw_epochs: int = field(default=16, metadata={"min": 0})
    census_epochs: int = field(default=0, metadata={"min": 0})
    batch_size: int = field(default=4, metadata={"min": 1})
    lr: float = field(default=4e-4, metadata={"gt": 0})
    weight_decay: float = field(default=1e-6, metadata={"fixed": True})  # ARFlow's, on weights only
    seed: int = 0
    init: str = "msra"   # msra: what ARFlow's init_weights means to do; pytorch: what it does (a no-op)

    def __post_init__(self) -> None:
        if self.init not in ("msra", "pytorch"):
            raise ValueError(f"PretrainConfig.init must be 'msra' or 'pytorch', got {self.init!r}")

    @property
    def epochs(self) -> int:
        return self.raw_epochs + self.census_epochs

    def loss_config(self, epoch: int):
        """The loss of (0-based) ``epoch``: sintel_raw first, then sintel_ft."""
        return SINTEL_RAW if epoch < self.raw_epochs else SINTEL_FT


def run_fingerprint(cfg: PretrainConfig, pairs: Sequence[SintelPair]) -> str:
    """What a resume file must match: the configuration and the training pairs, their names and the
    contents of their images (regenerated frames of the same count start afresh)."""
    files = {f"{i}.{k}": getattr(pair, k) for i, pair in enumerate(pairs) for k in ("image1", "image2")}
    names = [(pair.sequence, pair.frame, pair.pass_name) for pair in pairs]
    return hash_settings({"config": asdict(cfg), "pairs": names}, files)


def clear_resume(resume_dir: str | os.PathLike) -> None:
    """Delete the training state of a finished run (a later run then starts afresh)."""
    clear_state(Path(resume_dir) / "last.pt")


def pretrain(model: FlowNetwork, pairs: Sequence[SintelPair], cfg: PretrainConfig,
             resume_dir: str | os.PathLike | None = None, device: str = "cpu",
             on_epoch: Callable[[dict[str, Any]], None] | None = None,
             progress: bool = True) -> dict[str, Any]:
    """Train ``model`` in place on ``pairs`` → ``{"epochs_run", "resumed_from", "seconds", "history"}``.

    ``on_epoch(row)`` (:class:`f2depth.epochs.EpochLoop`'s hook) gets each epoch's history row (``epoch``,
    mean loss terms, steps taken and skipped, ``census``, ``seconds``), first each row a resumed run has.
    Each epoch's order and flips / swaps come from :func:`f2depth.epochs.epoch_generator` (seed, epoch).
    """
    model.to(device).train()
    optim = make_optimizer(model, cfg)
    dataset = SintelPairs(pairs, (cfg.height, cfg.width))
    loop = EpochLoop("flow_pretrain", cfg.epochs, {"model": model, "optimizer": optim},
                     Path(resume_dir) / "last.pt" if resume_dir is not None else None,
                     run_fingerprint(cfg, pairs), progress=progress)
    if not loop.restore() and cfg.init == "msra":
        msra_init(model, torch.Generator().manual_seed(cfg.seed))

    loss_cfg = SINTEL_RAW

    def batches(epoch: int) -> Iterator[tuple[torch.Tensor, torch.Tensor]]:
        nonlocal loss_cfg
        loss_cfg = cfg.loss_config(epoch - 1)
        gen = epoch_generator(cfg.seed, epoch)
        order = torch.randperm(len(dataset), generator=gen).tolist()
        for img1, img2 in torch.utils.data.DataLoader(dataset, batch_size=cfg.batch_size, sampler=order):
            yield flip_and_swap(img1, img2, gen)

    def step(batch: list[torch.Tensor]) -> dict[str, float]:
        img1, img2 = batch[0].to(device), batch[1].to(device)
        flows_fw, flows_bw = model(img1, img2, with_backward=True)
        loss, stats = flow_loss(flows_fw, flows_bw, img1, img2, loss_cfg)
        optim.zero_grad(set_to_none=True)
        if not torch.isfinite(loss):
            raise FloatingPointError(f"loss is {loss.item()}")
        backward_and_step(loss, optim)
        return stats

    t0 = time.perf_counter()
    loop.run_epochs(batches, step, end_epoch=lambda row: {"census": float(loss_cfg is SINTEL_FT)},
                    on_epoch=on_epoch)
    model.eval()
    return {"epochs_run": cfg.epochs - loop.resumed_from, "resumed_from": loop.resumed_from,
            "seconds": round(time.perf_counter() - t0, 1), "history": loop.history}
