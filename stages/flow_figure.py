"""DVC stage `flow_figure`: the paper's Figure 8 for our flow models — RGB | pretrained | fine-tuned
`full` | fine-tuned `patch` | ground truth — on a few held-out synthetic pairs.

Usage: python stages/flow_figure.py [params.yaml]

Pairs: `flow_figure.pairs` of the flow_finetune EPE test pairs (spread evenly); writes `flow_figure.out`.
A prepared set without ground truth (your own video, docs/ingest.md) gets the predictions on its
held-out pairs (all pairs without held-out scenes), and no ground-truth column.
"""

import sys
from dataclasses import dataclass, field

from f2depth import params as P
from f2depth import threads, tracking
from f2depth.flow.figures import comparison_rows, prediction_rows, render_flow_comparison
from f2depth.flow.finetune_data import gt_pairs, image_pairs, split_pairs, spread
from f2depth.flow.net.checkpoint import load_flow_model
from f2depth.formats.prepared import PreparedSet
from f2depth.stage import run_stage

TITLES = {"full": "Fine-tuned full", "patch": "Fine-tuned patch (F²Depth)"}


@dataclass(frozen=True)
class FigureParams:
    """The ``flow_figure`` section."""

    pairs: int = field(metadata={"min": 1})
    out: str


def config_from_params(p: dict) -> FigureParams:
    return P.section(p, "flow_figure", FigureParams)


def main(argv: list[str]) -> None:
    p = P.load(argv[1] if len(argv) > 1 else P.DEFAULT_PARAMS)
    threads.use(P.threads(p))
    cfg = config_from_params(p)
    holdout = P.value(p, "flow_finetune.holdout_scenes", int, min=0)
    losses = P.value(p, "flow_finetune.losses", tuple[str, ...])
    template, pretrained = P.value(p, "flow_finetune.model", str), P.value(p, "flow_finetune.pretrained", str)
    device = P.device(p)
    ds = PreparedSet(P.get(p, "data.prepared"))
    split = split_pairs(ds, holdout)
    pairs = list(gt_pairs(ds, split.test, limit=cfg.pairs))
    models = {"Pretrained": load_flow_model(pretrained)}
    for loss in ("full", "patch"):
        if loss in losses:
            models[TITLES[loss]] = load_flow_model(template.format(loss=loss))
    out = cfg.out
    if pairs:
        rows = comparison_rows(models, pairs, device)
    else:
        print(f"flow_figure: {ds.root} has no held-out pairs with ground truth; drawing the predictions only")
        test_scenes = set(split.test_scenes)
        held = [q for q in ds.pairs if q.scene in test_scenes] or list(ds.pairs)
        rows = prediction_rows(models, image_pairs(ds, spread(held, cfg.pairs)), device)
    render_flow_comparison(rows, out)
    epe = {f"epe.{row.pair_id}.{title}": e[0]
           for row in rows for title, e in row.epe.items() if e[0] is not None}
    tracking.mirror_stage("flow_figure", p, epe, artifacts=(out,))
    for row in rows:
        print(f"flow_figure {row.pair_id}: " + ", ".join(
            f"{t} EPE {e[0]:.3f}" for t, e in row.epe.items() if e[0] is not None))
    print(f"flow_figure: {len(rows)} pairs × {len(models)} models → {out}")


if __name__ == "__main__":
    run_stage("flow_figure", main, sys.argv)
