"""Supervised pretraining of a flow network on generated FlyingChairs-style pairs, with the bootstrap that
makes a from-scratch PWC-Lite learn on a CPU (docs/flow_pretrain.md, "The chairs route").

Why a bootstrap: after MSRA the pyramid features are dominated by their per-channel means, so the cost
volume is a smooth bowl whose argmax is at the true shift only when averaged over all pixels; per pixel
it is at chance, the decoder has nothing to read, and plain supervised (or unsupervised) training settles
on one image-independent field. The recipe:

1. MSRA, then a **data-dependent init** (:func:`data_dependent_init`: every convolution's pre-activation
   to zero mean and unit variance per channel on one calibration batch), and the **flow-writing
   convolutions zeroed** (``FlowNetwork.flow_heads``), so the first output is zero flow;
2. **phase A** (``feature_epochs``): the feature pyramid alone, trained with a cost-volume cross-entropy
   (:func:`matching_loss`: the softmax over the 81 displacements of √C·corr at strides 4 and 8 pushed
   towards the true displacement), lr ``feature_lr``;
3. **phase B** (``epochs``): the whole network, multi-scale EPE (:func:`multiscale_epe`) +
   ``matching_weight`` × the matching loss, lr falling along a cosine from ``lr`` to ``final_lr``
   (:meth:`BootstrapConfig.phase_b_lr`); the network kept is the mean of the weights at the ends of
   phase B's last ``average_epochs`` epochs (f2depth.averaging; 1: the last epoch's weights).

Every epoch is ``steps_per_epoch`` new batches drawn from a generator seeded by (seed, epoch), so a
resumed run (``<resume_dir>/last.pt``, :mod:`f2depth.epochs`) sees exactly the batches of an unbroken one.
Adam with ARFlow's betas and eps (:func:`f2depth.flow.net.network.make_optimizer`), no weight decay.
"""

from __future__ import annotations

import hashlib
import math
import os
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from f2depth.averaging import WeightAverage
from f2depth.data_parallel import SINGLE, Group
from f2depth.epochs import EpochLoop, epoch_rng
from f2depth.epochs import fingerprint as hash_settings
from f2depth.flow.chairs import ChairsSpec, render_pairs
from f2depth.flow.evaluation import EPEAccumulator
from f2depth.flow.net.correlation import MAX_DISPLACEMENT, correlation
from f2depth.flow.net.network import FlowNetwork, make_optimizer, msra_init
from f2depth.geometry import endpoint_error
from f2depth.precision import autocast

#: history.csv: what every epoch measures (f2depth.epochs.write_history)
HISTORY_COLUMNS = ("epoch", "phase", "loss", "matching", "top1_s4", "top1_s8", "steps", "skipped_steps",
                   "heldout_epe", "heldout_zero_epe", "heldout_top1_s4", "heldout_top1_s8", "seconds")
#: phase_b.csv: what phase B's epochs add, the training EPE and the held-out swap consistency (phase A's
#: zero flow has no direction)
PHASE_B_COLUMNS = ("epoch", "epe", "heldout_swap")
EPOCH_TEST_PAIRS = 16  # held-out pairs scored after every epoch (all of them after phase A and at the end)


@dataclass(frozen=True)
class BootstrapConfig:
    """The ``flow_pretrain.chairs`` keys: the generated data (``data``) and the bootstrap's schedule."""

    data: ChairsSpec
    batch_size: int = field(metadata={"min": 1})
    steps_per_epoch: int = field(metadata={"min": 1})
    feature_epochs: int = field(metadata={"min": 0})    # phase A: the feature pyramid alone
    feature_lr: float = field(metadata={"gt": 0})
    epochs: int = field(metadata={"min": 1})            # phase B: the whole network
    lr: float = field(metadata={"gt": 0})
    final_lr: float = field(metadata={"gt": 0})          # phase B's lr falls from lr to this (cosine)
    matching_weight: float = field(metadata={"min": 0})  # of the matching loss in phase B
    matching_strides: tuple[int, ...]                    # pyramid strides the matching loss reads
    w_scales: tuple[float, ...]                          # multi-scale EPE weight per level, finest first
    calibration_pairs: int = field(metadata={"min": 2})  # batch of the data-dependent init
    heldout_pairs: int = field(metadata={"min": 1})      # generated test pairs (own seed), never trained on
    average_epochs: int = field(metadata={"min": 1})     # the weights kept: mean over phase B's last N epochs
    amp: bool                                            # network passes under autocast (f2depth.precision)
    cpu_ranks: int | None = field(metadata={"min": 1})   # CPU: 1-thread data-parallel processes
    weight_decay: float = field(default=0.0, metadata={"fixed": True})

    def __post_init__(self) -> None:
        if not self.w_scales or any(w < 0 for w in self.w_scales):
            raise ValueError(f"w_scales = {list(self.w_scales)} must be non-negative weights, finest first")
        if self.final_lr > self.lr:
            raise ValueError(f"final_lr = {self.final_lr} is above lr = {self.lr}; phase B's lr only falls")
        if any(s < 1 for s in self.matching_strides):
            raise ValueError(f"matching_strides = {list(self.matching_strides)} must be pyramid strides >= 1")
        if self.cpu_ranks and self.batch_size % self.cpu_ranks:
            raise ValueError(f"batch_size = {self.batch_size} does not split into cpu_ranks = "
                             f"{self.cpu_ranks} equal parts; make it a multiple of cpu_ranks")
        if self.average_epochs > self.epochs:
            raise ValueError(f"average_epochs = {self.average_epochs} is more than phase B's epochs = "
                             f"{self.epochs}; set it to at most {self.epochs} (1: the last epoch's weights)")

    @property
    def total_epochs(self) -> int:
        return self.feature_epochs + self.epochs

    def phase_b_lr(self, step: int) -> float:
        """Phase B's lr at its ``step`` (0-based): a cosine from ``lr`` to ``final_lr`` over its steps."""
        progress = min(step / max(self.epochs * self.steps_per_epoch - 1, 1), 1.0)
        return self.final_lr + 0.5 * (self.lr - self.final_lr) * (1.0 + math.cos(math.pi * progress))


# ---- the start ------------------------------------------------------------------------------------------

@torch.no_grad()
def data_dependent_init(model: nn.Module, img1: torch.Tensor, img2: torch.Tensor, sweeps: int = 2,
                        min_std: float = 1e-3, skip: Sequence[nn.Module] = ()) -> dict[str, float]:
    """Rescale every convolution of ``model`` in place so that, on the calibration pair ``img1, img2
    (B,3,H,W)``, its output has zero mean and unit variance per channel.

    The convolutions are calibrated one at a time in the order the forward pass first uses them, each
    after everything before it, with one forward pass (frame 1 → 2) each: its per-channel statistics are
    pooled over all its uses (PWC-Lite's shared decoder and context network run at every pyramid level;
    the finest dominates), then its weight becomes ``w/σ`` and its bias ``(b−μ)/σ``. (Calibrated on the
    first use alone, the coarsest 2×2 level, the shared modules amplify the finer levels many times over.)
    A convolution calibrated before one that feeds it at a later use (the decoder's first layer reads each
    level's ``conv_1x1``) is off again afterwards, so the whole order is swept ``sweeps`` times.
    Channels with σ below ``min_std`` are centred and scaled by ``1/min_std``. The convolutions in
    ``skip`` (the zeroed flow heads) are left as they are. → ``{"convolutions", "max_std_error",
    "max_abs_mean"}``: how many were calibrated and how far their σ and μ are from 1 and 0 at the end."""
    skipped = {id(m) for m in skip}
    order: list[nn.Module] = []
    target: list[nn.Module | None] = [None]   # the convolution whose statistics are being pooled
    sums: list[torch.Tensor] = []

    def hook(module: nn.Module, _inputs: Any, out: torch.Tensor) -> None:
        if id(module) in skipped:
            return
        if target[0] is None and all(m is not module for m in order):
            order.append(module)
        if module is target[0]:
            o = out.detach()
            part = [torch.tensor(o.numel() / o.shape[1], dtype=torch.float64),
                    o.sum((0, 2, 3)).double(), (o * o).sum((0, 2, 3)).double()]
            sums[:] = part if not sums else [a + b for a, b in zip(sums, part)]

    def moments(module: nn.Module) -> tuple[torch.Tensor, torch.Tensor]:
        target[0] = module
        sums.clear()
        model(img1, img2, with_backward=False)
        n, s, ss = sums
        mean = s / n
        return mean, (ss / n - mean * mean).clamp_min(0).sqrt()

    handles = [m.register_forward_hook(hook) for m in model.modules() if isinstance(m, nn.Conv2d)]
    try:
        model(img1, img2, with_backward=False)  # the order of first use
        for _ in range(sweeps):
            for module in order:
                mean, std = moments(module)
                std = std.clamp_min(min_std)
                module.weight.div_(std.view(-1, 1, 1, 1).to(module.weight.dtype))
                if module.bias is not None:
                    module.bias.sub_(mean.to(module.bias.dtype)).div_(std.to(module.bias.dtype))
        check = [moments(m) for m in order]
    finally:
        for h in handles:
            h.remove()
    return {"convolutions": len(order), "max_std_error": max(float((s - 1).abs().max()) for _, s in check),
            "max_abs_mean": max(float(m.abs().max()) for m, _ in check)}


@torch.no_grad()
def zero_flow_heads(model: FlowNetwork) -> int:
    """Zero the weights and biases of the convolutions that write flow (``model.flow_heads()``) → how many."""
    heads = model.flow_heads()
    for conv in heads:
        conv.weight.zero_()
        if conv.bias is not None:
            conv.bias.zero_()
    return len(heads)


# ---- losses ---------------------------------------------------------------------------------------------

def flow_at(flow: torch.Tensor, size: tuple[int, int]) -> torch.Tensor:
    """Ground truth ``flow (B,2,H,W)`` px area-averaged to ``size`` = (h, w), in pixels of that size."""
    h, w = size
    H, W = flow.shape[-2:]
    scale = torch.tensor([w / W, h / H], dtype=flow.dtype, device=flow.device).view(1, 2, 1, 1)
    return F.interpolate(flow, size=size, mode="area") * scale


def multiscale_epe(flows: Sequence[torch.Tensor], gt: torch.Tensor, weights: Sequence[float]
                   ) -> tuple[torch.Tensor, list[float]]:
    """Σ_i w_i · mean EPE of level i, the ground truth ``gt (B,2,H,W)`` area-averaged to level i and in its
    pixels. ``flows``: finest first, level i ``(B,2,h_i,w_i)`` in its own pixels → (loss, EPE per level)."""
    loss = gt.new_zeros(())
    per_level = []
    for f, w in zip(flows, weights):
        epe = endpoint_error(f, flow_at(gt, tuple(f.shape[-2:]))).mean()
        loss = loss + w * epe
        per_level.append(float(epe.detach()))
    return loss, per_level


def _stride(image_h: int, level: torch.Tensor) -> int:
    return round(image_h / level.shape[-2])


def matching_loss(feats1: Sequence[torch.Tensor], feats2: Sequence[torch.Tensor], flow: torch.Tensor,
                  occluded: torch.Tensor, strides: Sequence[int], radius: int = MAX_DISPLACEMENT
                  ) -> tuple[torch.Tensor, dict[str, float]]:
    """Cost-volume cross-entropy of the pyramid levels at ``strides`` → (mean over levels, stats).

    ``feats1, feats2``: ``FlowNetwork.features`` of the two images; ``flow (B,2,H,W)`` px and ``occluded
    (B,1,H,W)`` bool at the images' size. At each level the (2r+1)² correlations ×√C (a dot product over
    √C) are a softmax over displacements; the target puts the true displacement (ground truth
    area-averaged to the level) on its four integer neighbours with bilinear weights. Scored: pixels whose
    area is fully visible in frame 2 and whose displacement lies within ±r. Stats: ``matching`` (the loss)
    and ``top1_s<stride>``, the share of scored pixels whose argmax is the nearest integer displacement.
    """
    image_h = flow.shape[-2]
    n = 2 * radius + 1
    losses, stats = [], {}
    for f1, f2 in zip(feats1, feats2):
        stride = _stride(image_h, f1)
        if stride not in strides:
            continue
        size = tuple(f1.shape[-2:])
        logp = F.log_softmax(correlation(f1, f2, radius).float() * math.sqrt(f1.shape[1]), 1)  # (B,n²,h,w)
        d = flow_at(flow, size)
        visible = F.interpolate((~occluded).float(), size=size, mode="area") > 0.999
        scored = visible[:, 0] & (d.abs() <= radius).all(1)
        lo = d.floor()
        frac = d - lo
        target = torch.zeros_like(logp)
        for ox in (0, 1):
            for oy in (0, 1):
                wx = frac[:, 0] if ox else 1 - frac[:, 0]
                wy = frac[:, 1] if oy else 1 - frac[:, 1]
                dx, dy = lo[:, 0] + ox, lo[:, 1] + oy
                ok = (dx.abs() <= radius) & (dy.abs() <= radius)
                index = ((dy.clamp(-radius, radius) + radius) * n + dx.clamp(-radius, radius) + radius).long()
                target.scatter_add_(1, index[:, None], (wx * wy * ok)[:, None])
        nearest = ((d[:, 1].round() + radius) * n + d[:, 0].round() + radius).long()
        ce = -(target * logp).sum(1)
        count = int(scored.sum())
        losses.append(ce[scored].mean() if count else logp.new_zeros(()))
        hit = (logp.argmax(1) == nearest)[scored]
        stats[f"top1_s{stride}"] = float(hit.float().mean()) if count else float("nan")
    if not losses:
        raise ValueError(f"matching_loss: no pyramid level has a stride in {list(strides)} (image height "
                         f"{image_h}; levels {[tuple(f.shape[-2:]) for f in feats1]})")
    loss = torch.stack(losses).mean()
    return loss, {"matching": float(loss.detach()), **stats}


# ---- training -------------------------------------------------------------------------------------------

def pool_digest(pool: torch.Tensor) -> str:
    """A digest of the texture pool's contents (part of the resume fingerprint)."""
    return hashlib.sha256(pool.contiguous().numpy().tobytes()).hexdigest()[:16]


def run_fingerprint(cfg: BootstrapConfig, seed: int, pool: torch.Tensor, network: str) -> str:
    """What a resume file must match: the configuration, seed, network and the texture pool's contents."""
    return hash_settings({"config": asdict(cfg), "seed": seed, "network": network, "pool": pool_digest(pool)})


def heldout_pairs(cfg: BootstrapConfig, seed: int, pool: torch.Tensor) -> tuple[torch.Tensor, ...]:
    """The generated test pairs (a seed stream of their own): ``img1, img2, flow, occluded``."""
    rng = np.random.default_rng([seed, 1_000_003])
    return render_pairs(cfg.data, pool, rng, cfg.heldout_pairs)


@torch.no_grad()
def heldout_scores(model: FlowNetwork, pairs: Sequence[torch.Tensor], cfg: BootstrapConfig, device: str,
                   batch: int = 8) -> dict[str, float]:
    """EPE (and zero flow's), swap consistency and matching top-1 of ``model`` on generated ``pairs``."""
    was_training = model.training
    model.eval()
    acc, zero = EPEAccumulator(), EPEAccumulator()
    tops: dict[str, list[float]] = {}
    img1, img2, gt, occ = pairs
    for i in range(0, len(img1), batch):
        a, b = img1[i:i + batch].to(device), img2[i:i + batch].to(device)
        g, o = gt[i:i + batch], occ[i:i + batch]
        pred = model(a, b, with_backward=False)[0][0].cpu()
        acc.add(pred, g, o)
        acc.add_swapped(pred, model(b, a, with_backward=False)[0][0].cpu())
        zero.add(torch.zeros_like(g), g, o)
        _, st = matching_loss(model.features(a), model.features(b), g.to(device), o.to(device),
                              cfg.matching_strides)
        for k, v in st.items():
            if k.startswith("top1"):
                tops.setdefault(k, []).append(v)
    model.train(was_training)
    m, z = acc.result(), zero.result()
    return {"heldout_epe": m["epe_all"], "heldout_zero_epe": z["epe_all"],
            "heldout_swap": m["swap_consistency"],
            **{f"heldout_{k}": float(np.nanmean(v)) for k, v in tops.items()}}


def calibration_batch(cfg: BootstrapConfig, seed: int, pool: torch.Tensor, device: str
                      ) -> tuple[torch.Tensor, torch.Tensor]:
    """The data-dependent init's batch of ``cfg.calibration_pairs`` generated pairs (a seed stream of its
    own): ``img1, img2`` on ``device``."""
    a, b, _, _ = render_pairs(cfg.data, pool, np.random.default_rng([seed, 2_000_003]), cfg.calibration_pairs)
    return a.to(device), b.to(device)


def recalibrate_decoder(model: FlowNetwork, calibration: tuple[torch.Tensor, torch.Tensor]
                        ) -> dict[str, float]:
    """The data-dependent init again, of every convolution outside ``model.feature_module()`` (and the flow
    heads), on the ``calibration`` pair batch: phase A changes the features' statistics, which the decoder
    was calibrated on."""
    features = {id(m) for m in model.feature_module().modules()}
    skip = [m for m in model.modules() if id(m) in features] + list(model.flow_heads())
    return data_dependent_init(model, *calibration, skip=skip)


def bootstrap_start(model: FlowNetwork, calibration: tuple[torch.Tensor, torch.Tensor], seed: int
                    ) -> dict[str, float]:
    """MSRA (seeded by ``seed``), zeroed flow heads and the data-dependent init on the ``calibration`` pair
    batch (:func:`calibration_batch`) → the init's report (:func:`data_dependent_init`)."""
    msra_init(model, torch.Generator().manual_seed(seed))
    zero_flow_heads(model)  # first, so the calibration sees the zero flow that training starts from
    model.to(calibration[0].device)
    return data_dependent_init(model, *calibration, skip=model.flow_heads())


def pretrain_chairs(model: FlowNetwork, pool: torch.Tensor, cfg: BootstrapConfig, seed: int, network: str,
                    heldout: Sequence[torch.Tensor], resume_dir: str | os.PathLike | None = None,
                    device: str = "cpu",
                    on_epoch: Callable[[dict[str, Any]], None] | None = None,
                    progress: bool = True, group: Group = SINGLE) -> dict[str, Any]:
    """Train ``model`` in place (module docstring) and leave it holding the mean of the last
    ``average_epochs`` epochs' weights → ``{"epochs_run", "resumed_from", "averaged_epochs", "seconds",
    "history", "start", "after_features", "last_epoch", "final"}`` (the last four: :func:`heldout_scores` on
    the generated ``heldout`` pairs, :func:`heldout_pairs`, after the init, after phase A, with the last
    epoch's weights and with the mean kept).
    ``on_epoch(row)`` as in :func:`f2depth.flow.pretrain.pretrain`. ``group``: this process's rank of a
    data-parallel run (:mod:`f2depth.flow.chairs_ranks`): it trains on its part of every global batch, the
    ranks average their gradients, and only rank 0 measures, saves the resume file and calls ``on_epoch``;
    the other ranks' ``model`` ends with the last epoch's weights, and they return ``{"epochs_run"}``."""
    model.to(device).train()
    opt_a = make_optimizer(model.feature_module(), _Lr(cfg.feature_lr, cfg.weight_decay))
    opt_b = make_optimizer(model, _Lr(cfg.lr, cfg.weight_decay))
    average = WeightAverage()
    loop = EpochLoop("flow_pretrain", cfg.total_epochs, {"model": model, "features_optimizer": opt_a,
                                                         "optimizer": opt_b, "average": average},
                     Path(resume_dir) / "last.pt" if resume_dir is not None else None,
                     run_fingerprint(cfg, seed, pool, network), main=group.main, progress=progress)
    test = tuple(heldout)
    calibration = calibration_batch(cfg, seed, pool, device)
    scores: dict[str, Any] = {}
    if not loop.restore():
        bootstrap_start(model, calibration, seed)  # the same weights on every rank
        if group.main:
            scores["start"] = heldout_scores(model, test, cfg, device)
    phase, b_step = "features", 0

    def batches(epoch: int) -> _Batches:
        nonlocal phase, b_step
        phase = "features" if epoch <= cfg.feature_epochs else "all"
        b_step = max(epoch - cfg.feature_epochs - 1, 0) * cfg.steps_per_epoch  # also right after a resume
        if epoch == cfg.feature_epochs + 1:
            group.broadcast(model)  # rank 0 alone recalibrated the decoder after phase A
        return _Batches(cfg, pool, epoch_rng(seed, epoch), group.part(cfg.batch_size))

    def step(batch: tuple[torch.Tensor, ...]) -> dict[str, float]:
        nonlocal b_step
        img1, img2, gt, occ = (t.to(device) for t in batch)
        with autocast(device, cfg.amp):  # the network's passes; the losses below in float32
            feats1, feats2 = model.features(img1), model.features(img2)
            flows = model(img1, img2, with_backward=False)[0] if phase == "all" else []
        match, stats = matching_loss(feats1, feats2, gt, occ, cfg.matching_strides)
        if phase == "features":
            loss, optim = match, opt_a
        else:
            for param_group in opt_b.param_groups:
                param_group["lr"] = cfg.phase_b_lr(b_step)
            b_step += 1
            epe, levels = multiscale_epe([f.float() for f in flows], gt, cfg.w_scales)
            loss, optim = epe + cfg.matching_weight * match, opt_b
            stats["epe"] = levels[0]
        _backward_averaged(loss, optim, group)
        return {"loss": float(loss.detach()), **stats}

    def end_epoch(row: dict[str, Any]) -> dict[str, Any]:
        out = {"phase": phase,
               **heldout_scores(model, tuple(t[:EPOCH_TEST_PAIRS] for t in test), cfg, device)}
        if row["epoch"] == cfg.feature_epochs:
            recalibrate_decoder(model, calibration)
            scores["after_features"] = heldout_scores(model, test, cfg, device)
        if row["epoch"] > cfg.total_epochs - cfg.average_epochs:
            average.add(model)
        return out

    t0 = time.perf_counter()
    loop.run_epochs(batches, step, end_epoch=end_epoch, on_epoch=on_epoch,
                    reduce=group.mean, barrier=group.barrier)
    model.eval()
    if not group.main:
        return {"epochs_run": cfg.total_epochs - loop.resumed_from}
    scores["last_epoch"] = heldout_scores(model, test, cfg, device)
    average.copy_to(model)
    scores["final"] = heldout_scores(model, test, cfg, device)
    return {"epochs_run": cfg.total_epochs - loop.resumed_from, "resumed_from": loop.resumed_from,
            "averaged_epochs": average.count,
            "seconds": round(time.perf_counter() - t0, 1), "history": loop.history, **scores}


def _backward_averaged(loss: torch.Tensor, optim: torch.optim.Optimizer, group: Group) -> None:
    """One step of ``group`` (one process: :data:`SINGLE`): back-propagate this rank's ``loss``, average the
    gradients over the ranks and step; raises ``FloatingPointError`` on every rank (none steps) when any
    rank's loss is not finite."""
    finite = bool(torch.isfinite(loss))
    optim.zero_grad(set_to_none=True)
    if finite:
        loss.backward()
    params = [p for g in optim.param_groups for p in g["params"]]
    if not group.average_gradients(params, finite):
        raise FloatingPointError(f"the loss is not finite on a rank (this one's: {loss.item()})")
    optim.step()


@dataclass(frozen=True)
class _Batches:
    """One epoch of generated batches (a length, so the progress bar shows the steps left); ``part``: the
    pairs of each global batch this rank renders."""

    cfg: BootstrapConfig
    pool: torch.Tensor
    rng: np.random.Generator
    part: slice

    def __len__(self) -> int:
        return self.cfg.steps_per_epoch

    def __iter__(self) -> Iterator[tuple[torch.Tensor, ...]]:
        for _ in range(self.cfg.steps_per_epoch):
            yield render_pairs(self.cfg.data, self.pool, self.rng, self.cfg.batch_size, self.part)


@dataclass(frozen=True)
class _Lr:
    """What :func:`make_optimizer` reads of a config."""

    lr: float
    weight_decay: float
