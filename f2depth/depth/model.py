"""DepthModel: DepthCNN (ResNet encoder + depth decoder) and PoseCNN (6-channel ResNet + pose decoder).

Pose convention (Monodepth2's `layers.py`; P²Net's `trainer_geo.py`): the pose network sees two frames in
temporal order ``[a, b]`` and ``predict_pose(img_a, img_b)`` returns ``b_T_a`` = T(t)·R(aa), the transform
mapping camera-a points into camera b. With target 0 and sources ±1 the source-from-target transforms
used for warping are ``1_T_0 = predict_pose(I0, I1)`` and ``-1_T_0 = predict_pose(I-1, I0, invert=True)``.

Pose prior (``train_depth.pose_prior: geometric``, not in the paper): given a prior ``b_T_a`` of the pair
(from multi-view geometry, ``f2depth.poses``), the pose is ``b_T_a = ΔT · prior`` with a residual
``ΔT = T(t)·R(aa)`` — MonoIndoor's residual pose, composed on the left, i.e. expressed in camera b, the
frame the prior maps into. The residual is PoseCNN's *second* output: Monodepth2's pose decoder predicts
two sets of six numbers (``num_frames_to_predict_for = 2``) of which P²Net uses only the first. So one
network serves both kinds of sample without a conflict: a pair with a prior gets ``ΔT·prior`` from the
second output, a pair without one gets the first output's pose alone (the paper's PoseCNN). The ×0.01
output scaling (Monodepth2's, P²Net's) keeps an untrained residual near the identity (a residual started
exactly at the identity learned no better on the CPU default: docs/depth_training.md).
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from torch import nn

from f2depth.depth.decoder import UPSAMPLE_MODES, DepthDecoder, disp_to_depth, sigmoid_input_for_depth
from f2depth.depth.encoder import ResnetEncoder
from f2depth.depth.pose import PoseDecoder
from f2depth.depth.resnet import BLOCKS, load_imagenet_resnet
from f2depth.errors import CheckpointError
from f2depth.geometry import MAX_DEPTH, MIN_DEPTH, invert_pose, pose_from_params
from f2depth.io import damaged_weights, load_weights, torch_save, weights_digest

CHECKPOINT_FORMAT = "f2depth.depth"
CHECKPOINT_VERSION = 1


@dataclass(frozen=True)
class DepthModelConfig:
    """Architecture of a DepthModel. height/width: training input size (multiples of 32)."""

    height: int
    width: int
    min_depth: float = MIN_DEPTH
    max_depth: float = MAX_DEPTH
    num_layers: int = 18
    upsample_mode: str = "nearest"

    def __post_init__(self) -> None:
        if self.height <= 0 or self.width <= 0 or self.height % 32 or self.width % 32:
            raise ValueError(f"height={self.height}, width={self.width}: both must be positive "
                             "multiples of 32")
        if not 0 < self.min_depth < self.max_depth:
            raise ValueError(f"need 0 < min_depth < max_depth, got {self.min_depth}, {self.max_depth}")
        if self.num_layers not in BLOCKS:
            raise ValueError(f"num_layers={self.num_layers}: use one of {sorted(BLOCKS)}")
        if self.upsample_mode not in UPSAMPLE_MODES:
            raise ValueError(f"upsample_mode={self.upsample_mode!r}: use one of {UPSAMPLE_MODES}")

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any], source: str = "config") -> DepthModelConfig:
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(d) - names)
        if unknown:
            raise ValueError(f"{source}: unknown DepthModelConfig keys {unknown}; known: {sorted(names)}")
        try:
            return cls(**d)
        except TypeError as exc:
            raise ValueError(f"{source}: incomplete DepthModelConfig ({exc})") from exc


class DepthModel(nn.Module):
    """DepthCNN + PoseCNN as four named submodules: depth_encoder, depth_decoder, pose_encoder, pose_decoder.

    All inputs are RGB in [0, 1] (normalised inside the encoders). Sizes are free as long as H and W are
    multiples of 32; ``config.height/width`` record the training size.
    """

    def __init__(self, config: DepthModelConfig) -> None:
        super().__init__()
        self.config = config
        self.depth_encoder = ResnetEncoder(config.num_layers, num_input_images=1)
        self.depth_decoder = DepthDecoder(self.depth_encoder.num_ch_enc, upsample_mode=config.upsample_mode)
        self.pose_encoder = ResnetEncoder(config.num_layers, num_input_images=2)
        self.pose_decoder = PoseDecoder(self.pose_encoder.num_ch_enc[-1], num_frames_to_predict_for=2)

    # -- depth -----------------------------------------------------------------------------------------
    def predict_disp(self, img: torch.Tensor) -> torch.Tensor:
        """img (B,3,H,W) in [0, 1] → sigmoid disparity (B,1,H,W) in (0, 1) (the raw network output)."""
        return self.depth_decoder(self.depth_encoder(img))

    def disp_to_depth(self, disp: torch.Tensor) -> torch.Tensor:
        """Sigmoid output (B,1,H,W) → depth (B,1,H,W) metres in [min_depth, max_depth]."""
        return disp_to_depth(disp, self.config.min_depth, self.config.max_depth)[1]

    def predict_depth(self, img: torch.Tensor) -> torch.Tensor:
        """img (B,3,H,W) in [0, 1] → depth (B,1,H,W) metres in [min_depth, max_depth]."""
        return self.disp_to_depth(self.predict_disp(img))

    def forward(self, img: torch.Tensor,
                pose_pairs: Sequence[tuple] = ()) -> tuple[torch.Tensor, torch.Tensor, list[torch.Tensor]]:
        """One call for a training step (so DistributedDataParallel sees every parameter used).

        img (B,3,H,W) target in [0, 1]; pose_pairs: (img_a, img_b, invert) or (img_a, img_b, invert, prior,
        prior_ok) per source, as ``predict_pose`` → (sigmoid disp (B,1,H,W), depth (B,1,H,W) metres,
        [T (B,4,4) per pair]). For inference use ``predict_depth``.
        """
        disp = self.predict_disp(img)
        poses = [self.predict_pose(a, b, inv, *rest) for a, b, inv, *rest in pose_pairs]
        return disp, self.disp_to_depth(disp), poses

    # -- pose ------------------------------------------------------------------------------------------
    def pose_params(self, img_a: torch.Tensor, img_b: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Frames a, b (B,3,H,W) in temporal order → (axis-angle (B,2,3), translation (B,2,3)): index 0 is
        PoseCNN's pose ``b_T_a``, index 1 the residual applied to a prior (module docstring)."""
        return self.pose_decoder(self.pose_encoder(torch.cat((img_a, img_b), dim=1)))

    def predict_pose(self, img_a: torch.Tensor, img_b: torch.Tensor, invert: bool = False,
                     prior: torch.Tensor | None = None, prior_ok: torch.Tensor | None = None) -> torch.Tensor:
        """Frames a, b (B,3,H,W) in [0, 1], in temporal order → ``b_T_a`` (B,4,4) = T(t)·R(aa).

        ``prior`` (B,4,4) ``b_T_a`` and ``prior_ok`` (B,) bool (default: every row has one): rows with a
        prior get ``ΔT · prior`` with ΔT from the second output, the others the first output's pose alone
        (module docstring); the prior of a row without one is never read, so it may hold anything, NaN
        included. ``invert=True`` returns the exact inverse ``a_T_b`` (Monodepth2's ``invert`` for earlier
        sources).
        """
        axisangle, translation = self.pose_params(img_a, img_b)
        if prior is None:
            return pose_from_params(axisangle[:, 0], translation[:, 0], invert=invert)
        with torch.autocast(device_type=axisangle.device.type, enabled=False):  # compose in float32
            aa, t = axisangle.float(), translation.float()
            ok = prior_ok if prior_ok is not None else torch.ones(len(prior), dtype=torch.bool,
                                                                  device=prior.device)
            eye = torch.eye(4, dtype=torch.float32, device=prior.device)
            safe = torch.where(ok[:, None, None], prior.float(), eye)  # no NaN reaches the gradients
            T = torch.where(ok[:, None, None], pose_from_params(aa[:, 1], t[:, 1]) @ safe,
                            pose_from_params(aa[:, 0], t[:, 0]))
            return invert_pose(T) if invert else T

    # -- weights ---------------------------------------------------------------------------------------
    def set_initial_depth(self, depth: float) -> None:
        """Shift the depth decoder's output bias so that the untrained DepthCNN predicts about ``depth``
        metres everywhere instead of the ≈ 0.2 m of sigmoid 0.5 (P²Net's and Monodepth2's start).

        Only the bias of ``depth_decoder.dispconv`` changes (by the pre-sigmoid value of ``depth``); the
        random weights still vary the output around it. Call before training, not on a trained model.
        """
        bias = sigmoid_input_for_depth(depth, self.config.min_depth, self.config.max_depth)
        with torch.no_grad():
            self.depth_decoder.dispconv.bias.fill_(bias)

    def load_imagenet(self, path: str | os.PathLike) -> None:
        """Initialise both encoders from a torchvision ImageNet ResNet state_dict file.

        The pose encoder's 6-channel first convolution is the ImageNet one duplicated and halved.
        """
        state = load_imagenet_resnet(path, self.config.num_layers)
        self.depth_encoder.load_imagenet(state, source=str(path))
        self.pose_encoder.load_imagenet(state, source=str(path))


def save_checkpoint(path: str | os.PathLike, model: DepthModel, params: dict[str, Any] | None = None,
                    **extra: Any) -> None:
    """Write ``{"format": "f2depth.depth", "version": 1, "state_dict", "weights_sha256", "config", "params",
    **extra}`` atomically (docs/formats.md, Models; ``weights_sha256``: :func:`f2depth.io.weights_digest` of
    the state dict, checked on load). ``extra`` may hold e.g. optimizer state or the epoch."""
    reserved = {"format", "version", "state_dict", "weights_sha256", "config", "params"} & set(extra)
    if reserved:
        raise ValueError(f"save_checkpoint: extra keys {sorted(reserved)} clash with the checkpoint format")
    state = {k: v.detach().cpu() for k, v in model.state_dict().items()}
    ckpt = {"format": CHECKPOINT_FORMAT, "version": CHECKPOINT_VERSION, "state_dict": state,
            "weights_sha256": weights_digest(state), "config": model.config.to_dict(),
            "params": dict(params or {}), **extra}
    torch_save(path, ckpt)


def read_checkpoint(path: str | os.PathLike) -> dict[str, Any]:
    """Load and validate a depth checkpoint dict (format, version, keys); tensors on CPU. Every problem,
    a missing file included, is a :class:`~f2depth.errors.CheckpointError` whose one line starts with
    the path and ends with the fix."""
    path = Path(path)
    if path.is_dir():
        inside = sorted(p.name for p in path.glob("*.pt"))[:4]
        hint = f"give a checkpoint file in it ({', '.join(inside)})" if inside else "give a checkpoint file"
        raise CheckpointError(f"{path}: is a directory, not a depth checkpoint; {hint}")
    if not path.is_file():
        raise CheckpointError(f"{path}: depth checkpoint not found; run `dvc repro train_depth` first")
    try:
        ckpt = load_weights(path, "an f2depth checkpoint",
                            "give a model written by f2depth (models/depth_<variant>/model.pt)")
    except ValueError as exc:
        raise CheckpointError(str(exc)) from exc
    if not isinstance(ckpt, dict):
        raise CheckpointError(f"{path}: expected a checkpoint dict, got {type(ckpt).__name__}")
    fmt = ckpt.get("format")
    if fmt != CHECKPOINT_FORMAT:
        raise CheckpointError(f"{path}: format {fmt!r} is not {CHECKPOINT_FORMAT!r}; this is not a "
                         f"DepthCNN/PoseCNN checkpoint (flow models are 'f2depth.flow')")
    version = ckpt.get("version")
    if version != CHECKPOINT_VERSION:
        raise CheckpointError(f"{path}: checkpoint version {version!r} is not supported (expected "
                         f"{CHECKPOINT_VERSION}); retrain with this version of f2depth")
    missing = [k for k in ("state_dict", "config", "params") if k not in ckpt]
    if missing:
        raise CheckpointError(f"{path}: checkpoint lacks {missing}; the file is incomplete, retrain or "
                              "re-save it")
    return ckpt


def _checkpoint_config(path: str | os.PathLike, config: Any) -> DepthModelConfig:
    """The checkpoint's ``config`` entry as a DepthModelConfig; any problem → CheckpointError naming the
    file."""
    if not isinstance(config, dict):
        raise CheckpointError(f"{path}: config is a {type(config).__name__}, not a dict of DepthModelConfig "
                         "fields; the file is damaged, retrain or re-save it")
    try:
        return DepthModelConfig.from_dict(config, source=f"{path}: config")
    except ValueError as exc:
        text = str(exc)
        raise CheckpointError(text if text.startswith(f"{path}:") else f"{path}: config: {text}") from None


def _check_finite(path: str | os.PathLike, state: dict[str, torch.Tensor]) -> None:
    """CheckpointError naming the file, the count and the first tensor when any floating weight is NaN or ±inf
    (a diverged training saves such weights, and they predict NaN depth everywhere)."""
    bad = {k: int((~torch.isfinite(v)).sum()) for k, v in state.items() if v.is_floating_point()}
    bad = {k: n for k, n in bad.items() if n}
    if bad:
        first = next(iter(bad))
        raise CheckpointError(f"{path}: {sum(bad.values())} non-finite weight(s) (NaN or inf) in {len(bad)} "
                         f"tensor(s), first {first}; the model is broken (a diverged training?): retrain "
                         "it or use another checkpoint")


def load_checkpoint(path: str | os.PathLike, map_location: str | torch.device = "cpu",
                    decoder_upsample: str | None = None) -> DepthModel:
    """Rebuild a DepthModel from a checkpoint written by ``save_checkpoint`` (strict key check).

    ``decoder_upsample`` ("nearest" | "bilinear") rebuilds the depth decoder with that ×2 upsampling
    instead of the one it was trained with (the layers have no weights): P²Net's NYU evaluation script
    (``nyuv2_eval_depth.py`` in P²Net's code) builds the decoder with bilinear upsampling while its
    training uses nearest. None: as trained.
    """
    return model_from_checkpoint(read_checkpoint(path), path, map_location, decoder_upsample)


def model_from_checkpoint(ckpt: dict[str, Any], path: str | os.PathLike,
                          map_location: str | torch.device = "cpu", decoder_upsample: str | None = None
                          ) -> DepthModel:
    """:func:`load_checkpoint` of a dict :func:`read_checkpoint` gave (``path`` names the file in errors), for
    a caller that also reads the checkpoint's ``params`` without loading the file twice."""
    config = _checkpoint_config(path, ckpt["config"])
    if decoder_upsample is not None:
        config = dataclasses.replace(config, upsample_mode=decoder_upsample)
    state = ckpt["state_dict"]
    if not isinstance(state, dict) or not all(isinstance(v, torch.Tensor) for v in state.values()):
        raise CheckpointError(f"{path}: state_dict is not a dict of tensors; the file is damaged, retrain or "
                         "re-save it")
    _check_finite(path, state)
    model = DepthModel(config)
    try:
        result = model.load_state_dict(state, strict=False)
    except RuntimeError as exc:  # shape mismatches
        first = " ".join(str(exc).split())[:200]  # torch lists every mismatching tensor on its own line
        raise CheckpointError(f"{path}: state_dict does not fit DepthModel({config}): {first}; retrain it "
                              "or give the model it was trained as") from exc
    if result.missing_keys or result.unexpected_keys:
        raise CheckpointError(f"{path}: state_dict does not match DepthModel({config}): missing "
                         f"{result.missing_keys[:5]}, unexpected {result.unexpected_keys[:5]}")
    damage = damaged_weights(path, ckpt, "re-run the stage that wrote it (`dvc repro train_depth`)")
    if damage:
        raise CheckpointError(damage)
    return model.to(map_location)
