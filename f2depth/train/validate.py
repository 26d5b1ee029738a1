"""Per-epoch validation: δ1 and AbsRel on the NYU-format labeled test set, at the training size.

The NYU protocol of ``f2depth.protocols.nyu.evaluate_nyu`` (crop, median scaling, clip to [0.1, 10] m, metrics
per image averaged) with the network input at the *training* size instead of 288×384 and no
post-processing — cheap enough to run every epoch and before training (epoch 0). ``max_images`` evenly
spaced test images keep it quick (up to ``CACHE_MAX`` of them are read once and kept in memory); the
``evaluate`` stage reports the full protocol.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from f2depth.depth import disp_to_depth
from f2depth.depth.predict import PredictDisp
from f2depth.formats.nyu_labeled import NYULabeledSet
from f2depth.protocols.nyu import evaluate_nyu

#: Validation sets of at most this many images are read from the .mat once and kept in memory (~2 MB each).
CACHE_MAX = 100


@contextmanager
def evaluating(model: nn.Module) -> Iterator[nn.Module]:
    """``model`` in eval mode inside the block; its train/eval mode is restored afterwards, also on error."""
    was_training = model.training
    model.eval()
    try:
        yield model
    finally:
        model.train(was_training)


@dataclass(frozen=True)
class ValConfig:
    mat: str
    splits: str
    gt: str = "depths"
    crop: str = "eigen"
    max_images: int | None = 20
    batch_size: int = 4


class Validator:
    """``validator(model) → {"val_abs_rel", "val_a1"}`` on a fixed subset of the test split."""

    def __init__(self, config: ValConfig, height: int, width: int,
                 device: torch.device | str = "cpu") -> None:
        self.config, self.height, self.width, self.device = config, height, width, torch.device(device)
        self.set = NYULabeledSet(config.mat, config.splits, split="test", gt=config.gt)
        n = len(self.set)
        if config.max_images is not None and config.max_images < n:
            spread = np.linspace(0, n - 1, int(config.max_images)).round().astype(int)
            self.positions = np.unique(spread).tolist()
        else:
            self.positions = list(range(n))
        self._cache = [self.set[i] for i in self.positions] if len(self.positions) <= CACHE_MAX else None

    def __len__(self) -> int:
        return len(self.positions)

    @torch.no_grad()
    def __call__(self, model: nn.Module) -> dict[str, float]:
        lo, hi = model.config.min_depth, model.config.max_depth

        def predict_disp(x: torch.Tensor) -> torch.Tensor:
            return disp_to_depth(model.predict_disp(x), lo, hi)[0]  # scaled disparity, ∝ 1/depth

        with evaluating(model):
            return self.score(predict_disp)

    @torch.no_grad()
    def score(self, predict_disp: PredictDisp) -> dict[str, float]:
        """``{"val_abs_rel", "val_a1"}`` of any ``predict_disp(img (B,3,H,W)) → disp (B,1,H,W)``."""
        samples = self._cache if self._cache is not None else (self.set[i] for i in self.positions)
        result = evaluate_nyu(
            samples, predict_disp, height=self.height, width=self.width,
            crop=self.config.crop, batch_size=self.config.batch_size, device=str(self.device),
        )  # fmt: skip
        m = result.metrics
        return {"val_abs_rel": float(m["abs_rel"]), "val_a1": float(m["a1"])}

    def close(self) -> None:
        self.set.close()


def make_validator(mat: str | os.PathLike, splits: str | os.PathLike, height: int, width: int,
                   device: torch.device | str = "cpu", **kwargs) -> Validator:
    return Validator(ValConfig(str(mat), str(splits), **kwargs), height, width, device)
