"""DVC stage `flow_pretrain`: the flow network (`flow_pretrain.network`, PWC-Lite) imported from ARFlow or
pretrained with ARFlow's loss.

Usage: python stages/flow_pretrain.py [params.yaml]

With `flow_pretrain.checkpoint` set, that ARFlow *.pth.tar (or another state dict of the network) is
imported. Otherwise the network is trained from scratch (ARFlow's schedule, f2depth.flow.pretrain) on the
Sintel-layout set at `data.sintel` — the synthetic animated set (`source: synthetic`) or MPI Sintel
(`source: sintel`) — without its last `holdout` sequences, resuming from `resume_dir` after an
interruption. Writes `model` (recording the network's name),
metrics/flow_pretrain.json (EPE, magnitude ratio Σ|flow|/Σ|gt| and mean cosine to the true flow of the
model and of zero flow on the held-out sequences and, with `eval_prepared`, on the prepared pairs with
ground truth) and colour-wheel figures into `figure_dir`.
"""

from __future__ import annotations

import sys
import time

import torch

from f2depth import params as P
from f2depth import tracking
from f2depth.data.sintel import list_pairs, list_sequences
from f2depth.eval.tables import format_value as fmt
from f2depth.flow import NETWORKS, build_network, load_flow_model, save_flow_model
from f2depth.flow.pretrain import PretrainConfig, clear_resume, pretrain
from f2depth.flow.validate import evaluate_prepared, evaluate_sintel
from f2depth.io import write_json
from f2depth.stage import run_stage

METRICS = "metrics/flow_pretrain.json"


def split_sequences(p: dict) -> tuple[list[str], list[str]]:
    root, holdout = P.get(p, "data.sintel"), int(P.get(p, "flow_pretrain.holdout"))
    seqs = list_sequences(root, P.get(p, "flow_pretrain.passes")[0])
    if not 0 < holdout < len(seqs):
        raise P.ParamsError(f"{p['_file']}: flow_pretrain.holdout = {holdout} must leave training and test "
                            f"sequences among the {len(seqs)} in {root}")
    return seqs[:-holdout], seqs[-holdout:]


def main(argv: list[str]) -> None:
    p = P.load(argv[1] if len(argv) > 1 else P.DEFAULT_PARAMS)
    t0 = time.perf_counter()
    P.pretrained_starts(p, ("flow_pretrain.checkpoint",))  # the paper's start required unless allowed
    section = P.get(p, "flow_pretrain")
    if P.get(p, "flow_pretrain.source") not in ("synthetic", "sintel"):
        raise P.ParamsError(f"{p['_file']}: flow_pretrain.source must be 'synthetic' or 'sintel'")
    device = P.resolve_device(str(P.get(p, "device")))
    root, passes = P.get(p, "data.sintel"), tuple(P.get(p, "flow_pretrain.passes"))
    train_seqs, test_seqs = split_sequences(p)
    network = str(P.get(p, "flow_pretrain.network"))
    if network not in NETWORKS:
        raise P.ParamsError(f"{p['_file']}: flow_pretrain.network = {network!r} is not a flow network; "
                            f"use one of {sorted(NETWORKS)} (f2depth.flow.checkpoint.NETWORKS)")
    cfg = PretrainConfig(**{k: int(section[k]) for k in ("height", "width", "raw_epochs", "census_epochs",
                                                          "batch_size")},
                         lr=float(section["lr"]), seed=int(P.get(p, "seed")), init=str(section["init"]))
    figures, n_fig = P.get(p, "flow_pretrain.figure_dir"), int(P.get(p, "flow_pretrain.figures"))
    metrics: dict = {"source": "arflow" if section.get("checkpoint") else str(section["source"]),
                     "random_init": not section.get("checkpoint"),
                     "train_sequences": train_seqs, "heldout_sequences": test_seqs}
    with tracking.stage_run("flow_pretrain", p) as run:
        if section.get("checkpoint"):
            model = load_flow_model(section["checkpoint"], network)
            metrics["imported"] = str(section["checkpoint"])
        else:
            torch.manual_seed(cfg.seed)
            model = build_network(network)
            metrics["training"] = pretrain(
                model, list_pairs(root, passes, train_seqs), cfg, section["resume_dir"], device,
                on_epoch=lambda epoch, st: run.log_metrics({f"train.{k}": v for k, v in st.items()}, epoch))
        save_flow_model(section["model"], model, config={"origin": metrics["source"], **vars(cfg)},
                        params=section)
        model.to(device).eval()
        for pass_name in passes:
            metrics[f"heldout_{pass_name}"] = evaluate_sintel(
                model, list_pairs(root, (pass_name,), test_seqs, require_flow=True), (cfg.height, cfg.width),
                device, figures, n_fig)
        if P.get(p, "flow_pretrain.eval_prepared"):
            metrics["prepared"] = evaluate_prepared(model, P.get(p, "data.prepared"),
                                                    P.get(p, "flow_pretrain.eval_prepared_pairs"), device,
                                                    figures, n_fig)
        metrics["seconds"] = round(time.perf_counter() - t0, 1)
        write_json(METRICS, metrics)
        run.log_metrics({k: v for k, v in metrics.items() if k.startswith(("heldout_", "prepared"))})
        run.log_artifact(section["model"])
        run.log_artifact(figures, "figures")
    clear_resume(section["resume_dir"])
    for name, res in metrics.items():
        if isinstance(res, dict) and "model" in res:
            m, z = res["model"], res["zero_flow"]
            print(f"flow_pretrain {name} ({res['pairs']} pairs): EPE all {m['epe_all']:.3f} (zero flow "
                  f"{z['epe_all']:.3f}), noc {m['epe_noc']:.3f} ({z['epe_noc']:.3f}), low texture "
                  f"{fmt(m['epe_low_texture'])} ({fmt(z['epe_low_texture'])}), "
                  f"|f|/|gt| {fmt(m.get('magnitude_ratio'), 2)}, cos {fmt(m.get('cosine'), 2)}, "
                  f"swap cos {fmt(m.get('swap_consistency'), 2)}")
            if (m.get("swap_consistency") or 0.0) < 0:
                print(f"flow_pretrain: WARNING {name}: flow(2→1) is not the reverse of flow(1→2) "
                      f"(swap cos {m['swap_consistency']:.2f}): the network's output does not follow the "
                      "images; its EPE and cosine there measure a constant field (docs/flow_pretrain.md)")
    print(f"flow_pretrain: {metrics['seconds']} s → {section['model']}")



if __name__ == "__main__":
    run_stage("flow_pretrain", main, sys.argv)
