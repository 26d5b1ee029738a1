"""DVC stage `evaluate@<variant>`: score every seed's depth model of one ablation variant.

Usage: python stages/evaluate.py --variant NAME [--params params.yaml] [--models models]
       [--metrics metrics/evaluate] [--reports reports/eval]

For each seed k of `train_depth.seeds`, models/depth_NAME/seed<k>.pt runs the protocol of every test set of
`evaluate.datasets` (f2depth/protocols/registry.py: NYU, the `data.nyu_labeled` test split with
`evaluate.nyu_gt`, `evaluate.nyu_crop`; 7-Scenes, every `evaluate.sevenscenes_stride`-th test frame; Campus),
each without and with flip post-processing (one forward pass of each image and its mirror gives both), and the
first seed's model is timed at `evaluate.timing_height` × `timing_width` (batch 1, median of `timing_repeats`
runs after `timing_warmup`; the other seeds' networks are the same, their rows repeat it). Writes
- metrics/evaluate/NAME.json: the mean over seeds of each set's headline (nyu.*, nyu_pp.*, sevenscenes.* =
  mean over all test frames as the paper's Average row, campus.* = mean of the scene rows, ms, ms_pp),
  `n_seeds`, `per_seed`, `decoder_upsample` (`evaluate.decoder_upsample`: the depth decoder is rebuilt with
  it) and `trained_with` (the flow model and loss weights the first seed's checkpoint recorded; Table 5's
  marks);
- reports/eval/NAME/: details.json (per-scene rows, std over images, settings, per seed),
  <set>.csv (per-image metrics of every seed, ± PP) and figures.npz (the first seed's predictions on a few
  test images, for the tables stage's figures);
and mirrors the numbers to an MLflow child run `NAME · evaluate · <pipeline>` (f2depth/tracking.py), whose
input is each seed's model as an MLflow logged model (the one its train_depth run logged).
"""

import argparse
import sys
import time
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Literal

import torch

from f2depth import params as P
from f2depth import threads, tracking
from f2depth.depth import model_from_checkpoint, read_checkpoint
from f2depth.errors import DataError
from f2depth.eval.suite import SuiteConfig, evaluate_model, metrics_document, model_disparity, rows_csv
from f2depth.formats.nyu_labeled import GT_KEYS
from f2depth.formats.samples import limit
from f2depth.formats.writable import check_output_folder
from f2depth.io import save_npz, write_json, write_text
from f2depth.protocols import registry
from f2depth.stage import run_stage


@dataclass(frozen=True)
class EvaluateStage:
    """The ``evaluate`` keys that are no part of SuiteConfig (the protocols read the first two themselves)."""

    nyu_gt: Literal[GT_KEYS]
    sevenscenes_stride: int = field(metadata={"min": 1})
    max_images: int | None = field(metadata={"min": 1})  # per test set; null: all


def config_from_params(p: dict) -> tuple[SuiteConfig, EvaluateStage]:
    return P.section(p, "evaluate", SuiteConfig, EvaluateStage, device=P.device(p), progress=True)


class _Absent(Exception):
    """A test set's data path is null or names nothing."""


def load_sets(p: dict, names: tuple[str, ...], most: int | None) -> dict:
    """The test sets named in `evaluate.datasets`, cut to `evaluate.max_images` each when set. A set whose
    data path (a ``data.*`` key it reads) is null or names nothing is skipped with one warning line (your
    own video without NYU, 7-Scenes or Campus copies); none left is a ParamsError."""
    def get(key: str):
        value = P.get(p, key)
        if key.startswith("data.") and (value is None or not Path(value).exists()):
            raise _Absent(key, value)
        return value

    sets = {}
    for name in names:
        try:
            sets[name] = limit(registry.protocol(name).open(get), most)
        except _Absent as absent:
            key, value = absent.args
            warnings.warn(f"evaluate: skipping test set {name}: {key} is {value!r}, which does not exist "
                          f"(set it to your copy, or drop {name} from evaluate.datasets)", stacklevel=1)
    if not sets:
        raise P.ParamsError(f"{p['_file']}: none of evaluate.datasets {list(names)} has its data: set "
                            "data.nyu_labeled, data.sevenscenes or data.campus to a copy")
    return sets


def main(argv: list[str]) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--variant", required=True)
    ap.add_argument("--params", default=str(P.DEFAULT_PARAMS))
    ap.add_argument("--models", default="models", help="folder of models/depth_<variant>")
    ap.add_argument("--metrics", default="metrics/evaluate", help="folder of <variant>.json")
    ap.add_argument("--reports", default="reports/eval", help="folder of <variant>/ (details, CSV, figures)")
    args = ap.parse_args(argv[1:])
    p = P.load(args.params)
    threads.use(P.threads(p), follow_free_cores=True)  # inference only: the count changes no result
    cfg, stage = config_from_params(p)
    for folder, option in ((Path(args.metrics), "--metrics"), (Path(args.reports) / args.variant,
                                                               "--reports")):
        check_output_folder(folder, option)  # before any work: scoring takes minutes
    if args.variant not in P.get(p, "variants"):
        raise P.ParamsError(f"{p['_file']}: no variant '{args.variant}' under `variants`")
    seeds = P.value(p, "train_depth.seeds", list[int])
    model_dir = Path(args.models) / f"depth_{args.variant}"
    files = [model_dir / f"seed{s}.pt" for s in seeds]
    missing = [str(f) for f in files if not f.is_file()]
    if missing:
        raise DataError(", ".join(missing), "not found", f"run `dvc repro train_depth@{args.variant}` "
                        "(train_depth.seeds lists the seeds to evaluate)")
    # every seed's model before any work: a file that does not fit ends the stage before minutes of scoring
    models, trained, weight_keys = [], None, {}
    for f in files:  # each file read once; the first seed's training params go to the metrics file
        ckpt = read_checkpoint(f)
        models.append(model_from_checkpoint(ckpt, f, cfg.device, cfg.decoder_upsample).eval())
        if trained is None:  # and the params key of each loss term's weight (older checkpoints: none)
            trained, weight_keys = ckpt["params"], ckpt.get("weight_keys", {})
    sets = load_sets(p, cfg.datasets, stage.max_images)
    cfg = replace(cfg, datasets=tuple(sets))  # the sets present (absent ones were skipped with a line)
    out_dir = Path(args.reports) / args.variant
    t0 = time.perf_counter()
    headlines, details, rows, kept = [], {}, {}, None
    weights = {weight_keys.get(term, term): w for term, w in (trained.get("weights") or {}).items()}

    def trained_with(some: list[int]) -> dict:  # the paper's names of what the models were trained with
        return tracking.trained_params(args.variant, weights, trained.get("flow_model"),
                                       trained.get("epochs"), some, trained.get("without") or ())

    with tracking.stage_run("evaluate", p, variant=args.variant, sections=("evaluate",),
                            run_params=trained_with(seeds)) as run:
        run.set_tags({"seeds": seeds})
        model_ids = [run.log_model(f, f"depth_{args.variant}-seed{s}", trained_with([s]), produced=False)
                     for f, s in zip(files, seeds)]  # the logged models their training runs made
        timing = None  # timed with the first seed's model: every seed's network is the same
        for seed, model in zip(seeds, models):
            net_hw = (model.config.height, model.config.width)
            with torch.no_grad():
                r = evaluate_model(model_disparity(model), sets, cfg, net_hw, timing)
            timing = r.details["timing"]
            headlines.append(r.headline)
            details[f"seed{seed}"] = r.details
            for name, items in r.per_image.items():
                rows.setdefault(name, []).extend({"seed": seed, **row} for row in items)
            kept = r.kept if kept is None else kept
            print(f"evaluate[{args.variant}] seed {seed}: " + summary_line(r.headline))
        doc = metrics_document(args.variant, seeds, headlines) | {
            "decoder_upsample": cfg.decoder_upsample,
            "trained_with": {"flow_model": trained.get("flow_model"), "weights": trained.get("weights")}}
        sizes = {name: len(s) for name, s in sets.items()}
        write_json(out_dir / "details.json", {"variant": args.variant, "model_dir": str(model_dir),
                                              "test_set_sizes": sizes, "settings": vars(cfg) | {
                                                  "datasets": list(cfg.datasets)}, "seeds": details})
        for name, items in rows.items():
            write_text(out_dir / f"{name}.csv", rows_csv(items))
        save_npz(out_dir / "figures.npz", **(kept or {}))
        write_json(Path(args.metrics) / f"{args.variant}.json", doc)
        run.log_summary(doc, {m: doc["per_seed"][f"seed{s}"] for m, s in zip(model_ids, seeds)})
        run.log_params({"test_set_sizes": sizes})
        run.log_artifact(Path(args.metrics) / f"{args.variant}.json")
        run.log_artifact(out_dir / "details.json")
    print(f"evaluate[{args.variant}]: {len(seeds)} seed(s), test sets {sizes}, mean over seeds: "
          f"{summary_line(doc)}; {time.perf_counter() - t0:.0f} s → {args.metrics}/{args.variant}.json")


def summary_line(h: dict) -> str:
    parts = [f"{g} AbsRel {h[g]['abs_rel']:.3f} δ1 {h[g]['a1']:.3f}" for g in registry.NAMES if g in h]
    return ", ".join(parts + [f"{h['ms']:.1f} ms ({h['ms_pp']:.1f} ms PP)"])


if __name__ == "__main__":
    run_stage("evaluate", main, sys.argv)
