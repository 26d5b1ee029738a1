"""DVC stage `tables`: the paper's tables and figures from the evaluation of every variant.

Usage: python stages/tables.py [--params params.yaml] [--metrics metrics/evaluate] [--eval reports/eval]
       [--train-metrics metrics/train_depth] [--pretrain-metrics metrics/flow_pretrain.json] [--out reports]
       [--headline metrics/tables.json]

Reads metrics/evaluate/<variant>.json and reports/eval/<variant>/ for every variant under `variants`,
the flow fine-tuning metrics (`flow_finetune.out_dir`/<loss>.json, EPE for Table 6) and the training
histories. Writes reports/tables/<table>.{md,csv,tex} (Table 1, 5, 6, 7-Scenes and Campus per scene,
inference time, all variants), reports/figures/depth/*.png (qualitative grids, error maps, training
curves) and reports/README.md (the index), and attaches them to the MLflow child run `tables`. The
headline goes to metrics/tables.json, the pipeline's one declared DVC metrics file (what `dvc exp show`
compares): δ1 and AbsRel of every variant on NYU, 7-Scenes and Campus, the floors (untrained network,
constant depth) and the flow teachers' EPE and swap consistency (f2depth.report.results.headline).

Seeds with intervals (params.yaml `tables`): from reports/eval/<variant>/<set>.csv (every seed's per-image
metrics), each variant's mean over seeds with its bootstrap interval and each gap of `tables.gaps` ([a, b]:
a − b) as a paired difference (same seeds, same test images) with its interval, marked significant where
the interval excludes 0 (f2depth.report.intervals): in Tables 5, 6 and the overview, in
reports/tables/ablation_gaps.{md,csv,tex}, in reports/tables/claims.md (the gaps the marks support, as
sentences), in metrics/tables.json (`<set>_<metric>_lo`/`_hi`, `gaps`, `confidence`) and in the MLflow run.
"""

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path

from f2depth import params as P
from f2depth import tracking
from f2depth.io import write_json, write_text
from f2depth.report.build import write_report
from f2depth.report.paper_tables import build_tables, claims, claims_markdown
from f2depth.report.results import (
    floors,
    flow_epe,
    headline,
    headline_intervals,
    load_variants,
    read_history,
    read_json,
    teacher_summary,
)
from f2depth.stage import run_stage


@dataclass(frozen=True)
class TablesParams:
    """params.yaml ``tables``: the ablation gaps ([a, b]: a − b) and their bootstrap (``bootstrap``
    resamples, ``confidence`` level, the numpy generator's ``bootstrap_seed``)."""

    gaps: tuple[tuple[str, str], ...]
    bootstrap: int
    confidence: float
    bootstrap_seed: int

    def __post_init__(self) -> None:
        if self.bootstrap < 1:
            raise ValueError(f"bootstrap is {self.bootstrap}; set it to a number of resamples >= 1 (2000)")
        if not 0 < self.confidence < 1:
            raise ValueError(f"confidence is {self.confidence}; set it to a level between 0 and 1 (0.95)")


def config_from_params(p: dict, variants: list[str]) -> TablesParams:
    """The ``tables`` section, every gap naming two different variants of ``variants``."""
    cfg = P.section(p, "tables", TablesParams)
    for i, pair in enumerate(cfg.gaps):
        unknown = [v for v in pair if v not in variants]
        if unknown:
            raise P.ParamsError(f"{p.get('_file', P.DEFAULT_PARAMS)}: tables.gaps[{i}] names {unknown[0]!r}, "
                                f"no variant of `variants` ({', '.join(variants)})")
        if pair[0] == pair[1]:
            raise P.ParamsError(f"{p.get('_file', P.DEFAULT_PARAMS)}: tables.gaps[{i}] compares "
                                f"{pair[0]!r} with itself; name two variants")
    return cfg


def main(argv: list[str]) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--params", default=str(P.DEFAULT_PARAMS))
    ap.add_argument("--metrics", default="metrics/evaluate", help="folder of <variant>.json")
    ap.add_argument("--eval", default="reports/eval", help="folder of <variant>/details.json, figures.npz")
    ap.add_argument("--train-metrics", default="metrics/train_depth",
                    help="folder of <variant>/{history,validation}.csv")
    ap.add_argument("--pretrain-metrics", default="metrics/flow_pretrain.json",
                    help="flow_pretrain's metrics (the teacher's EPE on the prepared pairs)")
    ap.add_argument("--out", default="reports", help="report root: tables/, figures/depth/, README.md")
    ap.add_argument("--headline", default="metrics/tables.json", help="metrics file of the headline numbers")
    args = ap.parse_args(argv[1:])
    p = P.load(args.params)
    variants = list(P.value(p, "variants", dict))
    cfg = config_from_params(p, variants)
    results = load_variants(variants, args.metrics, args.eval)
    flow_dir = Path(P.value(p, "flow_finetune.out_dir", str))
    losses = P.value(p, "flow_finetune.losses", list[str])
    pretrained, template = P.value(p, "flow_finetune.pretrained", str), P.value(p, "flow_finetune.model", str)
    flow = {loss: read_json(flow_dir / f"{loss}.json", f"run `dvc repro flow_finetune@{loss}`")
            for loss in losses}
    epe = {v: flow_epe(P.value(p, f"variants.{v}.flow", str | None), flow, pretrained, template)
           for v in variants}
    depth_hist = {v: read_history(Path(args.train_metrics) / v / "history.csv") for v in variants}
    depth_val = {v: read_history(Path(args.train_metrics) / v / "validation.csv") for v in variants}
    flow_hist = {loss: read_history(flow_dir / loss / "history.csv") for loss in losses}
    intervals = headline_intervals(results, args.eval, list(cfg.gaps), cfg.bootstrap, cfg.confidence,
                                   cfg.bootstrap_seed)
    train = {v: read_json(Path(args.train_metrics) / f"{v}.json", f"run `dvc repro train_depth@{v}`")
             for v in variants}
    tables = build_tables(results, epe, intervals, floors(results, train))
    pretrain = read_json(args.pretrain_metrics, "run `dvc repro flow_pretrain`")
    doc = headline(results, train, teacher_summary(pretrain, flow), intervals)
    with tracking.stage_run("tables", p, sections=("evaluate", "variants", "tables"),
                            closes_pipeline=True) as run:
        written = write_report(tables, results, depth_hist, depth_val, flow_hist, args.out)
        out = Path(args.out)
        write_text(out / "tables" / "claims.md", claims_markdown(intervals))
        run.log_artifact(out / "tables", "tables")
        run.log_artifact(out / "figures" / "depth", "figures")
        run.log_artifact(written["readme"])
        write_json(args.headline, doc)
        run.log_summary(doc)  # every variant's mean and interval, the gaps (``gaps.<a>-<b>.nyu_a1_lo``)
    print(f"tables: {len(tables)} tables ({', '.join(t.stem for t in tables)}) and "
          f"{len(written['figures'])} figures for {len(results)} variants → {written['readme']}; "
          f"{len(claims(intervals))} significant gap(s) ({100 * cfg.confidence:g} % intervals) → "
          f"{out / 'tables' / 'claims.md'}")


if __name__ == "__main__":
    run_stage("tables", main, sys.argv)
