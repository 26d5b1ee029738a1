"""DVC stage `train_depth@<variant>`: train DepthCNN + PoseCNN for one ablation variant, once per seed.

Usage: python stages/train_depth.py --variant NAME [--params params.yaml] [--no-resume]
       torchrun --nproc_per_node=N stages/train_depth.py --variant NAME   (several GPUs / processes)

Reads `train_depth`, the loss weights (`lambda1`, `lambda2`, `lambda_rigid`, `lambda3`), `data.*` and
`variants.NAME` (its flow model and the loss terms it switches off). Writes models/depth_NAME/{seed<k>.pt,
model.pt (= the first seed's)}, metrics/train_depth/NAME.json and
metrics/train_depth/NAME/{history,validation}.csv (every epoch's losses; the measured epochs' scores). The
models folder is built aside and replaces the old one only when every seed is trained; the resume states
(train_depth.resume_dir) are removed only after every output is written, so a killed run — or one whose
metrics could not be written — resumes from its last epoch checkpoint unless --no-resume is given. Every
output location is checked to be writable before any work. Validation: NYU's labeled test set
(data.nyu_labeled; null: none) and the prepared set's held-out tuples (prepare.val_share;
f2depth.train.heldout), whichever there are. With ground truth in the prepared set (the synthetic default)
every epoch also logs depth accuracy and pose errors on the training tuples (f2depth.train.diagnostics).
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import sys
from collections.abc import Iterator
from pathlib import Path

from f2depth import params as P
from f2depth import threads, tracking
from f2depth.epochs import clear_state, write_history
from f2depth.formats.writable import check_output_folder
from f2depth.io import atomic_dir, write_json
from f2depth.numbers import format_number as fmt
from f2depth.stage import run_stage
from f2depth.train.distributed import cleanup, init_from_env
from f2depth.train.loop import HISTORY_FILES
from f2depth.train.run import resume_states, run_params, train_variant
from f2depth.train.settings import settings_from_params


def main(argv: list[str]) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--variant", required=True)
    ap.add_argument("--params", default=str(P.DEFAULT_PARAMS))
    ap.add_argument("--resume", action=argparse.BooleanOptionalAction, default=True,
                    help="continue from the last epoch checkpoint of an interrupted run (default on)")
    ap.add_argument("--models", default="models", help="folder of models/depth_<variant>")
    ap.add_argument("--metrics", default="metrics/train_depth", help="folder of the metrics and history")
    args = ap.parse_args(argv[1:])
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    params = P.load(args.params)
    settings = settings_from_params(params, args.variant)
    threads.use(P.threads(params), loader_workers=settings.workers)
    out_dir = Path(args.models) / f"depth_{args.variant}"
    metrics_file = Path(args.metrics) / f"{args.variant}.json"
    history_dir = Path(args.metrics) / args.variant
    ctx = init_from_env(settings.device)
    try:
        if ctx.is_main:  # before any work: every output location must take files
            for folder, option in ((out_dir.parent, "--models"), (metrics_file.parent, "--metrics"),
                                   (history_dir, "--metrics"),
                                   (Path(settings.resume_dir), "train_depth.resume_dir")):
                check_output_folder(folder, option)

        runs: dict[int, tracking.StageRun] = {}  # seed → its MLflow run, which logs its model at the end

        @contextlib.contextmanager
        def open_run(seed: int) -> Iterator[tracking.StageRun]:
            with tracking.stage_run("train_depth", params, variant=args.variant,
                                    run_params=run_params(settings, [seed]),
                                    seed=seed if len(settings.seeds) > 1 else None) as run:
                runs[seed] = run
                yield run

        with (atomic_dir(out_dir, "train_depth", owned=True) if ctx.is_main  # DVC's output: DVC removes it
              else contextlib.nullcontext(out_dir)) as build_dir:
            result = train_variant(settings, build_dir, ctx=ctx, open_run=open_run, resume=args.resume)
        if ctx.is_main:
            for name, columns in HISTORY_FILES.items():
                write_history(history_dir / name, result.history, columns)
            write_json(metrics_file, result.metrics)
            for state in resume_states(settings):  # only now: every output is written
                clear_state(state)
            for seed, run in runs.items():  # each model in place: an MLflow logged model, the run's output
                run.log_model(out_dir / f"seed{seed}.pt", f"depth_{args.variant}-seed{seed}",
                              run_params(settings, [seed]))
    finally:
        cleanup(ctx)
    if ctx.is_main:
        m = result.metrics
        tr0, tr1 = m["train_untrained"].get("train_a1"), m["train_trained"].get("train_a1")
        parts = []
        if m["val_trained"]["a1"] is not None:
            parts.append(f"val δ1 {m['val_untrained']['a1']:.3f} untrained → {m['val_trained']['a1']:.3f} "
                         f"trained (constant depth: {fmt(m['val_constant_depth']['a1'])}), AbsRel "
                         f"{m['val_untrained']['abs_rel']:.3f} → {m['val_trained']['abs_rel']:.3f}")
        if "heldout" in m:
            h0, h1, floors = m["heldout_untrained"], m["heldout_trained"], m["heldout"]
            parts.append(f"held-out L_ph {h0['ph']:.4f} → {h1['ph']:.4f} (still camera: "
                         f"{floors['identity_ph']:.4f}, {floors['tuples']} tuples)"
                         + (f", held-out δ1 {h0['a1']:.3f} → {h1['a1']:.3f} (constant depth: "
                            f"{floors['constant_a1']:.3f})" if "a1" in h1 else ""))
        parts.append(f"training frames δ1 {fmt(tr0)} → {fmt(tr1)}")
        if "rigid_epe" in m["train_trained"]:
            epe = m.get("train_flow_epe", {})
            parts.append(f"rigid flow EPE {fmt(m['train_untrained'].get('rigid_epe'), 2)} → "
                         f"{fmt(m['train_trained']['rigid_epe'], 2)} px"
                         + (f" (the teacher's {fmt(epe['teacher'], 2)}, zero flow {fmt(epe['zero_flow'], 2)})"
                            if epe else ""))
        print(f"train_depth[{args.variant}]: {'; '.join(parts)}; {m['seconds_per_epoch']:.1f} s/epoch, "
              f"{m['wall_seconds']:.0f} s ({len(settings.seeds)} seed(s)) → {out_dir}")

if __name__ == "__main__":
    run_stage("train_depth", main, sys.argv)
