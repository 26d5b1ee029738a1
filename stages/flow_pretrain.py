"""DVC stage `flow_pretrain`: the flow network (`flow_pretrain.network`, PWC-Lite) imported from ARFlow,
bootstrapped on generated FlyingChairs-style pairs, or pretrained with ARFlow's loss.

Usage: python stages/flow_pretrain.py [params.yaml]

With `flow_pretrain.checkpoint` set, that ARFlow *.pth.tar (or another state dict of the network) is
imported (the paper). Otherwise the network is trained from scratch, resuming from `resume_dir` after an
interruption:
- `source: chairs` (the CPU default): supervised on FlyingChairs-style pairs generated on the fly
  (f2depth.flow.chairs; textures: procedural plus crops of the training sequences at `data.sintel`)
  with the bootstrap of f2depth.flow.bootstrap (`flow_pretrain.chairs`);
- `source: synthetic | sintel`: ARFlow's unsupervised schedule (f2depth.flow.pretrain) on the
  Sintel-layout set at `data.sintel` (the animated set or MPI Sintel).
Either way the last `holdout` sequences of `data.sintel` are never trained on. Writes `model` (recording
the network's name), metrics/flow_pretrain.json (EPE, magnitude ratio Σ|flow|/Σ|gt|, mean cosine to the
true flow and swap consistency of the model, beside zero flow, on the held-out sequences, on the held-out
generated pairs (chairs) and, with `eval_prepared`, on the prepared pairs with ground truth),
metrics/flow_pretrain/history.csv (one row per training epoch; only the header for an imported model),
metrics/flow_pretrain/phase_b.csv (the chairs route's phase B epochs: training EPE, held-out swap
consistency; only the header otherwise) and
colour-wheel figures into `figure_dir`.
"""

import sys
import time
from dataclasses import asdict, dataclass, field
from typing import Literal

import torch

from f2depth import params as P
from f2depth import threads, tracking
from f2depth.epochs import write_history
from f2depth.flow import NETWORKS, build_network, load_flow_model, save_flow_model
from f2depth.flow import bootstrap as chairs_route
from f2depth.flow.chairs_ranks import chairs_pool, pretrain_in_ranks
from f2depth.flow.pretrain import HISTORY_COLUMNS, PretrainConfig, clear_resume, pretrain
from f2depth.flow.validate import evaluate_generated, evaluate_prepared, evaluate_sintel
from f2depth.formats.sintel import list_pairs, list_sequences
from f2depth.io import write_json
from f2depth.numbers import format_number as fmt
from f2depth.stage import run_stage

METRICS = "metrics/flow_pretrain.json"
HISTORY = "metrics/flow_pretrain/history.csv"
PHASE_B = "metrics/flow_pretrain/phase_b.csv"


@dataclass(frozen=True)
class PretrainStage:
    """The ``flow_pretrain`` keys that are no part of PretrainConfig."""

    network: str
    checkpoint: str | None
    source: Literal["chairs", "synthetic", "sintel"]
    chairs: chairs_route.BootstrapConfig
    passes: tuple[Literal["clean", "final"], ...]
    holdout: int = field(metadata={"min": 1})
    eval_prepared: bool
    eval_prepared_pairs: int | None = field(metadata={"min": 1})  # null: all
    figures: int = field(metadata={"min": 0})
    figure_dir: str
    model: str
    resume_dir: str

    def __post_init__(self) -> None:
        if self.network not in NETWORKS:
            raise ValueError(f"network = {self.network!r} is not a flow network; use one of "
                             f"{sorted(NETWORKS)} (f2depth.flow.net.checkpoint.NETWORKS)")
        if not self.passes:
            raise ValueError("passes is empty; name the Sintel passes to train on and score (clean, final)")


def config_from_params(p: dict) -> tuple[PretrainConfig, PretrainStage]:
    cfg, stage = P.section(p, "flow_pretrain", PretrainConfig, PretrainStage, seed=P.value(p, "seed", int))
    if not stage.checkpoint and stage.source != "chairs" and cfg.epochs == 0:
        raise P.ParamsError(f"{p['_file']}: flow_pretrain.raw_epochs and census_epochs are both 0, so "
                            "ARFlow's route would save the random initial weights as the flow teacher; set "
                            "one of them above 0, use source: chairs, or import ARFlow's model "
                            "(flow_pretrain.checkpoint)")
    return cfg, stage


def split_sequences(p: dict, stage: PretrainStage) -> tuple[list[str], list[str]]:
    root = P.get(p, "data.sintel")
    seqs = list_sequences(root, stage.passes[0])
    if not stage.holdout < len(seqs):
        raise P.ParamsError(f"{p['_file']}: flow_pretrain.holdout = {stage.holdout} must leave training and "
                            f"test sequences among the {len(seqs)} in {root}")
    return seqs[:-stage.holdout], seqs[-stage.holdout:]


def pretrain_on_chairs(model, stage: PretrainStage, seed: int, train_frames: list, device: str, run
                       ) -> tuple[dict, tuple]:
    """The chairs route → (training result, held-out generated pairs); on a CPU in `cpu_ranks` processes."""
    cfg = stage.chairs
    if device == "cpu" and cfg.cpu_ranks:
        return pretrain_in_ranks(model, cfg, seed, stage.network, train_frames, stage.resume_dir,
                                 on_epoch=run.log_epoch)
    pool = chairs_pool(cfg, seed, train_frames)
    generated = chairs_route.heldout_pairs(cfg, seed, pool)
    result = chairs_route.pretrain_chairs(model, pool, cfg, seed, stage.network, generated,
                                          stage.resume_dir, device, on_epoch=run.log_epoch)
    return result, generated


def main(argv: list[str]) -> None:
    p = P.load(argv[1] if len(argv) > 1 else P.DEFAULT_PARAMS)
    threads.use(P.threads(p))
    cfg, stage = config_from_params(p)
    t0 = time.perf_counter()
    P.pretrained_starts(p, ("flow_pretrain.checkpoint",))  # the paper's start required unless allowed
    device = P.device(p)
    root, passes = P.get(p, "data.sintel"), stage.passes
    train_seqs, test_seqs = split_sequences(p, stage)
    figures, n_fig = stage.figure_dir, stage.figures
    metrics: dict = {"source": "arflow" if stage.checkpoint else stage.source,
                     "random_init": not stage.checkpoint,
                     "train_sequences": train_seqs, "heldout_sequences": test_seqs}
    with tracking.stage_run("flow_pretrain", p) as run:
        if stage.checkpoint:
            model = load_flow_model(stage.checkpoint, stage.network)
            metrics["imported"] = stage.checkpoint
        elif stage.source == "chairs":
            torch.manual_seed(cfg.seed)
            model = build_network(stage.network)
            frames = [pair.image1 for pair in list_pairs(root, passes[:1], train_seqs)]
            metrics["training"], generated = pretrain_on_chairs(model, stage, cfg.seed, frames, device, run)
        else:
            torch.manual_seed(cfg.seed)
            model = build_network(stage.network)
            metrics["training"] = pretrain(
                model, list_pairs(root, passes, train_seqs), cfg, stage.resume_dir, device,
                on_epoch=run.log_epoch)
        made_with = asdict(stage.chairs) if metrics["source"] == "chairs" else vars(cfg)
        save_flow_model(stage.model, model, config={"origin": metrics["source"], **made_with},
                        params=P.get(p, "flow_pretrain"))
        model.to(device).eval()
        if metrics["source"] == "chairs":
            metrics["generated"] = evaluate_generated(model, generated, device, figures, n_fig)
        for pass_name in passes:
            metrics[f"heldout_{pass_name}"] = evaluate_sintel(
                model, list_pairs(root, (pass_name,), test_seqs, require_flow=True), (cfg.height, cfg.width),
                device, figures, n_fig)
        if stage.eval_prepared:
            metrics["prepared"] = evaluate_prepared(model, P.get(p, "data.prepared"),
                                                    stage.eval_prepared_pairs, device, figures, n_fig)
        metrics["seconds"] = round(time.perf_counter() - t0, 1)
        columns = chairs_route.HISTORY_COLUMNS if metrics["source"] == "chairs" else HISTORY_COLUMNS
        rows = metrics.get("training", {}).get("history", [])
        write_history(HISTORY, rows, columns)
        write_history(PHASE_B, rows, chairs_route.PHASE_B_COLUMNS)
        write_json(METRICS, metrics)
        run.log_summary(metrics)
        run.log_artifact(stage.model)
        run.log_artifact(HISTORY)
        run.log_artifact(PHASE_B)
        run.log_artifact(figures, "figures")
    clear_resume(stage.resume_dir)
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
    training = metrics.get("training", {})
    if "after_features" in training:
        start, after = training.get("start", {}), training["after_features"]
        print("flow_pretrain: per-pixel cost-volume top-1 on held-out generated pairs (chance 1/81 = 0.012): "
              + ", ".join(f"stride {s}: {fmt(start.get(f'heldout_top1_s{s}'), 2)} after the init → "
                          f"{fmt(after.get(f'heldout_top1_s{s}'), 2)} after phase A"
                          for s in stage.chairs.matching_strides))
    print(f"flow_pretrain: {metrics['seconds']} s → {stage.model}")


if __name__ == "__main__":
    run_stage("flow_pretrain", main, sys.argv)
