"""Figures as PNG: qualitative depth grids (the paper's Figures 5 and 7), AbsRel error maps and training
curves. Matplotlib's object API (no pyplot state, no display needed); files are written atomically.

Depth maps are median-scaled and clipped predictions next to the ground truth (m). Every row of a grid
shares one colour scale (the 1st-99th percentile of that row's valid ground truth), so the columns are
comparable; invalid ground truth (0) is drawn black.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence

import numpy as np
from matplotlib.colors import Colormap
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from f2depth.geometry import MAX_DEPTH, MIN_DEPTH
from f2depth.io import atomic_path

DEPTH_CMAP = "magma_r"  # near = bright
ERROR_CMAP = "inferno"
ERROR_MAX = 0.5  # AbsRel at the top of the error colour scale


def _cmap(name: str) -> Colormap:
    from matplotlib import colormaps

    return colormaps[name].with_extremes(bad="black")


def _save(fig: Figure, path: str | os.PathLike, dpi: int = 100) -> None:
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=dpi, bbox_inches="tight", format="png")


def row_range(gt: np.ndarray) -> tuple[float, float]:
    """Colour range (m) of one row: 1st-99th percentile of gt's valid (> 0) pixels; the depth range
    (``f2depth.geometry.MIN_DEPTH``, ``MAX_DEPTH``) if none."""
    valid = gt[gt > 0]
    if valid.size == 0:
        return MIN_DEPTH, MAX_DEPTH
    lo, hi = np.percentile(valid, [1, 99])
    return float(lo), float(max(hi, lo + 1e-3))


def abs_rel_map(pred: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """|pred − gt| / gt per pixel (H,W); NaN where gt ≤ 0."""
    out = np.full(gt.shape, np.nan, np.float64)
    valid = gt > 0
    out[valid] = np.abs(pred[valid] - gt[valid]) / gt[valid]
    return out


def _grid(k: int, cols: int, hw: tuple[int, int], row_inches: float, title: str) -> tuple[Figure, np.ndarray]:
    """A figure of ``k`` rows × ``cols`` panels of images of aspect ``hw``; axes (k, cols)."""
    size = (2.4 * cols + 0.8, row_inches * hw[0] / hw[1] * k + (0.5 if title else 0.3))
    fig = Figure(figsize=size, layout="constrained")
    return fig, fig.subplots(k, cols, squeeze=False)


def _finish(fig: Figure, axes: np.ndarray, path: str | os.PathLike, row_labels: Sequence[str],
            title: str) -> None:
    """Row labels, no ticks, the title; then write the PNG."""
    for i, label in enumerate(row_labels[: axes.shape[0]]):
        axes[i, 0].set_ylabel(label, fontsize=8)
    for ax in axes.ravel():
        ax.set_xticks([])
        ax.set_yticks([])
    if title:
        fig.suptitle(title, fontsize=11)
    _save(fig, path)


def depth_grid(path: str | os.PathLike, rgb: np.ndarray, preds: Sequence[tuple[str, np.ndarray]],
               gt: np.ndarray, row_labels: Sequence[str] = (), title: str = "") -> None:
    """Rows of [RGB, each prediction, ground truth]. rgb (K,h,w,3) uint8; preds: (label, (K,h,w) m);
    gt (K,h,w) m, 0 = invalid. One colour scale per row with a colour bar."""
    fig, axes = _grid(rgb.shape[0], 2 + len(preds), gt.shape[1:], 2.4, title)
    cmap = _cmap(DEPTH_CMAP)
    for i in range(rgb.shape[0]):
        lo, hi = row_range(gt[i])
        axes[i, 0].imshow(rgb[i])
        im = None
        for j, (_, pred) in enumerate(preds, start=1):
            im = axes[i, j].imshow(pred[i], cmap=cmap, vmin=lo, vmax=hi)
        axes[i, -1].imshow(np.ma.masked_less_equal(gt[i], 0), cmap=cmap, vmin=lo, vmax=hi)
        if im is not None:
            fig.colorbar(im, ax=axes[i, -1], fraction=0.05, pad=0.02, label="m")
    for j, head in enumerate(["RGB", *[p[0] for p in preds], "Ground truth"]):
        axes[0, j].set_title(head, fontsize=10)
    _finish(fig, axes, path, row_labels, title)


def error_grid(path: str | os.PathLike, rgb: np.ndarray, preds: Sequence[tuple[str, np.ndarray]],
               gt: np.ndarray, row_labels: Sequence[str] = (), title: str = "") -> None:
    """Rows of [RGB, AbsRel map of each prediction] on one scale 0…ERROR_MAX; each panel is titled with
    its mean AbsRel over the valid pixels."""
    k = rgb.shape[0]
    fig, axes = _grid(k, 1 + len(preds), gt.shape[1:], 2.6, title)
    cmap = _cmap(ERROR_CMAP)
    im = None
    for i in range(k):
        axes[i, 0].imshow(rgb[i])
        for j, (label, pred) in enumerate(preds, start=1):
            err = abs_rel_map(pred[i], gt[i])
            im = axes[i, j].imshow(np.ma.masked_invalid(err), cmap=cmap, vmin=0.0, vmax=ERROR_MAX)
            mean = float(np.nanmean(err)) if np.isfinite(err).any() else math.nan
            axes[i, j].set_title(f"{label}: AbsRel {mean:.3f}", fontsize=8)
    axes[0, 0].set_title("RGB", fontsize=10)
    if im is not None:
        fig.colorbar(im, ax=axes, shrink=min(1.0, 3.0 / k), fraction=0.05, pad=0.02, label="|pred − gt| / gt")
    _finish(fig, axes, path, row_labels, title)


def training_curves(path: str | os.PathLike, depth: Mapping[str, Mapping[str, Sequence[float]]],
                    validation: Mapping[str, Mapping[str, Sequence[float]]],
                    flow: Mapping[str, Mapping[str, Sequence[float]]]) -> None:
    """Depth training (total loss, validation δ1 and AbsRel per epoch, one line per variant) and flow
    fine-tuning (held-out EPE per epoch, one line per loss). Inputs: ``{name: {column: values}}`` as
    read from the history files (``epoch`` column required): ``depth`` and ``flow`` each run's
    history.csv, ``validation`` each depth run's validation.csv; empty mappings leave a panel blank."""
    fig = Figure(figsize=(11, 7.5), layout="constrained")
    axes = fig.subplots(2, 2).ravel()
    panels = [(axes[0], depth, "total", "training loss (L_depth)"),
              (axes[1], validation, "val_a1", "validation δ<1.25 ↑"),
              (axes[2], validation, "val_abs_rel", "validation AbsRel ↓")]
    for ax, source, column, label in panels:
        for name, h in source.items():
            if column in h and "epoch" in h:
                x, y = np.asarray(h["epoch"]), np.asarray(h[column], dtype=float)
                ok = np.isfinite(y)
                ax.plot(x[ok], y[ok], marker="o", ms=3, label=name)
        ax.set_xlabel("epoch")
        ax.set_ylabel(label)
    ax = axes[3]
    for i, (name, h) in enumerate(flow.items()):
        for column, style in (("epe_low_texture", "-"), ("epe_all", "--")):
            if column in h and "epoch" in h:
                y = np.asarray(h[column], dtype=float)
                ok = np.isfinite(y)
                ax.plot(np.asarray(h["epoch"])[ok], y[ok], style, color=f"C{i}", marker="o", ms=3,
                        label=f"{name}: {column.removeprefix('epe_').replace('_', '-')}")
    ax.set_xlabel("epoch")
    ax.set_ylabel("flow EPE on held-out pairs (px) ↓")
    for a in axes:
        if a.get_legend_handles_labels()[0]:
            a.legend(fontsize=7)
        else:
            a.text(0.5, 0.5, "no history file found", ha="center", va="center", transform=a.transAxes)
        a.xaxis.set_major_locator(MaxNLocator(integer=True))
        a.grid(alpha=0.3)
    fig.suptitle("Training curves: depth variants (train_depth) and flow fine-tuning (flow_finetune)")
    _save(fig, path)
