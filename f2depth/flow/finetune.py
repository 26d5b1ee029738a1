"""Fine-tuning the flow network (PWC-Lite) on the prepared indoor pairs with F²Depth's patch loss or ARFlow's
own loss (paper §3.1 and §4.1; Table 6), resumable, with per-epoch EPE on synthetic ground truth.

Per step: a batch of pairs (t, t+1) with the keypoints of both frames is flipped and colour-jittered
(:mod:`f2depth.flow.augment`; the network sees the jittered frames, the loss the un-jittered ones), the
network predicts both directions at all its levels (PWC-Lite: five), and :func:`batch_loss` gives L_flow:

* ``patch`` — :func:`f2depth.flow.patch_loss.finetune_loss` with the ``w_scales`` / ``backward`` settings
  (ARFlow's: four scales, both directions, smoothness on the finest level);
* ``full`` — ARFlow's own unsupervised loss, :func:`f2depth.flow.loss.flow_loss` with ``SINTEL_FT``
  (census over every non-occluded pixel, four scales, both directions), λ = ``smooth_weight`` and the range
  map instead of the forward–backward check when ``occlusion`` is ``range_map``.

Adam with ARFlow's settings (betas 0.9/0.999, eps 1e-7, weight decay 1e-6 on weights, none on biases) and
a constant learning rate (paper: 5e-5, 37 epochs, batch 20).

**Mixed precision** (``amp``, off by default and in the ``paper`` profile: ARFlow trains in float32): the
network runs under ``torch.autocast`` (CUDA float16, CPU bfloat16) and the loss in float32 with autocast
off; on CUDA a GradScaler scales the loss.

**Epochs** are :mod:`f2depth.epochs`: a step with a non-finite loss is skipped and counted, an epoch of
nothing else stops the run; after every epoch the model, the optimiser, the grad scaler and the history
are written atomically to ``resume_path`` with a fingerprint (configuration, training pairs and whatever
the caller adds, e.g. hashes of the pretrained model and the keypoints); a matching file is continued after
its last finished epoch. Shuffling and augmentation of epoch e come from a generator seeded by (seed, e),
so a resumed run ends with the same weights as an uninterrupted one.
"""

from __future__ import annotations

import os
import time
import warnings
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import torch

from f2depth.epochs import EpochLoop, epoch_generator
from f2depth.epochs import fingerprint as hash_settings
from f2depth.flow.augment import augment_batch
from f2depth.flow.evaluation import evaluate_gt_pairs
from f2depth.flow.finetune_data import FlowPairs, GTPair, collate
from f2depth.flow.loss import SINTEL_FT, FlowLossConfig, flow_loss
from f2depth.flow.net.network import FlowNetwork, make_optimizer
from f2depth.flow.patch_loss import FinetuneLossConfig, finetune_loss
from f2depth.precision import autocast, backward_and_step, full_precision, grad_scaler

LOSSES = ("patch", "full")
TRAIN_COLUMNS = ("loss", "photometric", "smooth", "used_pixels", "coverage", "noc_fraction")
EPE_COLUMNS = ("epe_all", "epe_noc", "epe_low_texture")
HISTORY_COLUMNS = ("epoch", *TRAIN_COLUMNS, "steps", "skipped_steps", *EPE_COLUMNS, "seconds")


@dataclass(frozen=True)
class FinetuneConfig:
    """The training keys of the ``flow_finetune`` section (ranges checked by f2depth.params.section)."""

    loss: str = "patch"               # patch | full
    epochs: int = field(default=6, metadata={"min": 0})
    batch_size: int = field(default=4, metadata={"min": 1})
    lr: float = field(default=5e-5, metadata={"gt": 0})
    patch_spacing: int = 2
    w_scales: tuple[float, ...] = (1.0, 1.0, 1.0, 1.0, 0.0)  # patch: weight per level, finest first (ARFlow)
    backward: bool = True             # patch: also the backward term (ARFlow's with_bk)
    smooth_weight: float = 50.0       # params.yaml lambda_flow_smooth
    occlusion: str = "range_map"  # ARFlow's warm-up; "forward_backward": the paper's check
    augment: bool = True
    amp: bool = False                 # autocast the network (CUDA float16, CPU bfloat16)
    weight_decay: float = field(default=1e-6, metadata={"fixed": True})  # ARFlow's
    seed: int = 0

    def __post_init__(self) -> None:
        if self.loss not in LOSSES:
            raise ValueError(f"FinetuneConfig.loss must be one of {LOSSES}, got {self.loss!r}")
        if not isinstance(self.w_scales, tuple):
            raise TypeError(f"FinetuneConfig.w_scales must be a tuple, got {type(self.w_scales).__name__}")
        self.patch_loss_config()  # checks occlusion, patch_spacing and w_scales

    def patch_loss_config(self) -> FinetuneLossConfig:
        return FinetuneLossConfig(spacing=self.patch_spacing, w_scales=self.w_scales, backward=self.backward,
                                  smooth_weight=self.smooth_weight, occlusion=self.occlusion)

    def full_loss_config(self) -> FlowLossConfig:
        """ARFlow's ``sintel_ft`` loss with our λ and occlusion choice (range map = ARFlow's warm-up)."""
        return SINTEL_FT.with_changes(w_smooth=self.smooth_weight,
                                      occ_from_back=self.occlusion == "range_map")

    def loss_settings(self) -> dict[str, Any]:
        """What the loss computed, for the metrics file."""
        if self.loss == "full":
            c = self.full_loss_config()
            return {"loss": "full", "function": "f2depth.flow.loss.flow_loss", "setting": "sintel_ft",
                    "w_ternary": c.w_ternary, "w_l1": c.w_l1, "w_ssim": c.w_ssim,
                    "w_scales": list(c.w_scales),
                    "w_sm_scales": list(c.w_sm_scales), "backward": True, "smooth_weight": c.w_smooth,
                    "occlusion": "range_map" if c.occ_from_back else "forward_backward", "amp": self.amp}
        c = self.patch_loss_config()
        return {"loss": "patch", "function": "f2depth.flow.patch_loss.finetune_loss",
                "patch_spacing": c.spacing, "w_scales": list(c.w_scales), "w_sm_scales": [1.0],
                "backward": c.backward, "smooth_weight": c.smooth_weight, "occlusion": c.occlusion,
                "amp": self.amp}


def batch_loss(flows_fw: Sequence[torch.Tensor], flows_bw: Sequence[torch.Tensor], img1: torch.Tensor,
               img2: torch.Tensor, keypoints: torch.Tensor | None, keypoint_mask: torch.Tensor | None,
               cfg: FinetuneConfig) -> tuple[torch.Tensor, dict[str, float]]:
    """L_flow of one batch for ``cfg.loss`` → ``(loss, stats)`` with every :data:`TRAIN_COLUMNS` key.

    ``flows_fw, flows_bw``: the network's levels (PWC-Lite: five), finest first, in pixels of their level;
    ``img1, img2 (B,3,H,W)`` in [0,1]; ``keypoints (B,2,K,2)`` / ``keypoint_mask (B,2,K)`` of frames 1 and 2
    (patch only; ignored by ``full``). For ``full`` (every pixel), ``coverage`` is 1 and ``used_pixels`` is
    frame 1's non-occluded share of the image in pixels.
    """
    if cfg.loss == "full":
        loss, stats = flow_loss(list(flows_fw), list(flows_bw), img1, img2, cfg.full_loss_config())
        h, w = img1.shape[-2:]
        stats.update(used_pixels=stats["noc_fraction"] * h * w, coverage=1.0, pixels=float(h * w))
        return loss, stats
    if keypoints is None or keypoint_mask is None:
        raise ValueError("batch_loss: the patch loss needs keypoints and keypoint_mask")
    return finetune_loss(flows_fw, flows_bw, img1, img2, keypoints, keypoint_mask, cfg.patch_loss_config())


def prepare_batch(batch: dict[str, torch.Tensor], cfg: FinetuneConfig, gen: torch.Generator
                  ) -> dict[str, torch.Tensor]:
    """Augmented batch (``cfg.augment``) with ``net1``, ``net2`` = what the network sees."""
    if cfg.augment:
        return augment_batch(batch, gen)
    return {**batch, "net1": batch["img1"], "net2": batch["img2"]}


def train_step(model: FlowNetwork, optimizer: torch.optim.Optimizer, batch: dict[str, torch.Tensor],
               cfg: FinetuneConfig, device: torch.device | str = "cpu",
               scaler: torch.amp.GradScaler | None = None) -> dict[str, float]:
    """One update on a prepared batch (:func:`prepare_batch`) → its loss terms; raises FloatingPointError
    (no update) when the loss is not finite. The network runs under :func:`autocast` with ``cfg.amp``, the
    loss in float32."""
    img1, img2 = batch["img1"].to(device), batch["img2"].to(device)
    with autocast(device, cfg.amp):
        flows_fw, flows_bw = model(batch["net1"].to(device), batch["net2"].to(device), with_backward=True)
    if cfg.amp:
        flows_fw, flows_bw = [f.float() for f in flows_fw], [f.float() for f in flows_bw]
    with full_precision(device):
        loss, stats = batch_loss(flows_fw, flows_bw, img1, img2, batch.get("keypoints"),
                                 batch.get("keypoint_mask"), cfg)
    optimizer.zero_grad(set_to_none=True)
    if not torch.isfinite(loss):
        raise FloatingPointError(f"loss is {loss.item()}")
    backward_and_step(loss, optimizer, scaler)
    return stats


def finetune(model: FlowNetwork, dataset: FlowPairs, cfg: FinetuneConfig, eval_pairs: Iterable[GTPair] = (),
             resume_path: str | os.PathLike | None = None, fingerprint: Mapping[str, Any] | None = None,
             device: str = "cpu", workers: int = 0,
             on_epoch: Callable[[dict[str, Any]], None] | None = None,
             progress: bool = True) -> dict[str, Any]:
    """Fine-tune ``model`` in place; returns ``{"history", "epochs_run", "resumed_from", "seconds"}``.

    ``eval_pairs`` (kept in memory) are scored after every epoch; ``on_epoch(row)`` gets each epoch's
    history row (1-based ``epoch``) once its state is saved, and first each row a resumed run already has.
    Each epoch's order and augmentation come from :func:`f2depth.epochs.epoch_generator` (seed, epoch).
    ``history`` rows have :data:`HISTORY_COLUMNS` (EPE None without ground truth).
    """
    eval_pairs = list(eval_pairs)
    model.to(device)
    optimizer = make_optimizer(model, cfg)
    scaler = grad_scaler(device, cfg.amp)  # float16 on CUDA only; else a pass-through
    run = f"flow_finetune[{cfg.loss}]"
    loop = EpochLoop(run, cfg.epochs, {"model": model, "optimizer": optimizer, "scaler": scaler}, resume_path,
                     hash_settings({"config": asdict(cfg), "pairs": [p.pair_id for p in dataset.pairs],
                                    **dict(fingerprint or {})}), progress=progress)
    loop.restore()

    def batches(epoch: int):
        gen = epoch_generator(cfg.seed, epoch)
        order = torch.randperm(len(dataset), generator=gen).tolist()
        model.train()
        for batch in torch.utils.data.DataLoader(dataset, batch_size=cfg.batch_size, sampler=order,
                                                 collate_fn=collate, num_workers=workers):
            yield prepare_batch(batch, cfg, gen)

    def step(batch: dict[str, torch.Tensor]) -> dict[str, float]:
        stats = train_step(model, optimizer, batch, cfg, device, scaler)
        return {k: stats[k] for k in TRAIN_COLUMNS}

    def end_epoch(row: dict[str, Any]) -> dict[str, Any]:
        if row["steps"] and row["noc_fraction"] == 0:
            warnings.warn(f"{run} epoch {row['epoch']}: the {cfg.occlusion} check marked every "
                          "pixel occluded, so only the smoothness term trained; the flow is degenerate (e.g. "
                          "constant, forward = backward). Use a better pretrained model or set "
                          "flow_finetune.occlusion: range_map", stacklevel=2)
        epe = evaluate_gt_pairs(model, eval_pairs, device)["model"] if eval_pairs else {}
        return {k: epe.get(k) for k in EPE_COLUMNS}

    t0 = time.perf_counter()
    loop.run_epochs(batches, step, end_epoch=end_epoch, on_epoch=on_epoch)
    model.eval()
    return {"history": loop.history, "epochs_run": max(cfg.epochs - loop.resumed_from, 0),
            "resumed_from": loop.resumed_from, "seconds": round(time.perf_counter() - t0, 1)}
