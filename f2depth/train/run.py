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

from f2depth import processes, tracking
from f2depth.depth import DepthModel, DepthModelConfig, save_checkpoint
from f2depth.epochs import fingerprints
from f2depth.errors import DataError
from f2depth.formats.prepared import VAL_TUPLES, PreparedSet
from f2depth.poses.store import PosePriors
from f2depth.superpixels import scaled_min_area
from f2depth.train.data import DataConfig, TupleDataset, batch_problem
from f2depth.train.diagnostics import (
    DIAGNOSTIC_KEYS,
    TrainTruth,
    constant_depth_metrics,
    diagnose,
    teacher_epe,
)
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


@dataclass
class _Parts:
    """What every seed of a variant shares: the data, the frozen teacher and the measurements."""

    prepared: PreparedSet
    dataset: TupleDataset
    teacher: FlowTeacher | ExactTeacher | None
    validator: Any
    heldout: HeldOutValidator | None
    truth: TrainTruth | None
    floor: dict[str, float]
    heldout_floors: dict[str, Any] | None
    step_config: StepConfig
    priors: PosePriors | None
    train_flow_epe: dict[str, float] | None  # diagnostics.teacher_epe on the training tuples

    def floors(self) -> dict[str, Any]:
        """The metrics file's floors: a constant depth on the validation images, the held-out tuples', and
        the teacher's and zero flow's EPE on the training tuples with ground truth."""
        constant = {"abs_rel": self.floor.get("val_abs_rel"), "a1": self.floor.get("val_a1")}
        return {"val_constant_depth": constant,
                **({"heldout": {"tuples": len(self.heldout), **self.heldout_floors}}
                   if self.heldout is not None else {}),
                **({"train_flow_epe": self.train_flow_epe} if self.train_flow_epe is not None else {})}

    def close(self) -> None:
        if self.validator is not None:
            self.validator.close()


def _parts(s: TrainSettings, ctx: DistContext, measures: bool = True) -> _Parts:
    """Read the prepared set, load the teacher and build the validators of ``s`` (errors name the file);
    ``measures`` False: the data and the checks only (a stage whose seeds train in processes)."""
    if s.flow_model and not Path(s.flow_model).is_file():
        raise DataError(s.flow_model, f"flow model not found (variants.{s.variant}.flow)",
                        f"`dvc repro train_depth@{s.variant}` builds it first, or set variants.{s.variant}"
                        ".flow to an existing flow model (models/flow_*.pt)")
    prepared = PreparedSet(s.prepared)
    h, w = prepared.hw
    priors = PosePriors(s.poses) if s.pose_prior == "geometric" else None
    dataset = TupleDataset(prepared, s.keypoints_file, DataConfig(num_points=s.num_points, augment=s.augment),
                           priors=priors)
    if problem := batch_problem(len(dataset), s.batch_size, ctx.world_size):  # before any model is built
        raise DataError(Path(s.prepared) / "tuples.csv", *problem)
    masked = s.rigid_mask == "consistency"  # of the network's flow: the exact flow needs no mask
    teacher = (None if not s.flow_model or not measures
               else ExactTeacher.from_prepared(s.flow_model, prepared, ctx.device, s.teacher_memo_mb)
               if s.teacher == "exact"
               else FlowTeacher.load(s.flow_model, ctx.device, s.teacher_memo_mb, masked))
    if not s.nyu_labeled and not prepared.val_tuples:
        raise DataError(Path(s.prepared) / VAL_TUPLES, "no validation set: data.nyu_labeled is null and the "
                        "prepared set holds no held-out tuples", "set prepare.val_share (e.g. 0.2) and re-run"
                        " prepare, or point data.nyu_labeled (and data.nyu_splits) at NYU's labeled set")
    here = ctx.is_main and measures
    validator = make_validator(s.nyu_labeled, s.nyu_splits, h, w, ctx.device, gt=s.val_gt, crop=s.val_crop,
                               max_images=s.val_max_images) if here and s.nyu_labeled else None
    heldout = (HeldOutValidator(prepared, dataset.keypoints, s.num_points, priors, ctx.device,
                                max_tuples=s.val_max_images) if here and prepared.val_tuples else None)
    truth = (TrainTruth.from_prepared(prepared, s.diagnostic_tuples, priors)
             if here and s.diagnostic_tuples > 0 else None)
    return _Parts(prepared, dataset, teacher, validator, heldout, truth,
                  constant_depth_metrics(validator) if validator is not None else {},
                  heldout.floors() if heldout is not None else None,
                  StepConfig(weights=s.weights, min_area=scaled_min_area(h, w), amp=s.amp), priors,
                  teacher_epe(teacher, truth, ctx.device) if truth and teacher else None)


def _train_seed(s: TrainSettings, parts: _Parts, seed: int, build_dir: Path, ctx: DistContext,
                on_epoch: Callable[[dict[str, Any]], None], resume: bool, fingerprint: str,
                progress: bool) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """Train one seed from scratch (or its resume state), write ``seed<k>.pt`` on rank 0 → (its summary,
    its history rows)."""
    state_file = Path(s.resume_dir) / s.variant / f"seed{seed}.pt"
    parts.dataset.seed = seed
    seed_everything(seed)
    h, w = parts.prepared.hw
    model = DepthModel(DepthModelConfig(height=h, width=w))
    if s.imagenet_weights:
        model.load_imagenet(s.imagenet_weights)
    if s.init_depth is not None:
        model.set_initial_depth(s.init_depth)
    result = fit(
        model, parts.dataset, parts.teacher, parts.step_config,
        loop_config(s, seed, progress),
        ctx=ctx, checkpoint=state_file, resume=resume, fingerprint=fingerprint,
        validate=_measure(parts.validator, parts.heldout, parts.truth, ctx.device), on_epoch=on_epoch,
    )  # fmt: skip
    if ctx.is_main:
        if result.resumed_from:
            log.info("seed %d: resumed after epoch %d (%s)", seed, result.resumed_from, state_file)
        save_checkpoint(build_dir / f"seed{seed}.pt", model, params=s.as_dict(), variant=s.variant, seed=seed,
                        history=result.history, weight_keys=dict(WEIGHT_KEYS))  # each term's params key
    return {"seed": seed, **_summary(result)}, result.history


def loop_config(s: TrainSettings, seed: int, progress: bool) -> LoopConfig:
    """The training loop's settings of one seed of ``s``."""
    return LoopConfig(s.epochs, s.batch_size, s.schedule, workers=s.workers, sync_bn=s.sync_bn,
                      val_every=s.val_every, state_every=s.state_every, flow_fade_epochs=s.flow_fade_epochs,
                      seed=seed, progress=progress)


def _count_epoch(row: dict[str, Any]) -> None:
    """A seed process's ``on_epoch``: a trained epoch moves the stage's bar (row 0: the untrained network)."""
    if row["epoch"] > 0:
        processes.epoch_done()


def _seed_job(s: TrainSettings, seed: int, build_dir: Path, resume: bool, fingerprint: str
              ) -> tuple[dict[str, Any], list[dict[str, Any]], dict[str, Any]]:
    """One seed in a :mod:`f2depth.processes` process: its own data, teacher and validators → (its
    summary, its history, the floors)."""
    logging.basicConfig(level=logging.WARNING, format="%(message)s")
    parts = _parts(s, DistContext())  # in_processes: a CPU run
    try:
        return (*_train_seed(s, parts, seed, build_dir, DistContext(), _count_epoch, resume, fingerprint,
                             progress=False), parts.floors())
    finally:
        parts.close()


def in_processes(s: TrainSettings, ctx: DistContext) -> bool:
    """Whether the seeds train in :mod:`f2depth.processes` processes: on a CPU without torchrun, when
    ``train_depth.seed_threads`` fixes their thread count."""
    return s.seed_threads is not None and ctx.device.type == "cpu" and not ctx.distributed


def train_variant(
    s: TrainSettings,
    build_dir: str | Path,
    ctx: DistContext | None = None,
    open_run: RunOpener = no_tracking,
    resume: bool = True,
    progress: bool = True,
) -> VariantRun:
    """Train every seed of ``s``, write the models into ``build_dir`` on rank 0 (module docstring) and
    return the metrics and the first seed's history; ``open_run(seed)`` is entered around each seed (after
    it, replaying its epochs, when the seeds train in processes: :func:`in_processes`)."""
    ctx = ctx or DistContext()
    t0 = time.perf_counter()
    pooled = in_processes(s, ctx)
    parts = _parts(s, ctx, measures=not pooled)  # in processes: each builds its own
    build_dir = Path(build_dir)
    if ctx.is_main:
        log.info("train_depth[%s]: %d tuples at %dx%d, batch %d, %d epochs (lr phases %s), flow model %s, "
                 "loss weights %s, %s%s", s.variant, len(parts.dataset), *parts.prepared.hw, s.batch_size,
                 s.epochs, list(s.schedule.phases), s.flow_model or "none (P²Net baseline)", s.weights,
                 (f"ImageNet init from {s.imagenet_weights}" if s.imagenet_weights
                  else "random init (no ImageNet weights: allow_random_init)")
                 + (f", initial depth {s.init_depth} m" if s.init_depth is not None else "")
                 + (f", PoseCNN refines the geometric pose priors of {s.poses} "
                    f"({parts.priors.reliable_share:.0%} of the pairs have one)" if parts.priors else ""),
                 f"; seeds {list(s.seeds)} side by side, {s.seed_threads} thread(s) each"
                 if pooled else "")
    run_fps = run_fingerprints(s)
    trained: list[tuple[dict[str, Any], list[dict[str, Any]]]] = []
    floors = parts.floors()
    if pooled:
        jobs = [(s, seed, build_dir, resume, run_fps[seed]) for seed in s.seeds]
        done = processes.run_jobs(_seed_job, jobs, s.seed_threads, s.epochs * len(s.seeds),
                                  f"train_depth[{s.variant}] {len(s.seeds)} seed(s)", progress)
        trained, floors = [(summary, history) for summary, history, _ in done], done[0][2]
        for seed, (summary, history) in zip(s.seeds, trained):
            with open_run(seed) as run:  # the seed's MLflow run, its epochs replayed
                run.set_tags({"seed": seed})
                for row in history:
                    run.log_epoch(row)
                run.log_summary(summary)
    else:
        for seed in s.seeds:
            with open_run(seed) if ctx.is_main else no_tracking(seed) as run:
                run.set_tags({"seed": seed})
                summary, history = _train_seed(s, parts, seed, build_dir, ctx, run.log_epoch, resume,
                                               run_fps[seed], progress)
                if ctx.is_main:
                    run.log_summary(summary)  # this seed's entry of the metrics file's per_seed
            trained.append((summary, history))
            barrier(ctx)
    per_seed = [summary for summary, _ in trained]
    if ctx.is_main:  # model.pt: a hard link where possible, no second copy
        try:
            os.link(build_dir / f"seed{s.seeds[0]}.pt", build_dir / "model.pt")
        except OSError:
            shutil.copyfile(build_dir / f"seed{s.seeds[0]}.pt", build_dir / "model.pt")
    metrics = {
        "variant": s.variant, "flow_model": s.flow_model, "teacher": s.teacher, "weights": dict(s.weights),
        "without": list(s.without), "epochs": s.epochs, "batch_size": s.batch_size,
        "lr_phases": list(s.schedule.phases), "train_tuples": len(parts.dataset),
        "steps_per_epoch": len(parts.dataset) // s.batch_size, "seeds": list(s.seeds),
        "main_seed": s.seeds[0],
        "seed_threads": s.seed_threads if pooled else None,
        "resnet_init": s.imagenet_weights or "random", "init_depth": s.init_depth, "amp": s.amp,
        **{k: v for k, v in per_seed[0].items() if k != "seed"},
        **floors,
        "per_seed": per_seed, "wall_seconds": round(time.perf_counter() - t0, 2),
    }  # fmt: skip
    parts.close()
    barrier(ctx)
    return VariantRun(metrics, trained[0][1])


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
