"""Train one variant over its seeds: build data, flow teacher, validator and model, call ``loop.fit``, write
each seed's model into the folder the stage gives, and return the metrics and the first seed's history.

The stage script (``stages/train_depth.py``) owns the outputs and the tracking: it opens
``models/depth_<variant>`` as a temporary sibling that replaces the old folder only when complete, gives
:func:`train_variant` an opener of one MLflow run per seed, writes the metrics and the history and then
removes the resume states. Into ``build_dir`` (rank 0 only) go ``seed<k>.pt`` per seed (``f2depth.depth``
checkpoints) and ``model.pt``, the **first listed seed's** model (a hard link, or a copy) — the model the
``evaluate`` stage uses for single-model results, unchanged when seeds are appended to the list. Resume
states live in ``<resume_dir>/<variant>/seed<k>.pt`` (:func:`resume_states`), so a run killed during a later
seed does not retrain the earlier ones.
"""

from __future__ import annotations

import contextlib
import logging
import os
import shutil
import time
from collections.abc import Callable
from contextlib import AbstractContextManager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from f2depth import tracking
from f2depth.data.errors import DataError
from f2depth.data.prepared import VAL_TUPLES, PreparedSet
from f2depth.depth import DepthModel, DepthModelConfig, save_checkpoint
from f2depth.epochs import fingerprints
from f2depth.poses.store import PosePriors
from f2depth.superpixels import scaled_min_area
from f2depth.train.data import DataConfig, TupleDataset, batch_problem
from f2depth.train.diagnostics import DIAGNOSTIC_KEYS, TrainTruth, constant_depth_metrics, diagnose
from f2depth.train.distributed import DistContext, barrier
from f2depth.train.exact_teacher import ExactTeacher
from f2depth.train.heldout import HELDOUT_KEYS, HeldOutValidator
from f2depth.train.loop import FitResult, LoopConfig, fit, seed_everything
from f2depth.train.settings import TrainSettings
from f2depth.train.step import WEIGHT_KEYS, StepConfig
from f2depth.train.teacher import FlowTeacher
from f2depth.train.validate import make_validator

log = logging.getLogger(__name__)


def run_fingerprints(s: TrainSettings) -> dict[int, str]:
    """Seed → what its resumable state must match: the settings that shape training and the contents of
    the input files (the whole prepared set: its images and superpixels too, not only its tables), which
    are read once for all seeds."""
    ignored = ("seeds", "workers", "resume_dir", "device", "diagnostic_tuples", "val_every",
               "state_every")
    settings = {k: v for k, v in s.as_dict().items() if k not in ignored}
    files = {"prepared": s.prepared,  # the folder's contents: images, superpixels, tables, camera
             "keypoints": s.keypoints_file, "flow_model": s.flow_model, "imagenet": s.imagenet_weights,
             "pose_priors": Path(s.poses) / "priors.json" if s.poses else None}
    return fingerprints({seed: {**settings, "seed": seed} for seed in s.seeds}, files)


def _summary(result: FitResult) -> dict[str, Any]:
    hist = result.history
    first = next((r for r in hist if r["epoch"] == 0), {})
    last = hist[-1] if hist else {}
    other = ("epoch", "lr", "seconds", "val_seconds", "steps", "skipped_steps", *DIAGNOSTIC_KEYS,
             *HELDOUT_KEYS)
    losses = {k: v for k, v in last.items() if k not in other and not k.startswith("val_")}
    heldout = {f"heldout_{name}": {k.removeprefix("heldout_"): row.get(k) for k in HELDOUT_KEYS if k in row}
               for name, row in (("untrained", first), ("trained", last)) if "heldout_ph" in row}
    return {
        "val_untrained": {"abs_rel": first.get("val_abs_rel"), "a1": first.get("val_a1")},
        "val_trained": {"abs_rel": last.get("val_abs_rel"), "a1": last.get("val_a1")},
        "train_untrained": {k: first.get(k) for k in DIAGNOSTIC_KEYS if k in first},
        "train_trained": {k: last.get(k) for k in DIAGNOSTIC_KEYS if k in last},
        **heldout,
        "final_losses": losses,
        "seconds": round(sum(r.get("seconds", 0.0) + r.get("val_seconds", 0.0) for r in hist), 2),
        "seconds_per_epoch": round(sum(r.get("seconds", 0.0) for r in hist if r["epoch"] > 0)
                                   / max(1, sum(1 for r in hist if r["epoch"] > 0)), 3),
        "resumed_from_epoch": result.resumed_from,
    }


#: seed → a context manager yielding the MLflow run of that seed (f2depth.tracking.stage_run)
RunOpener = Callable[[int], AbstractContextManager[tracking.StageRun]]


def no_tracking(seed: int) -> AbstractContextManager[tracking.StageRun]:
    return contextlib.nullcontext(tracking.StageRun())


def run_params(s: TrainSettings, seeds: list[int]) -> dict[str, Any]:
    """What the MLflow runs of ``seeds`` of this variant log that they trained with: the variant's loss
    weights under their params.yaml names (``WEIGHT_KEYS``), its flow model, ... (f2depth.tracking)."""
    weights = {WEIGHT_KEYS[term]: w for term, w in s.weights.items()}
    return tracking.trained_params(s.variant, weights, s.flow_model, s.epochs, seeds, s.without)


@dataclass(frozen=True)
class VariantRun:
    """What :func:`train_variant` returns: the metrics document and the first seed's per-epoch rows."""

    metrics: dict[str, Any]
    history: list[dict[str, Any]]


def resume_states(s: TrainSettings) -> list[Path]:
    """The resume-state file of every seed of the variant (removed by the stage once every output is
    written)."""
    return [Path(s.resume_dir) / s.variant / f"seed{seed}.pt" for seed in s.seeds]


def train_variant(
    s: TrainSettings,
    build_dir: str | Path,
    ctx: DistContext | None = None,
    open_run: RunOpener = no_tracking,
    resume: bool = True,
    progress: bool = True,
) -> VariantRun:
    """Train every seed of ``s``, write the models into ``build_dir`` on rank 0 (module docstring) and
    return the metrics and the first seed's history; ``open_run(seed)`` is entered around each seed."""
    ctx = ctx or DistContext()
    if s.flow_model and not Path(s.flow_model).is_file():
        raise DataError(s.flow_model, f"flow model not found (variants.{s.variant}.flow)",
                        f"`dvc repro train_depth@{s.variant}` builds it first, or set variants.{s.variant}"
                        ".flow to an existing flow model (models/flow_*.pt)")
    t0 = time.perf_counter()
    prepared = PreparedSet(s.prepared)
    h, w = prepared.hw
    priors = PosePriors(s.poses) if s.pose_prior == "geometric" else None
    dataset = TupleDataset(prepared, s.keypoints_file, DataConfig(num_points=s.num_points, augment=s.augment),
                           priors=priors)
    if problem := batch_problem(len(dataset), s.batch_size, ctx.world_size):  # before any model is built
        raise DataError(Path(s.prepared) / "tuples.csv", *problem)
    teacher = (None if not s.flow_model
               else ExactTeacher.from_prepared(s.flow_model, prepared, ctx.device, s.teacher_memo_mb)
               if s.teacher == "exact" else FlowTeacher.load(s.flow_model, ctx.device, s.teacher_memo_mb))
    if not s.nyu_labeled and not prepared.val_tuples:
        raise DataError(Path(s.prepared) / VAL_TUPLES, "no validation set: data.nyu_labeled is null and the "
                        "prepared set holds no held-out tuples", "set prepare.val_share (e.g. 0.2) and re-run"
                        " prepare, or point data.nyu_labeled (and data.nyu_splits) at NYU's labeled set")
    validator = make_validator(s.nyu_labeled, s.nyu_splits, h, w, ctx.device, gt=s.val_gt, crop=s.val_crop,
                               max_images=s.val_max_images) if ctx.is_main and s.nyu_labeled else None
    heldout = (HeldOutValidator(prepared, dataset.keypoints, s.num_points, priors, ctx.device,
                                max_tuples=s.val_max_images) if ctx.is_main and prepared.val_tuples else None)
    truth = (TrainTruth.from_prepared(prepared, s.diagnostic_tuples, priors)
             if ctx.is_main and s.diagnostic_tuples > 0 else None)
    floor = constant_depth_metrics(validator) if validator is not None else {}
    heldout_floors = heldout.floors() if heldout is not None else None
    step_config = StepConfig(weights=s.weights, min_area=scaled_min_area(h, w), amp=s.amp)
    schedule = s.schedule
    build_dir = Path(build_dir)
    if ctx.is_main:
        log.info("train_depth[%s]: %d tuples at %dx%d, batch %d, %d epochs (lr phases %s), flow model %s, "
                 "loss weights %s, %s", s.variant, len(dataset), h, w, s.batch_size, s.epochs,
                 list(schedule.phases), s.flow_model or "none (P²Net baseline)", s.weights,
                 (f"ImageNet init from {s.imagenet_weights}" if s.imagenet_weights
                  else "random init (no ImageNet weights: allow_random_init)")
                 + (f", initial depth {s.init_depth} m" if s.init_depth is not None else "")
                 + (f", PoseCNN refines the geometric pose priors of {s.poses} ({priors.reliable_share:.0%} "
                    "of the pairs have one)" if priors is not None else ""))
    per_seed: list[dict[str, Any]] = []
    main_history: list[dict[str, Any]] = []
    run_fps = run_fingerprints(s)
    for seed, state_file in zip(s.seeds, resume_states(s)):
        dataset.seed = seed
        seed_everything(seed)
        model = DepthModel(DepthModelConfig(height=h, width=w))
        if s.imagenet_weights:
            model.load_imagenet(s.imagenet_weights)
        if s.init_depth is not None:
            model.set_initial_depth(s.init_depth)
        with open_run(seed) if ctx.is_main else no_tracking(seed) as run:
            run.set_tags({"seed": seed})
            result = fit(
                model, dataset, teacher, step_config,
                LoopConfig(s.epochs, s.batch_size, schedule, seed=seed, workers=s.workers,
                           sync_bn=s.sync_bn, progress=progress, val_every=s.val_every,
                           state_every=s.state_every),
                ctx=ctx, checkpoint=state_file, resume=resume, fingerprint=run_fps[seed],
                validate=_measure(validator, heldout, truth, ctx.device),
                on_epoch=run.log_epoch,
            )  # fmt: skip
            summary = {"seed": seed, **_summary(result)}
            if ctx.is_main:
                if result.resumed_from:
                    log.info("seed %d: resumed after epoch %d (%s)", seed, result.resumed_from, state_file)
                save_checkpoint(build_dir / f"seed{seed}.pt", model, params=s.as_dict(),
                                variant=s.variant, seed=seed, history=result.history,
                                weight_keys=dict(WEIGHT_KEYS))  # the params key of each term's weight
                run.log_summary(summary)  # this seed's entry of the metrics file's per_seed
        per_seed.append(summary)
        if seed == s.seeds[0]:
            main_history = result.history
        barrier(ctx)
    if ctx.is_main:  # model.pt: a hard link where possible, no second copy
        try:
            os.link(build_dir / f"seed{s.seeds[0]}.pt", build_dir / "model.pt")
        except OSError:
            shutil.copyfile(build_dir / f"seed{s.seeds[0]}.pt", build_dir / "model.pt")
    metrics = {
        "variant": s.variant, "flow_model": s.flow_model, "teacher": s.teacher, "weights": dict(s.weights),
        "without": list(s.without), "epochs": s.epochs, "batch_size": s.batch_size,
        "lr_phases": list(schedule.phases), "train_tuples": len(dataset),
        "steps_per_epoch": len(dataset) // s.batch_size, "seeds": list(s.seeds), "main_seed": s.seeds[0],
        "resnet_init": s.imagenet_weights or "random", "init_depth": s.init_depth, "amp": s.amp,
        **{k: v for k, v in per_seed[0].items() if k != "seed"},
        "val_constant_depth": {"abs_rel": floor.get("val_abs_rel"), "a1": floor.get("val_a1")},
        **({"heldout": {"tuples": len(heldout), **heldout_floors}} if heldout is not None else {}),
        "per_seed": per_seed, "wall_seconds": round(time.perf_counter() - t0, 2),
    }  # fmt: skip
    if validator is not None:
        validator.close()
    barrier(ctx)
    return VariantRun(metrics, main_history)


def _measure(validator, heldout: HeldOutValidator | None, truth: TrainTruth | None, device):
    """The per-epoch measurement ``fit`` calls on rank 0: the NYU-format validation, the held-out tuples and,
    with ground truth, the diagnostics on the training tuples (whichever there are)."""
    if validator is None and heldout is None and truth is None:
        return None

    def measure(model: DepthModel) -> dict[str, float]:
        out = validator(model) if validator is not None else {}
        if heldout is not None:
            out.update(heldout(model))
        if truth is not None:
            out.update(diagnose(model, truth, device))
        return out

    return measure
