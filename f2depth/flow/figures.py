"""Figure 8 of the paper for our models: per pair one row RGB | flow of each model | ground truth, flows
in the Middlebury colour coding (:func:`f2depth.colour.flow_to_color`) with one magnitude scale
per row (the largest ground-truth magnitude, or the largest predicted one without ground truth). Under
each predicted flow: its EPE on all / low-texture pixels of that pair.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

import numpy as np
import torch

from f2depth.colour import flow_to_color
from f2depth.flow.evaluation import epe_stats
from f2depth.flow.finetune_data import GTPair
from f2depth.flow.net.network import FlowNetwork
from f2depth.io import atomic_path


@dataclass(frozen=True)
class FigureRow:
    """One pair: ``rgb (H,W,3)`` uint8, flows ``(H,W,2)`` per column title, ground truth or None."""

    pair_id: str
    rgb: np.ndarray
    flows: dict[str, np.ndarray]
    epe: dict[str, tuple[float | None, float | None]]
    gt: np.ndarray | None


def _hw2(flow: torch.Tensor) -> np.ndarray:
    return flow[0].permute(1, 2, 0).float().cpu().numpy()


def _predict(models: Mapping[str, FlowNetwork], img1: torch.Tensor, img2: torch.Tensor, device: str
             ) -> dict[str, torch.Tensor]:
    out = {}
    for title, model in models.items():
        model.to(device).eval()
        out[title] = model(img1.to(device), img2.to(device), with_backward=False)[0][0].cpu()
    return out


def _rgb(img: torch.Tensor) -> np.ndarray:
    return (img[0].permute(1, 2, 0).numpy() * 255).round().astype(np.uint8)


@torch.no_grad()
def comparison_rows(models: Mapping[str, FlowNetwork], pairs: Iterable[GTPair], device: str = "cpu"
                    ) -> list[FigureRow]:
    """Predict every pair with every model (``{column title: model}``, in column order)."""
    rows = []
    for g in pairs:
        flows, epe = {}, {}
        for title, pred in _predict(models, g.img1, g.img2, device).items():
            stats = epe_stats(pred, g.flow, g.occluded, g.low_texture, g.valid)
            flows[title] = _hw2(pred)
            epe[title] = (stats["epe_all"], stats["epe_low_texture"])
        rows.append(FigureRow(g.pair_id, _rgb(g.img1), flows, epe, _hw2(g.flow * g.valid)))
    return rows


@torch.no_grad()
def prediction_rows(models: Mapping[str, FlowNetwork],
                    pairs: Iterable[tuple[str, torch.Tensor, torch.Tensor]], device: str = "cpu"
                    ) -> list[FigureRow]:
    """:func:`comparison_rows` for pairs without ground truth (``(pair_id, img1, img2)``, images
    ``(1,3,H,W)`` in [0,1]): the predictions only, no EPE and no ground-truth column."""
    rows = []
    for pair_id, img1, img2 in pairs:
        preds = _predict(models, img1, img2, device)
        rows.append(FigureRow(pair_id, _rgb(img1), {t: _hw2(f) for t, f in preds.items()},
                              dict.fromkeys(preds, (None, None)), None))
    return rows


def _fmt(x: float | None) -> str:
    return "–" if x is None else f"{x:.2f}"


def render_flow_comparison(rows: list[FigureRow], path: str | os.PathLike, gt_title: str = "Ground truth",
                           dpi: int = 150) -> None:
    """Write the figure (PNG, atomically): one row per pair, column titles on top."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if not rows:
        raise ValueError(f"{path}: no pairs to draw")
    titles = list(rows[0].flows)
    ncol = len(titles) + 2
    h, w = rows[0].rgb.shape[:2]
    fig, axes = plt.subplots(len(rows), ncol, figsize=(ncol * 2.4, len(rows) * 2.4 * h / w + 0.6),
                             squeeze=False)
    for r, row in enumerate(rows):
        scale = (float(np.linalg.norm(row.gt, axis=2).max()) if row.gt is not None else
                 max(float(np.linalg.norm(f, axis=2).max()) for f in row.flows.values()))
        panels = [("RGB", row.rgb, row.pair_id)]
        panels += [(t, flow_to_color(row.flows[t], scale),
                    f"EPE {_fmt(row.epe[t][0])} / low {_fmt(row.epe[t][1])}") for t in titles]
        gt_img = flow_to_color(row.gt, scale) if row.gt is not None else np.full_like(row.rgb, 255)
        panels.append((gt_title, gt_img, f"max {scale:.1f} px" if row.gt is not None else "no ground truth"))
        for c, (title, img, label) in enumerate(panels):
            ax = axes[r, c]
            ax.imshow(img)
            ax.set_xticks([])
            ax.set_yticks([])
            ax.set_xlabel(label, fontsize=7)
            if r == 0:
                ax.set_title(title, fontsize=9)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi)
    plt.close(fig)
