"""Scoring a flow model against ground truth: Sintel-layout pairs (``.flo`` + occlusions), generated
FlyingChairs-style pairs (f2depth.flow.chairs) and prepared frame pairs whose flow follows from
ground-truth depth and pose (rigid scene).

Predictions are made at a chosen network size (frames area-resized) and the flow is resized back to the
ground-truth resolution with its components rescaled (ARFlow's protocol), then scored by
:class:`f2depth.flow.evaluation.EPEAccumulator` — next to zero flow on the same pixels as a baseline.
The model also runs on the swapped frames, for ``swap_consistency`` (is the flow read from the images?).
Low-texture pixels are those of :func:`f2depth.flow.evaluation.low_texture_mask` on frame 1.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

from f2depth.colour import flow_to_color
from f2depth.flow.evaluation import (
    EPEAccumulator,
    evaluate_gt_pairs,
    flow_scores,
    low_texture_mask,
    score_pair,
)
from f2depth.flow.net.network import FlowNetwork
from f2depth.formats.images import to_tensor
from f2depth.formats.sintel import SintelPair, load_pair, resized_tensor
from f2depth.geometry import endpoint_error


def evaluate_sintel(model: FlowNetwork, pairs: Sequence[SintelPair], size: tuple[int, int] | None,
                    device: str = "cpu", figure_dir: str | os.PathLike | None = None, figures: int = 0
                    ) -> dict:
    """EPE of ``model`` and of zero flow on Sintel-layout pairs with ``.flo`` and occlusion ground truth.

    With ``figure_dir``, writes colour-wheel PNGs of the first ``figures`` pairs (spread over the list).
    """
    acc, zero = EPEAccumulator(), EPEAccumulator()
    chosen = set(np.linspace(0, len(pairs) - 1, figures).round().astype(int).tolist()) if figures else set()
    for i, pair in enumerate(pairs):
        d = load_pair(pair)
        if d["flow"] is None or d["occluded"] is None:
            raise ValueError(f"evaluate_sintel: {pair.image1} has no flow/occlusion ground truth")
        gt = torch.from_numpy(d["flow"]).permute(2, 0, 1).unsqueeze(0)
        occ = torch.from_numpy(d["occluded"])[None, None]
        a, b = (resized_tensor(d[k], size).unsqueeze(0) for k in ("image1", "image2"))
        low = low_texture_mask(to_tensor(d["image1"]).unsqueeze(0))
        pred = score_pair(model, acc, zero, a, b, gt, occ, low, None, device)
        if figure_dir is not None and i in chosen:
            save_figure(Path(figure_dir) / f"{pair.sequence}_{pair.pass_name}_{pair.frame:04d}.png",
                        d["image1"], gt, pred)
    return flow_scores(acc, zero, len(pairs))


def evaluate_generated(model: FlowNetwork, pairs: Sequence[torch.Tensor], device: str = "cpu",
                       figure_dir: str | os.PathLike | None = None, figures: int = 0) -> dict:
    """EPE of ``model`` and of zero flow on generated pairs ``img1, img2 (n,3,H,W)``, ``flow (n,2,H,W)``,
    ``occluded (n,1,H,W)`` (f2depth.flow.chairs.render_pairs), at their own size."""
    img1, img2, flow, occluded = pairs
    acc, zero = EPEAccumulator(), EPEAccumulator()
    chosen = set(np.linspace(0, len(img1) - 1, figures).round().astype(int).tolist()) if figures else set()
    for i in range(len(img1)):
        a, b = img1[i:i + 1], img2[i:i + 1]
        pred = score_pair(model, acc, zero, a, b, flow[i:i + 1], occluded[i:i + 1], low_texture_mask(a), None,
                          device)
        if figure_dir is not None and i in chosen:
            rgb = (a[0].permute(1, 2, 0) * 255).round().to(torch.uint8).numpy()
            save_figure(Path(figure_dir) / f"generated_{i:03d}.png", rgb, flow[i:i + 1], pred)
    return flow_scores(acc, zero, len(img1))


def evaluate_prepared(model: FlowNetwork, prepared_root: str | os.PathLike, max_pairs: int | None = None,
                      device: str = "cpu", figure_dir: str | os.PathLike | None = None, figures: int = 0
                      ) -> dict | None:
    """EPE on the prepared set's consecutive pairs (``pairs.csv``) that have ground truth; None when the
    set has no ground truth. Ground truth as the fine-tuning scores it (``finetune_data.gt_pair``: rigid
    flow of frame 1's depth under the relative pose with the geometric K; occluded = hidden in frame 2 or
    leaving the image; pixels without depth are not scored). The network runs at the prepared size."""
    from f2depth.flow.finetune_data import gt_pairs, scored_pairs
    from f2depth.formats.prepared import PreparedSet

    ds = PreparedSet(prepared_root)
    pairs = scored_pairs(ds, ds.pairs, max_pairs)
    if not pairs:
        return None
    chosen = set(np.linspace(0, len(pairs) - 1, figures).round().astype(int).tolist()) if figures else set()

    def draw(i: int, g, pred: torch.Tensor) -> None:
        if figure_dir is not None and i in chosen:
            rgb = (g.img1[0].permute(1, 2, 0) * 255).round().to(torch.uint8).numpy()
            save_figure(Path(figure_dir) / f"prepared_{g.pair_id}.png", rgb, g.flow * g.valid, pred)

    return evaluate_gt_pairs(model, gt_pairs(ds, pairs), device, draw)


def save_figure(path: str | os.PathLike, image1: np.ndarray, gt: torch.Tensor, pred: torch.Tensor) -> None:
    """One row: frame 1 | ground truth | prediction (same colour scale) | end-point error (0–5 px, grey)."""
    from f2depth.io import write_rgb

    gt_np = gt[0].permute(1, 2, 0).numpy()
    pred_np = pred[0].permute(1, 2, 0).numpy()
    scale = float(np.linalg.norm(gt_np, axis=2).max()) or 1.0
    err = endpoint_error(pred, gt)[0, 0].numpy()
    err_img = np.repeat((np.clip(err / 5.0, 0, 1) * 255).astype(np.uint8)[..., None], 3, 2)
    row = np.concatenate([image1, flow_to_color(gt_np, scale), flow_to_color(pred_np, scale), err_img], 1)
    write_rgb(path, row)
