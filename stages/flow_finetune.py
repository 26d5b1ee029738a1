"""DVC stage `flow_finetune`: PWC-Lite fine-tuned on the prepared pairs (t, t+1) with F²Depth's patch
census loss (`patch`, computed over `w_scales` and both directions with `backward`, as ARFlow computes its
loss) or ARFlow's own all-pixel loss (`full`, ARFlow's sintel_ft settings; Table 6).

Usage: python stages/flow_finetune.py --loss {patch,full} [--params params.yaml]

Starts from `flow_finetune.pretrained`, trains on the pairs of every scene except the last
`holdout_scenes` scenes with ground truth, and scores EPE (all / non-occluded / low-texture) on the
held-out pairs after every epoch. Writes `flow_finetune.model` (with {loss}), `<out_dir>/<loss>/history.csv`
(DVC plots), `<out_dir>/<loss>.json` (the loss settings used, EPE of the pretrained and the fine-tuned
model on the held-out test pairs and on up to `eval_train_pairs` training pairs, with the magnitude ratio
Σ|flow|/Σ|gt| and the mean cosine to the true flow, zero-flow baseline, seconds) and mirrors it to MLflow.
The training state goes to `<resume_dir>/<loss>.pt` after every epoch and is removed at the end.
"""

import argparse
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import torch

from f2depth import params as P
from f2depth import threads, tracking
from f2depth.epochs import clear_state, file_digest, write_history
from f2depth.errors import DataError
from f2depth.flow.evaluation import evaluate_gt_pairs
from f2depth.flow.finetune import (
    HISTORY_COLUMNS,
    LOSSES,
    FinetuneConfig,
    finetune,
)
from f2depth.flow.finetune_data import FlowPairs, gt_pairs, split_pairs
from f2depth.flow.net.checkpoint import load_flow_model, save_flow_model
from f2depth.formats.prepared import PreparedSet
from f2depth.io import write_json
from f2depth.keypoints.store import KeypointFile
from f2depth.numbers import format_number as fmt
from f2depth.stage import run_stage


@dataclass(frozen=True)
class FinetuneStage:
    """The ``flow_finetune`` keys that are no part of FinetuneConfig."""

    losses: tuple[Literal[LOSSES], ...]
    holdout_scenes: int = field(metadata={"min": 0})
    eval_train_pairs: int = field(metadata={"min": 0})
    workers: int = field(metadata={"min": 0})
    pretrained: str
    model: str  # {loss} = patch | full
    out_dir: str
    resume_dir: str


def config_from_params(p: dict, loss: str = "patch") -> tuple[FinetuneConfig, FinetuneStage]:
    smooth = P.value(p, "lambda_flow_smooth", float, min=0)
    return P.section(p, "flow_finetune", FinetuneConfig, FinetuneStage, loss=loss,
                     seed=P.value(p, "seed", int), smooth_weight=smooth)


EPE_KEYS = ("epe_all", "epe_noc", "epe_low_texture", "epe_occ", "magnitude_ratio", "cosine",
            "swap_consistency", "pairs")


def _epe(scores: dict, which: str = "model") -> dict:
    """One row of :func:`evaluate_gt_pairs`' ``scores`` (``model`` or ``zero_flow``) with its pair count."""
    row = {"pairs": scores["pairs"], **scores[which]}
    return {k: row.get(k) for k in EPE_KEYS}


def main(argv: list[str]) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--loss", choices=LOSSES, default="patch")
    ap.add_argument("--params", default=str(P.DEFAULT_PARAMS))
    args = ap.parse_args(argv[1:])
    p = P.load(args.params)
    loss = args.loss
    cfg, stage = config_from_params(p, loss)
    threads.use(P.threads(p), loader_workers=stage.workers)
    P.pretrained_starts(p, ("flow_pretrain.checkpoint",))  # the paper starts from ARFlow's Sintel model
    device = P.device(p)
    ds = PreparedSet(P.get(p, "data.prepared"))
    kp_path = Path(P.get(p, "data.keypoints")) / "train.npz"
    keypoints = KeypointFile(kp_path) if loss == "patch" else None
    split = split_pairs(ds, stage.holdout_scenes)
    pretrained = Path(stage.pretrained)
    if not pretrained.is_file():
        raise DataError(pretrained, "pretrained flow model not found", "run `dvc repro flow_pretrain` or "
                        "point flow_finetune.pretrained at a models/flow_*.pt or an ARFlow *.pth.tar")
    model_path = Path(stage.model.format(loss=loss))
    out_dir = Path(stage.out_dir)
    history_csv, metrics_json = out_dir / loss / "history.csv", out_dir / f"{loss}.json"
    resume_path = Path(stage.resume_dir) / f"{loss}.pt"
    train_limit = stage.eval_train_pairs

    torch.manual_seed(cfg.seed)
    t0 = time.perf_counter()
    model = load_flow_model(pretrained)
    levels = model.flow_levels()
    if loss == "patch" and any(w > 0 for w in cfg.w_scales[levels:]):
        raise P.ParamsError(f"{p['_file']}: flow_finetune.w_scales {list(cfg.w_scales)} weighs "
                            f"{len(cfg.w_scales)} levels but the network of {pretrained} outputs {levels}; "
                            f"give at most {levels} weights, finest first")
    test = list(gt_pairs(ds, split.test))
    before_test = evaluate_gt_pairs(model, test, device)
    before = {"test": _epe(before_test),
              "train": _epe(evaluate_gt_pairs(model, gt_pairs(ds, split.train, train_limit), device))}
    fingerprint = {"pretrained_sha256": file_digest(pretrained), "prepared_sha256": file_digest(ds.root),
                   "keypoints_sha256": file_digest(kp_path) if keypoints is not None else None}
    with tracking.stage_run("flow_finetune", p, variant=loss) as run:
        rows: list[dict] = []

        def on_epoch(row: dict) -> None:  # also each row a resumed run replays
            rows.append(row)
            write_history(history_csv, rows, HISTORY_COLUMNS)
            run.log_epoch(row)

        info = finetune(model, FlowPairs(ds, split.train, keypoints), cfg, test, resume_path, fingerprint,
                        device, stage.workers, on_epoch)
        write_history(history_csv, info["history"], HISTORY_COLUMNS)
        save_flow_model(model_path, model,
                        config={"source": "flow_finetune", "loss": loss, "pretrained": str(pretrained),
                                "train_scenes": split.train_scenes, "test_scenes": split.test_scenes},
                        params={**P.get(p, "flow_finetune"), "flow_smooth": cfg.smooth_weight,
                                "seed": cfg.seed})
        after = {"test": _epe(evaluate_gt_pairs(model, test, device)),
                 "train": _epe(evaluate_gt_pairs(model, gt_pairs(ds, split.train, train_limit), device))}
        metrics = {"loss": loss, "loss_settings": cfg.loss_settings(), "ground_truth": bool(test),
                   "test_scenes": split.test_scenes, "test_on_train": split.test_on_train,
                   "train_pairs": len(split.train), "test_pairs": len(split.test), "pretrained": before,
                   "finetuned": after,
                   "zero_flow": {"test": _epe(before_test, "zero_flow")}, "epochs": cfg.epochs,
                   "epochs_run": info["epochs_run"], "resumed_from": info["resumed_from"],
                   "seconds": round(time.perf_counter() - t0, 1)}
        write_json(metrics_json, metrics)
        run.log_summary(metrics)
        run.log_artifact(model_path)
        run.log_artifact(history_csv)
        run.log_artifact(metrics_json)
    clear_state(resume_path)
    for name, m in (("pretrained", before["test"]), ("fine-tuned", after["test"])):
        print(f"flow_finetune[{loss}] {name}: EPE all {fmt(m['epe_all'])}, noc {fmt(m['epe_noc'])}, "
              f"low-texture {fmt(m['epe_low_texture'])}, |f|/|gt| {fmt(m['magnitude_ratio'], 2)}, "
              f"cos {fmt(m['cosine'], 2)}, swap cos {fmt(m['swap_consistency'], 2)} on {m['pairs']} "
              "test pairs")
    print(f"flow_finetune[{loss}]: {len(split.train)} training pairs, {info['epochs_run']} epochs in "
          f"{metrics['seconds']} s → {model_path}")


if __name__ == "__main__":
    run_stage("flow_finetune", main, sys.argv)
