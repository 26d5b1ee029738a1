"""Everything one ``train_depth`` variant needs, resolved from params.yaml into a frozen dataclass.

Variants (params ``variants.<name>``, docs/method.md §1): ``flow_model`` (path of the frozen flow network,
or null for the P²Net baseline without flow losses), ``rigid_from`` / ``feature_from`` (the YAML file that
``lambda_rigid`` / ``lambda3`` are read from: ``params.yaml`` for the user's value, or
``configs/ablation_off.yaml`` (both 0) to switch the term off), and ``dep_flow_model`` / ``dep_flow_code``
(what DVC tracks for the variant, see dvc.yaml). The name ``params.yaml`` in ``*_from`` means the
parameter file in use (``--params``), so a copied parameter file behaves like the original.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from f2depth import params as P
from f2depth.depth import DepthModelConfig
from f2depth.depth.decoder import sigmoid_input_for_depth
from f2depth.losses import LossWeights

PARAMS_NAME = "params.yaml"
#: train_depth.pose_prior: none = the paper's PoseCNN; geometric = PoseCNN refines a prior from multi-view
#: geometry (the ``poses`` stage, f2depth.poses), a residual pose as MonoIndoor's (f2depth.depth.model)
POSE_PRIORS = ("none", "geometric")


@dataclass(frozen=True)
class TrainSettings:
    variant: str
    prepared: str
    keypoints_file: str
    nyu_labeled: str
    nyu_splits: str
    flow_model: str | None
    weights: LossWeights
    lambda_sources: dict[str, str]
    epochs: int
    batch_size: int
    lr: tuple[float, ...]
    lr_epochs: tuple[int, ...]
    num_points: int
    augment: bool
    seeds: tuple[int, ...]
    workers: int = 0
    imagenet_weights: str | None = None
    init_depth: float | None = None
    val_gt: str = "depths"
    val_crop: str = "eigen"
    val_max_images: int | None = 20
    sync_bn: bool = True
    amp: bool = False
    pose_prior: str = "none"  # none (the paper) | geometric (PoseCNN refines f2depth.poses' priors)
    poses: str | None = None  # data.poses: the pose-prior folder, read when pose_prior is geometric
    device: str = "auto"
    checkpoint_dir: str = "tmp/train_depth"
    diagnostic_tuples: int = 64

    def as_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d["lr"], d["lr_epochs"], d["seeds"] = list(self.lr), list(self.lr_epochs), list(self.seeds)
        return d


@dataclass(frozen=True)
class TrainDepthParams:
    """The ``train_depth`` section (read by f2depth.params.section, which checks the ranges)."""

    epochs: int = field(metadata={"min": 1})
    batch_size: int = field(metadata={"min": 1})
    lr: tuple[float, ...]
    lr_epochs: tuple[int, ...]
    num_points: int = field(metadata={"min": 1})
    imagenet_weights: str | None
    amp: bool
    init_depth: Any  # null or metres inside DepthCNN's range (checked below)
    pose_prior: str
    augment: bool
    seeds: tuple[int, ...]
    workers: int = field(metadata={"min": 0})
    val_max_images: int | None = field(metadata={"min": 1})
    diagnostic_tuples: int = field(metadata={"min": 0})
    sync_bn: bool
    checkpoint_dir: str

    def __post_init__(self) -> None:
        if self.pose_prior not in POSE_PRIORS:
            raise ValueError(f"pose_prior must be one of {', '.join(POSE_PRIORS)}, got {self.pose_prior!r}")
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


def _lambda_from(params: dict[str, Any], params_path: str, source: str, key: str, variant: str) -> float:
    if not isinstance(source, str) or not source:
        raise P.ParamsError(f"{params_path}: variants.{variant}: give the file {key} is read from "
                            f"(params.yaml or configs/ablation_off.yaml)")
    if Path(source).name == PARAMS_NAME and Path(source).parent == Path("."):
        return P.value(params, key, float, min=0)
    path = Path(source)
    if not path.is_file():
        raise P.ParamsError(f"{params_path}: variants.{variant} reads {key} from {path}, "
                            "which does not exist")
    data = yaml.safe_load(path.read_text()) or {}
    if not isinstance(data, dict) or key not in data:
        raise P.ParamsError(f"{path}: no '{key}' (variants.{variant} reads it from this file)")
    return P.value({**data, "_file": str(path)}, key, float, min=0)


def settings_from_params(params: dict[str, Any], variant: str) -> TrainSettings:
    """Resolve ``variant`` from a loaded params dict (``f2depth.params.load``); errors name the key."""
    path = params.get("_file", PARAMS_NAME)
    variants = P.get(params, "variants")
    if variant not in variants:
        raise P.ParamsError(f"{path}: unknown variant '{variant}'; variants: {sorted(variants)}")
    v = variants[variant] or {}
    flow_model = v.get("flow_model")
    dep = v.get("dep_flow_model")
    if flow_model is not None and dep != flow_model:
        raise P.ParamsError(f"{path}: variants.{variant}.dep_flow_model is {dep!r} but flow_model is "
                            f"{flow_model!r}; they must name the same file so DVC tracks the model used")
    rigid_from, feature_from = v.get("rigid_from"), v.get("feature_from")
    weights = LossWeights(
        lambda1=P.value(params, "lambda1", float, min=0),
        lambda2=P.value(params, "lambda2", float, min=0),
        lambda3=_lambda_from(params, path, feature_from, "lambda3", variant),
        lambda_rigid=_lambda_from(params, path, rigid_from, "lambda_rigid", variant),
    )
    if flow_model is None and (weights.lambda3 != 0 or weights.lambda_rigid != 0):
        raise P.ParamsError(f"{path}: variants.{variant} has no flow_model but lambda_rigid="
                            f"{weights.lambda_rigid}, lambda3={weights.lambda3}; read both from "
                            "configs/ablation_off.yaml or give a flow model")
    td = P.section(params, "train_depth", TrainDepthParams)
    # Before any work: the paper's pretrained starts (allow_random_init: false) must exist.
    starts = P.pretrained_starts(params, ("train_depth.imagenet_weights",)
                                 + (("flow_pretrain.checkpoint",) if flow_model is not None else ()))
    return TrainSettings(
        variant=variant,
        prepared=str(P.get(params, "data.prepared")),
        keypoints_file=str(Path(P.get(params, "data.keypoints")) / "train.npz"),
        nyu_labeled=str(P.get(params, "data.nyu_labeled")),
        nyu_splits=str(P.get(params, "data.nyu_splits")),
        flow_model=str(flow_model) if flow_model is not None else None,
        weights=weights,
        lambda_sources={"lambda_rigid": str(rigid_from), "lambda3": str(feature_from)},
        epochs=td.epochs, batch_size=td.batch_size, lr=td.lr, lr_epochs=td.lr_epochs,
        num_points=td.num_points, augment=td.augment, seeds=td.seeds, workers=td.workers,
        imagenet_weights=starts["train_depth.imagenet_weights"],
        init_depth=None if td.init_depth is None else float(td.init_depth),
        val_gt=P.value(params, "evaluate.nyu_gt", str), val_crop=P.value(params, "evaluate.nyu_crop", str),
        val_max_images=td.val_max_images, sync_bn=td.sync_bn, amp=td.amp, pose_prior=td.pose_prior,
        poses=str(P.get(params, "data.poses")) if td.pose_prior == "geometric" else None,
        device=P.value(params, "device", P.Device), checkpoint_dir=td.checkpoint_dir,
        diagnostic_tuples=td.diagnostic_tuples,
    )
