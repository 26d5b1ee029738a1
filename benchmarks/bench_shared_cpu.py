"""How much training slows down when the CPU is shared: a depth-training step (bench_train_step.py, variant
`full`, batch 4) and a flow fine-tuning step (PWC-Lite, the patch loss, batch 4) alone and beside busy
competing processes, per thread setting. The figure of issue 26 is the ratio (beside / alone; goal ≤ 2
with one competitor on a 2-core machine); both times come from this one process, so the ratio holds on
any machine.

Run: ``python benchmarks/bench_shared_cpu.py [--size 96x128] [--threads auto N 1] [--steps depth flow]
[--competitors 1] [--repeats 5] [--out f.json]``. ``auto`` is what every stage does when neither
``threads`` nor ``$OMP_NUM_THREADS`` is set: the usable CPUs, lowered before every step to the cores the
other processes leave free (f2depth.threads.adapt); run it with ``$OMP_NUM_THREADS`` unset. A number
fixes the count. The default compares ``auto``, torch's own count (a fixed count of all cores) and 1. A
competitor is a Python busy loop (one core's worth of work, like another user's job). Every timing
first runs steps for ``--warmup`` seconds, so that the automatic count has measured the others.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_train_step import depth_step, write_set  # noqa: E402

from f2depth import threads as f2threads  # noqa: E402
from f2depth.flow import PWCLite  # noqa: E402
from f2depth.flow.finetune import FinetuneConfig, prepare_batch, train_step  # noqa: E402
from f2depth.flow.finetune_data import FlowPairs, collate  # noqa: E402
from f2depth.flow.net.network import make_optimizer  # noqa: E402
from f2depth.formats.prepared import PreparedSet  # noqa: E402
from f2depth.io import write_json  # noqa: E402
from f2depth.keypoints.store import KeypointFile  # noqa: E402

BUSY = "while True:\n    pass\n"


@contextmanager
def flow_step(hw: tuple[int, int]) -> Iterator[Callable[[int], object]]:
    """A seeded prepared set with pairs and keypoints, a fresh PWC-Lite → ``step(k)``: one update of the
    default fine-tuning (the patch loss, augmentation, batch 4)."""
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        write_set(root, hw, pairs=True)
        ds = PreparedSet(root / "prepared")
        pairs = FlowPairs(ds, ds.pairs, KeypointFile(root / "keypoints" / "train.npz"))
        torch.manual_seed(0)
        model = PWCLite().train()
        cfg = FinetuneConfig()
        opt = make_optimizer(model, cfg)
        gen = torch.Generator().manual_seed(0)

        def step(k: int) -> object:
            items = [pairs[(cfg.batch_size * k + i) % len(pairs)] for i in range(cfg.batch_size)]
            return train_step(model, opt, prepare_batch(collate(items), cfg, gen), cfg)

        yield step


STEPS = {"depth": depth_step, "flow": flow_step}


def seconds_per_step(kind: str, hw: tuple[int, int], threads: int | None, repeats: int,
                     warmup: float) -> float:
    """Median wall seconds of ``repeats`` steps, after at least one step and ``warmup`` seconds of them."""
    f2threads.use(threads)
    with STEPS[kind](hw) as step:
        k, t0 = 0, time.perf_counter()
        while k == 0 or time.perf_counter() - t0 < warmup:
            f2threads.adapt()
            step(k)
            k += 1
        times = []
        for j in range(k, k + repeats):
            f2threads.adapt()
            t = time.perf_counter()
            step(j)
            times.append(time.perf_counter() - t)
    return statistics.median(times)


def beside(competitors: int, measure: Callable[[], float]) -> float:
    """``measure()`` while ``competitors`` busy processes run."""
    procs = [subprocess.Popen([sys.executable, "-c", BUSY]) for _ in range(competitors)]
    try:
        return measure()
    finally:
        for p in procs:
            p.kill()
            p.wait()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="96x128")
    ap.add_argument("--threads", nargs="+", default=["auto", str(torch.get_num_threads()), "1"],
                    help="'auto' (the stages' automatic count) or a fixed count, one or more")
    ap.add_argument("--steps", nargs="+", choices=sorted(STEPS), default=["depth", "flow"])
    ap.add_argument("--competitors", type=int, default=1)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--warmup", type=float, default=4.0, help="seconds of steps before timing")
    ap.add_argument("--out", type=Path, default=None, help="also write the numbers as JSON here")
    args = ap.parse_args()
    if "auto" in args.threads and os.environ.get("OMP_NUM_THREADS"):
        sys.exit("bench_shared_cpu: 'auto' needs $OMP_NUM_THREADS unset (it fixes the count); "
                 "run `env -u OMP_NUM_THREADS python benchmarks/bench_shared_cpu.py`")
    hw = tuple(int(v) for v in args.size.lower().split("x"))
    print(f"{'step':>5} {'threads':>7} {'alone s':>8} {'beside s':>9} {'slowdown':>9}   "
          f"({args.competitors} busy competitor(s), {args.size}, batch 4)")
    results = []
    for kind in args.steps:
        for setting in dict.fromkeys(args.threads):
            n = None if setting == "auto" else int(setting)
            alone = seconds_per_step(kind, hw, n, args.repeats, args.warmup)
            shared = beside(args.competitors,
                            lambda: seconds_per_step(kind, hw, n, args.repeats, args.warmup))  # noqa: B023
            results.append({"step": kind, "threads": setting, "alone_s": alone, "beside_s": shared,
                            "slowdown": shared / alone, "competitors": args.competitors, "size": args.size})
            print(f"{kind:>5} {setting:>7} {alone:8.3f} {shared:9.3f} {shared / alone:8.2f}×", flush=True)
    if args.out:
        write_json(args.out, results)


if __name__ == "__main__":
    main()
