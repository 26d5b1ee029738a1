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
hardly depends on the images for the first hundreds of steps; with MSRA the correlation peaks are
visible from the start, which is what makes a CPU-sized pretraining possible.

A step whose loss is not finite is skipped (counted in the epoch stats), so no NaN reaches the
optimiser. After every epoch the full training state (model, optimiser, epoch, RNG) is written
atomically to ``<resume_dir>/last.pt``; a later run with the same configuration continues from it.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import torch
from tqdm import tqdm

from f2depth.data.sintel import SintelPair, SintelPairs
from f2depth.flow.loss import SINTEL_FT, SINTEL_RAW, flow_loss
from f2depth.flow.network import FlowNetwork, msra_init
from f2depth.io import torch_save

RESUME_FORMAT = "f2depth.pwclite_resume"
RESUME_VERSION = 1


@dataclass(frozen=True)
class PretrainConfig:
    height: int = 128
    width: int = 192
    raw_epochs: int = 4
    census_epochs: int = 4
    batch_size: int = 4
    lr: float = 1e-4
    weight_decay: float = 1e-6
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


def make_optimizer(model: torch.nn.Module, cfg: PretrainConfig) -> torch.optim.Optimizer:
    """ARFlow's Adam: weight decay on weights only (bias_decay 0)."""
    weights = [p for n, p in model.named_parameters() if not n.endswith("bias")]
    biases = [p for n, p in model.named_parameters() if n.endswith("bias")]
    return torch.optim.Adam(
        [{"params": weights, "weight_decay": cfg.weight_decay}, {"params": biases, "weight_decay": 0.0}],
        lr=cfg.lr, betas=(0.9, 0.999), eps=1e-7)


def _resume_file(resume_dir: str | os.PathLike) -> Path:
    return Path(resume_dir) / "last.pt"


def clear_resume(resume_dir: str | os.PathLike) -> None:
    """Delete the training state of a finished run (a later run then starts afresh)."""
    path = _resume_file(resume_dir)
    path.unlink(missing_ok=True)
    if path.parent.is_dir() and not any(path.parent.iterdir()):
        path.parent.rmdir()


def _load_resume(path: Path, cfg: PretrainConfig, n_pairs: int) -> dict[str, Any] | None:
    if not path.is_file():
        return None
    state = torch.load(path, map_location="cpu", weights_only=True)
    if (not isinstance(state, dict) or state.get("format") != RESUME_FORMAT
            or state.get("version") != RESUME_VERSION or state.get("config") != asdict(cfg)
            or state.get("n_pairs") != n_pairs):
        return None  # another configuration or data set: start afresh (the file is overwritten)
    return state


def pretrain(model: FlowNetwork, pairs: Sequence[SintelPair], cfg: PretrainConfig,
             resume_dir: str | os.PathLike | None = None, device: str = "cpu",
             on_epoch: Callable[[int, dict[str, float]], None] | None = None,
             progress: bool = True) -> dict[str, Any]:
    """Train ``model`` in place on ``pairs`` → ``{"epochs_run", "resumed_from", "seconds", "history"}``.

    ``on_epoch(epoch, stats)`` is called after each epoch (1-based epoch; mean loss terms, skipped steps).
    """
    model.to(device).train()
    optim = make_optimizer(model, cfg)
    dataset = SintelPairs(pairs, (cfg.height, cfg.width), augment=True)
    start, history = 0, []
    resume = _resume_file(resume_dir) if resume_dir is not None else None
    state = _load_resume(resume, cfg, len(pairs)) if resume is not None else None
    if state is not None:
        model.load_state_dict(state["model"])
        optim.load_state_dict(state["optimizer"])
        start, history = int(state["epoch"]), list(state["history"])
    elif cfg.init == "msra":
        msra_init(model, torch.Generator().manual_seed(cfg.seed))
    t0 = time.perf_counter()
    for epoch in range(start, cfg.epochs):
        torch.manual_seed(cfg.seed * 100_003 + epoch)  # shuffling and augmentation of this epoch
        loader = torch.utils.data.DataLoader(dataset, batch_size=cfg.batch_size, shuffle=True)
        loss_cfg = cfg.loss_config(epoch)
        sums: dict[str, float] = {}
        steps = skipped = 0
        bar = tqdm(loader, desc=f"flow_pretrain {epoch + 1}/{cfg.epochs}", disable=not progress,
                   leave=False)
        for img1, img2 in bar:
            img1, img2 = img1.to(device), img2.to(device)
            flows_fw, flows_bw = model(img1, img2, with_backward=True)
            loss, stats = flow_loss(flows_fw, flows_bw, img1, img2, loss_cfg)
            optim.zero_grad(set_to_none=True)
            if not torch.isfinite(loss):
                skipped += 1
                continue
            loss.backward()
            optim.step()
            steps += 1
            for k, v in stats.items():
                sums[k] = sums.get(k, 0.0) + v
            bar.set_postfix(loss=f"{stats['loss']:.4f}")
        epoch_stats = {k: v / max(steps, 1) for k, v in sums.items()}
        epoch_stats.update(steps=steps, skipped_steps=skipped,
                           census=float(loss_cfg is SINTEL_FT))
        if not all(math.isfinite(v) for v in epoch_stats.values()):
            raise FloatingPointError(f"flow_pretrain: non-finite epoch statistics {epoch_stats}")
        history.append(epoch_stats)
        if resume is not None:
            torch_save(resume, {"format": RESUME_FORMAT, "version": RESUME_VERSION, "config": asdict(cfg),
                                "n_pairs": len(pairs), "epoch": epoch + 1, "history": history,
                                "model": {k: v.detach().cpu() for k, v in model.state_dict().items()},
                                "optimizer": optim.state_dict()})
        if on_epoch is not None:
            on_epoch(epoch + 1, epoch_stats)
    model.eval()
    return {"epochs_run": cfg.epochs - start, "resumed_from": start,
            "seconds": round(time.perf_counter() - t0, 1), "history": history}
