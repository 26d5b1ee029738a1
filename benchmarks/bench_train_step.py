"""One depth-training step (variant `full`: all five losses, frozen PWC-Lite) at batch 4, split into data
loading, flow network, depth/pose forward, losses and backward (+ Adam step), with 1 and 2 threads.

Run: ``python benchmarks/bench_train_step.py [--sizes 96x128 288x384] [--repeats 3] [--threads 1 2]
[--out f.json]``.
Sizes default to the CPU default (``prepare.height/width`` of params.yaml, 96×128) and the paper's
288×384. A seeded prepared set of 8 tuples (smooth random images, block superpixels, 2000 keypoints per
frame) is written to a temporary folder; the networks are randomly initialised. Median of ``--repeats``
steps after one warm-up step.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import cv2
import numpy as np
import torch
from torch.utils.data import default_collate

from f2depth import params as P
from f2depth import threads as f2threads
from f2depth.depth import DepthModel, DepthModelConfig
from f2depth.flow import PWCLite
from f2depth.io import imwrite, write_json, write_text
from f2depth.keypoints import save_keypoints
from f2depth.losses import total_loss
from f2depth.superpixels import scaled_min_area
from f2depth.train.data import DataConfig, TupleDataset
from f2depth.train.loop import depth_optimizer
from f2depth.train.settings import loss_weights
from f2depth.train.step import (
    StepConfig,
    batch_to,
    loss_terms,
    network_forward,
    teacher_forward,
)
from f2depth.train.teacher import FlowTeacher

PARTS = ("data", "flow", "forward", "losses", "backward")
PARAMS = Path(__file__).resolve().parents[1] / "params.yaml"  # the loss weights of L_depth


def write_set(root: Path, hw: tuple[int, int], tuples: int = 8, points: int = 2000, seed: int = 0,
              pairs: bool = False) -> None:
    """A prepared set (docs/formats.md) of ``tuples`` tuples in one scene, and its keypoint file; with
    ``pairs`` also the flow fine-tuning pairs (t, t+1) of all its frames."""
    h, w = hw
    rng = np.random.default_rng(seed)
    K = [[0.85 * w, 0.0, w / 2], [0.0, 0.85 * w, h / 2], [0.0, 0.0, 1.0]]
    write_json(root / "prepared" / "camera.json", {"K": K, "height": h, "width": w})
    coarse = rng.uniform(0, 255, (12, 12 * (w + 8 * tuples) // h + 1, 3)).astype(np.float32)
    wide = cv2.resize(coarse, (w + 8 * (tuples + 2), h), interpolation=cv2.INTER_CUBIC).clip(0, 255)
    frames, rows, kp = [], [], []
    for k in range(tuples + 2):
        fid = f"s_{k:05d}"
        img = wide[:, 8 * k: 8 * k + w].astype(np.uint8)
        imwrite(root / "prepared" / "images" / "s" / f"{fid}.png", img)
        frames.append(f"{fid},s,s/{fid}.ppm,images/s/{fid}.png,")
        xy = [rng.integers(0, w, points), rng.integers(0, h, points), np.zeros(points, int)]
        kp.append(np.stack(xy, axis=1))
    seg = ((np.arange(h)[:, None] // 24) * 100 + np.arange(w)[None, :] // 24).astype(np.uint16)
    for k in range(1, tuples + 1):
        imwrite(root / "prepared" / "segments" / f"s_{k:05d}.png", seg)
        rows.append(f"s_{k:05d},s,s_{k:05d},s_{k - 1:05d},s_{k + 1:05d},segments/s_{k:05d}.png")
    write_text(root / "prepared" / "frames.csv",
               "frame_id,scene,raw_file,image,gt\n" + "\n".join(frames) + "\n")
    write_text(root / "prepared" / "tuples.csv",
               "tuple_id,scene,target,prev,next,segments\n" + "\n".join(rows) + "\n")
    pair_rows = [f"s_{k:05d},s,s_{k:05d},s_{k + 1:05d}" for k in range(tuples + 1)] if pairs else []
    write_text(root / "prepared" / "pairs.csv", "pair_id,scene,frame1,frame2\n" + "".join(
        r + "\n" for r in pair_rows))
    save_keypoints(root / "keypoints" / "train.npz", list(range(tuples + 2)), kp)


def time_step(ds: TupleDataset, model: DepthModel, teacher: FlowTeacher, opt, cfg: StepConfig,
              step: int) -> dict[str, float]:
    t = {}
    t0 = time.perf_counter()
    batch = batch_to(default_collate([ds.item(i, step) for i in range(4)]), "cpu")
    t1 = time.perf_counter()
    flow = teacher_forward(teacher, batch, features=True)
    t2 = time.perf_counter()
    net = network_forward(model, batch)
    t3 = time.perf_counter()
    loss, _ = total_loss(loss_terms(net, batch, flow, cfg), cfg.weights)
    t4 = time.perf_counter()
    opt.zero_grad(set_to_none=True)
    loss.backward()
    opt.step()
    t5 = time.perf_counter()
    t.update(data=t1 - t0, flow=t2 - t1, forward=t3 - t2, losses=t4 - t3, backward=t5 - t4)
    return t


@contextmanager
def depth_step(hw: tuple[int, int]) -> Iterator[Callable[[int], dict[str, float]]]:
    """A seeded prepared set in a temporary folder and a fresh `full` model → ``step(k)`` (the k-th
    training step, timed by part)."""
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        write_set(root, hw)
        ds = TupleDataset(root / "prepared", root / "keypoints" / "train.npz", DataConfig(num_points=3000))
        torch.manual_seed(0)
        model = DepthModel(DepthModelConfig(*hw)).train()
        teacher = FlowTeacher(PWCLite())
        opt = depth_optimizer(model.parameters(), 1e-4)
        cfg = StepConfig(loss_weights(P.load(PARAMS)), min_area=scaled_min_area(*hw))
        yield lambda k: time_step(ds, model, teacher, opt, cfg, k)


def bench(hw: tuple[int, int], threads: int | None, repeats: int) -> dict[str, float]:
    """Median seconds per part over ``repeats`` steps after one warm-up step. ``threads`` None: the
    stages' automatic budget (f2depth.threads), adapted before every step."""
    f2threads.use(threads)
    with depth_step(hw) as step:
        runs = []
        for k in range(repeats + 1):
            f2threads.adapt()
            runs.append(step(k))
    runs = runs[1:]
    out = {p: statistics.median(r[p] for r in runs) for p in PARTS}
    out["total"] = statistics.median(sum(r[p] for p in PARTS) for r in runs)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", nargs="+", default=["96x128", "288x384"])
    ap.add_argument("--threads", nargs="+", type=int, default=[1, 2])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", type=Path, default=None, help="also write the numbers as JSON here")
    args = ap.parse_args()
    results = []
    header = " ".join(f"{p:>9}" for p in (*PARTS, "total"))
    print(f"{'size':>8} {'threads':>7} {header}   (seconds, batch 4)")
    for size in args.sizes:
        hw = tuple(int(v) for v in size.lower().split("x"))
        for n in args.threads:
            r = bench(hw, n, args.repeats)
            results.append({"size": size, "threads": n, **r})
            print(f"{size:>8} {n:>7} " + " ".join(f"{r[p]:9.3f}" for p in (*PARTS, "total")), flush=True)
    if args.out:
        write_json(args.out, results)


if __name__ == "__main__":
    main()
