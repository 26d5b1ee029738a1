"""Write the report: tables (Markdown, CSV, LaTeX), figures and the ``README.md`` index."""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from f2depth.io import write_text
from f2depth.protocols import registry
from f2depth.report import figures
from f2depth.report.paper_tables import OURS, P2NET, Table
from f2depth.report.results import VariantResults


def _same_images(a: VariantResults, b: VariantResults, prefix: str) -> bool:
    key = f"{prefix}_id"
    return key in a.kept and key in b.kept and np.array_equal(a.kept[key], b.kept[key])


def write_figures(results: Mapping[str, VariantResults], depth_histories: Mapping[str, Mapping],
                  depth_validations: Mapping[str, Mapping], flow_histories: Mapping[str, Mapping],
                  out_dir: str | os.PathLike) -> list[Path]:
    """Qualitative grids and AbsRel error maps (RGB, baseline, full, GT; the first seed, no PP) for every
    test set with figures (``Protocol.figure``: NYU, 7-Scenes), and the training curves. Returns the
    files written."""
    out = Path(out_dir)
    written: list[Path] = []
    ours, base = results.get(OURS), results.get(P2NET)
    for protocol in registry.protocols():
        prefix, figure = protocol.name, protocol.figure
        if figure is None or ours is None or f"{prefix}_pred" not in ours.kept:
            continue
        title = figure.title
        preds = [("F²Depth (full)", ours.kept[f"{prefix}_pred"])]
        if base is not None and _same_images(ours, base, prefix):
            preds.insert(0, ("P²Net (baseline)", base.kept[f"{prefix}_pred"]))
        rgb, gt = ours.kept[f"{prefix}_rgb"], ours.kept[f"{prefix}_gt"]
        labels = [str(x) for x in ours.kept[f"{prefix}_id"]]
        grid = out / f"{prefix}_qualitative.png"
        figures.depth_grid(grid, rgb, preds, gt, labels, f"{title}: depth (median-scaled, no PP)")
        errors = out / f"{prefix}_error_maps.png"
        figures.error_grid(errors, rgb, preds, gt, labels, f"{title}: per-pixel AbsRel")
        written += [grid, errors]
    curves = out / "training_curves.png"
    figures.training_curves(curves, depth_histories, depth_validations, flow_histories)
    written.append(curves)
    return written


def readme(tables: Sequence[Table], table_dir: str, figure_files: Sequence[Path], root: Path,
           variants: Mapping[str, VariantResults]) -> str:
    """The index of ``reports/``: what the variants are, every table inline with links to its three
    formats, and the figures."""
    seeds = sorted({r.n_seeds for r in variants.values()})
    lines = [
        "# F²Depth reproduction: results",
        "",
        "Written by the `tables` DVC stage (`dvc repro tables`) from `metrics/evaluate/*.json`, "
        "`reports/eval/` and the flow metrics. Rows marked † are quoted from the paper (arXiv 2403.18443), "
        "not reproduced; all other numbers are ours, on the data `params.yaml` points at (by default the "
        "embedded synthetic sets, so they are not comparable in value with the paper's).",
        "",
        f"Variants evaluated: {', '.join(f'`{v}`' for v in variants)}; seeds per variant: "
        f"{', '.join(map(str, seeds))} (cells with several seeds show mean ± sample std, n = seeds; the "
        "cells without PP of Tables 5, 6 and the overview show the mean with its bootstrap interval, "
        "`mean [lo, hi]`, and `tables/ablation_gaps.md` each ablation gap as a paired difference; "
        "`tables/claims.md` lists the gaps whose interval excludes 0).",
        "",
        "## Tables",
        "",
    ]
    for t in tables:
        links = " · ".join(f"[{s[1:]}]({table_dir}/{t.stem}{s})" for s in (".md", ".csv", ".tex"))
        lines += [f"### {t.title}", "", links, "", t.markdown(), ""]
    lines += ["## Figures", ""]
    for f in figure_files:
        rel = f.relative_to(root).as_posix()
        lines += [f"### {f.stem.replace('_', ' ')}", "", f"![{f.stem}]({rel})", ""]
    lines += ["Other figures written by other stages: `figures/keypoints/` (keypoints), "
              "`figures/flow_comparison.png` (flow_figure).", ""]
    return "\n".join(lines)


def write_report(tables: Sequence[Table], results: Mapping[str, VariantResults],
                 depth_histories: Mapping[str, Mapping], depth_validations: Mapping[str, Mapping],
                 flow_histories: Mapping[str, Mapping], root: str | os.PathLike, table_dir: str = "tables",
                 figure_dir: str = "figures/depth") -> dict:
    """Tables into ``root/table_dir``, figures into ``root/figure_dir``, ``root/README.md``; returns
    ``{"tables": [...], "figures": [...], "readme": path}``."""
    root = Path(root)
    table_files = [p for t in tables for p in t.write(root / table_dir)]
    figure_files = write_figures(results, depth_histories, depth_validations, flow_histories,
                                 root / figure_dir)
    index = root / "README.md"
    write_text(index, readme(tables, table_dir, figure_files, root, results))
    return {"tables": table_files, "figures": figure_files, "readme": index}
