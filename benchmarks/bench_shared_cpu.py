"""How much a depth-training step slows down when the CPU is shared: the step of bench_train_step.py
(variant `full`, batch 4) alone and beside busy competing processes, per torch thread count. The figure
of issue 26 is the ratio (beside / alone; goal ≤ 2 with one competitor on this 2-core machine); both
times come from this one process, so the ratio holds on any machine.

Run: ``python benchmarks/bench_shared_cpu.py [--size 96x128] [--threads T ...] [--competitors 1]
[--repeats 3] [--out f.json]``. ``--threads`` defaults to torch's own choice (what every stage uses
today) and 1. A competitor is a Python busy loop (one core's worth of work, like another user's job).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_train_step import bench  # noqa: E402

from f2depth.io import write_json  # noqa: E402

BUSY = "while True:\n    pass\n"


def beside(competitors: int, hw: tuple[int, int], threads: int, repeats: int) -> float:
    """Median step seconds while ``competitors`` busy processes run."""
    procs = [subprocess.Popen([sys.executable, "-c", BUSY]) for _ in range(competitors)]
    try:
        return bench(hw, threads, repeats)["total"]
    finally:
        for p in procs:
            p.kill()
            p.wait()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="96x128")
    ap.add_argument("--threads", nargs="+", type=int, default=[torch.get_num_threads(), 1])
    ap.add_argument("--competitors", type=int, default=1)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", type=Path, default=None, help="also write the numbers as JSON here")
    args = ap.parse_args()
    hw = tuple(int(v) for v in args.size.lower().split("x"))
    print(f"{'threads':>7} {'alone s':>8} {'beside s':>9} {'slowdown':>9}   ({args.competitors} busy "
          f"competitor(s), {args.size}, batch 4)")
    results = []
    for n in dict.fromkeys(args.threads):
        alone = bench(hw, n, args.repeats)["total"]
        shared = beside(args.competitors, hw, n, args.repeats)
        results.append({"threads": n, "alone_s": alone, "beside_s": shared, "slowdown": shared / alone,
                        "competitors": args.competitors, "size": args.size})
        print(f"{n:>7} {alone:8.3f} {shared:9.3f} {shared / alone:8.2f}×", flush=True)
    if args.out:
        write_json(args.out, results)


if __name__ == "__main__":
    main()
