"""Everything one ``train_depth`` variant needs, resolved from params.yaml into one frozen dataclass.

A variant (params ``variants.<name>``, docs/method.md §1) says what it is: ``flow``, the frozen flow network
that supervises depth (a model file; null for the P²Net baseline, which has no flow losses), and
``without``, the loss terms it switches off (``f2depth.train.step.TERMS``: smooth, planar, rigid, feature; a
variant without a flow network must switch off the flow terms, ``FLOW_TERMS``). Its loss weights are the
top-level ``lambda1``, ``lambda2``, ``lambda_rigid``, ``lambda3`` (``WEIGHT_KEYS``) with those terms at 0 (the
key is not ``off``: YAML 1.1 readers such as PyYAML take ``off`` for false). What DVC tracks for each
variant (the flow model file) is written in dvc.yaml, not here.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from f2depth import params as P
from f2depth.depth import DepthModelConfig
from f2depth.depth.decoder import sigmoid_input_for_depth
from f2depth.train.schedule import LRSchedule
from f2depth.train.step import FLOW_TERMS, TERMS, WEIGHT_KEYS

#: train_depth.pose_prior: none = the paper's PoseCNN; geometric = PoseCNN refines a prior from multi-view
#: geometry (the ``poses`` stage, f2depth.poses), a residual pose as MonoIndoor's (f2depth.depth.model)
POSE_PRIORS = ("none", "geometric")
#: train_depth.teacher: network = the frozen flow network (the paper); exact = its flow replaced by the
#: synthetic world's exact rigid flow, a diagnosis of the synthetic default (f2depth.train.exact_teacher)
TEACHERS = ("network", "exact")
#: train_depth.rigid_mask: none = L_rigid on every pixel (the paper); consistency = where the teacher's flows
#: target → source and back agree (f2depth.train.teacher, docs/method.md)
RIGID_MASKS = ("none", "consistency")
@dataclass(frozen=True)
class Variant:
    """One ``variants.<name>`` entry of params.yaml."""

    flow: str | None  # the frozen flow network (models/flow_*.pt); null: the P²Net baseline
    without: tuple[str, ...]  # loss terms (f2depth.train.step.TERMS) this variant trains with weight 0


@dataclass(frozen=True)
class TrainSettings:
    """The ``train_depth`` section (read by f2depth.params.section, which checks the ranges), then what one
    variant resolves from the rest of params.yaml (given to the loader by :func:`settings_from_params`)."""

    epochs: int = field(metadata={"min": 1})
    batch_size: int = field(metadata={"min": 1})
    lr: tuple[float, ...]
    lr_epochs: tuple[int, ...]
    num_points: int = field(metadata={"min": 1})
    imagenet_weights: str | None  # checked by f2depth.params.pretrained_starts
    amp: bool
    init_depth: Any  # null or metres inside DepthCNN's range (checked below; a float afterwards)
    pose_prior: str  # none (the paper) | geometric (PoseCNN refines f2depth.poses' priors)
    augment: bool
    seeds: tuple[int, ...]
    workers: int = field(metadata={"min": 0})
    seed_threads: int | None = field(metadata={"min": 1})  # CPU: a process per seed (f2depth.processes)
    val_max_images: int | None = field(metadata={"min": 1})
    val_every: int = field(metadata={"min": 1})
    state_every: int = field(metadata={"min": 1})
    diagnostic_tuples: int = field(metadata={"min": 0})
    sync_bn: bool
    teacher_memo_mb: float = field(metadata={"min": 0})  # f2depth.train.teacher: the frozen network's memo
    teacher: str  # network (the paper) | exact (diagnosis: the synthetic world's rigid flow)
    rigid_mask: str  # none (the paper) | consistency: L_rigid where the teacher's two flows agree
    flow_fade_epochs: int | None = field(metadata={"min": 1})  # f2depth.train.schedule.flow_weight_factor
    resume_dir: str
    # ---- resolved for the variant
    variant: str
    flow_model: str | None  # variants.<name>.flow
    weights: dict[str, float]  # term → weight for every term of f2depth.train.step.TERMS, 0 when off
    without: tuple[str, ...]  # variants.<name>.without
    prepared: str  # data.prepared
    keypoints_file: str  # data.keypoints/train.npz
    nyu_labeled: str | None  # data.nyu_labeled, data.nyu_splits: the per-epoch validation (null: none, then
    nyu_splits: str | None  # the held-out tuples of prepare.val_share are the only one)
    val_gt: str  # evaluate.nyu_gt, evaluate.nyu_crop: validated as the evaluation scores
    val_crop: str
    poses: str | None  # data.poses, the pose-prior folder, when pose_prior is geometric
    device: str

    def __post_init__(self) -> None:
        if self.pose_prior not in POSE_PRIORS:
            raise ValueError(f"pose_prior must be one of {', '.join(POSE_PRIORS)}, got {self.pose_prior!r}")
        if self.teacher not in TEACHERS:
            raise ValueError(f"teacher must be one of {', '.join(TEACHERS)}, got {self.teacher!r}")
        if self.rigid_mask not in RIGID_MASKS:
            raise ValueError(f"rigid_mask must be one of {', '.join(RIGID_MASKS)}, got {self.rigid_mask!r}")
        _ = self.schedule  # LRSchedule's rules check lr and lr_epochs (its errors name them)
        if not self.seeds or len(set(self.seeds)) != len(self.seeds):
            raise ValueError(f"seeds must be a non-empty list of distinct integers, got {list(self.seeds)}")
        if self.init_depth is not None:
            lo, hi = DepthModelConfig.min_depth, DepthModelConfig.max_depth
            try:
                if isinstance(self.init_depth, bool):
                    raise TypeError("a bool is not a depth")
                sigmoid_input_for_depth(self.init_depth, lo, hi)
            except (TypeError, ValueError):
                raise ValueError(f"init_depth must be null or a depth in metres strictly between {lo} and "
                                 f"{hi} (DepthCNN's range), got {self.init_depth!r}") from None
            object.__setattr__(self, "init_depth", float(self.init_depth))

    @property
    def schedule(self) -> LRSchedule:
        """The paper's lr schedule (``lr``, ``lr_epochs``) scaled to ``epochs``."""
        return LRSchedule.scaled(self.lr, self.lr_epochs, self.epochs)

    def as_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        for key in ("lr", "lr_epochs", "seeds", "without"):
            d[key] = list(d[key])
        return d


def variant(params: dict[str, Any], name: str) -> Variant:
    """``variants.<name>``, checked: its keys, its ``without`` names (terms of L_depth) and, without a flow
    network, that the flow terms are off. Errors are one line naming the key (did-you-mean for a typo)."""
    path = params.get("_file", P.DEFAULT_PARAMS)
    variants = P.value(params, "variants", dict)
    if name not in variants:
        raise P.ParamsError(f"{path}: unknown variant '{name}'; variants: {sorted(variants)}")
    v = P.section(params, f"variants.{name}", Variant)
    P.reject_unknown(path, f"variants.{name}.without", v.without, TERMS, what="terms")
    on = [t for t in FLOW_TERMS if t not in v.without]
    if v.flow is None and on:
        raise P.ParamsError(f"{path}: variants.{name} has no flow network (flow: null) but leaves "
                            f"{', '.join(on)} on; add {'them' if len(on) > 1 else 'it'} to "
                            f"variants.{name}.without or give it a flow model")
    return v


def loss_weights(params: dict[str, Any], without: Iterable[str] = ()) -> dict[str, float]:
    """The weight of every term of L_depth (``f2depth.train.step.TERMS``, in that order) from params.yaml's
    top-level ``lambda1``, ``lambda2``, ``lambda_rigid``, ``lambda3`` (``WEIGHT_KEYS``), 0 for the terms in
    ``without``. Each must be a number >= 0 (checked also for a term that is off)."""
    weights = {term: P.value(params, WEIGHT_KEYS[term], float, min=0) for term in TERMS}
    off = set(without)
    return {term: 0.0 if term in off else w for term, w in weights.items()}


def _path_or_none(value: Any) -> str | None:
    return None if value is None else str(value)


def settings_from_params(params: dict[str, Any], name: str) -> TrainSettings:
    """Resolve variant ``name`` from a loaded params dict (``f2depth.params.load``); errors name the key."""
    v = variant(params, name)
    geometric = P.get(params, "train_depth.pose_prior", None) == "geometric"
    resolved = {
        "variant": name, "flow_model": v.flow, "weights": loss_weights(params, v.without),
        "without": v.without,
        "prepared": str(P.get(params, "data.prepared")),
        "keypoints_file": str(Path(P.get(params, "data.keypoints")) / "train.npz"),
        "nyu_labeled": _path_or_none(P.get(params, "data.nyu_labeled", None)),
        "nyu_splits": _path_or_none(P.get(params, "data.nyu_splits", None)),
        "val_gt": P.value(params, "evaluate.nyu_gt", str),
        "val_crop": P.value(params, "evaluate.nyu_crop", str),
        "poses": str(P.get(params, "data.poses")) if geometric else None,
        "device": P.value(params, "device", P.Device),
    }  # fmt: skip
    settings = P.section(params, "train_depth", TrainSettings, **resolved)
    if settings.teacher == "exact" and not (P.value(params, "allow_random_init", bool)
                                            and P.get(params, "data_source", None) == "synthetic"):
        raise P.ParamsError(f"{params.get('_file', P.DEFAULT_PARAMS)}: train_depth.teacher: exact needs the "
                            "synthetic default's ground truth (data_source: synthetic, allow_random_init: "
                            "true); it is a diagnosis, not the paper's method: set it to network")
    # Before any work: the paper's pretrained starts (allow_random_init: false) must exist.
    starts = P.pretrained_starts(params, ("train_depth.imagenet_weights",)
                                 + (("flow_pretrain.checkpoint",) if v.flow is not None else ()))
    return dataclasses.replace(settings, imagenet_weights=starts["train_depth.imagenet_weights"])
