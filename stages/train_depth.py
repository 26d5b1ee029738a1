"""DVC stage `train_depth@<variant>`: train DepthCNN + PoseCNN for one ablation variant, once per seed.

Usage: python stages/train_depth.py --variant NAME [--params params.yaml] [--no-resume]
       torchrun --nproc_per_node=N stages/train_depth.py --variant NAME   (several GPUs / processes)

Reads `train_depth`, `loss_weights`, `data.*` and `variants.NAME` (its flow model and the loss terms it
switches off). Writes models/depth_NAME/{seed<k>.pt, model.pt (= the first seed's)},
metrics/train_depth/NAME.json and metrics/train_depth/NAME/history.csv. A killed run resumes from its
last epoch checkpoint unless --no-resume is given. With ground truth in the prepared set (the
synthetic default) every epoch also logs depth accuracy and pose errors on the training tuples
(f2depth.train.diagnostics).
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from f2depth import params as P
from f2depth.losses import NonFiniteLossError
from f2depth.numbers import format_number as fmt
from f2depth.stage import run_stage
from f2depth.train.distributed import cleanup, init_from_env
from f2depth.train.run import train_variant
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
    ctx = init_from_env(settings.device)
    metrics_dir = Path(args.metrics)
    try:
        m = train_variant(
            settings, out_dir=Path(args.models) / f"depth_{args.variant}",
            metrics_file=metrics_dir / f"{args.variant}.json",
            history_file=metrics_dir / args.variant / "history.csv",
            ctx=ctx, params=params, resume=args.resume,
        )  # fmt: skip
    except NonFiniteLossError as exc:
        sys.exit(f"train_depth[{args.variant}]: {exc}")
    finally:
        cleanup(ctx)
    if ctx.is_main:
        floor = m["val_constant_depth"]["a1"]
        tr0, tr1 = m["train_untrained"].get("train_a1"), m["train_trained"].get("train_a1")
        print(f"train_depth[{args.variant}]: val δ1 {m['val_untrained']['a1']:.3f} untrained → "
              f"{m['val_trained']['a1']:.3f} trained (constant depth: {fmt(floor)}), AbsRel "
              f"{m['val_untrained']['abs_rel']:.3f} → {m['val_trained']['abs_rel']:.3f}; training frames δ1 "
              f"{fmt(tr0)} → {fmt(tr1)}; {m['seconds_per_epoch']:.1f} s/epoch, "
              f"{m['wall_seconds']:.0f} s ({len(settings.seeds)} seed(s)) → "
              f"{args.models}/depth_{args.variant}")



if __name__ == "__main__":
    run_stage("train_depth", main, sys.argv)
