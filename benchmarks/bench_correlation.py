"""PWC-Lite cost volume and whole-model speed on CPU.

Run: ``python benchmarks/bench_correlation.py [--repeats 5] [--skip-model] [--out file.json]``.

1. Correlation forward + backward at the 1/4 (32 ch, 80×96) and 1/8 (64 ch, 40×48) levels of a 320×384
   input, batch 8 (= both directions of a batch of 4, as in training), 1 thread: the banded-GEMM
   ``correlation`` against the straightforward shift-and-multiply ``correlation_reference`` (what
   ARFlow's ``correlation_native.py`` does), and the peak memory allocated during one forward +
   backward (output and gradients included).
2. The whole model with 2 threads: one 320×384 forward pass at batch 1 (forward flow only, as ARFlow's
   inference; and both directions), and forward + ARFlow census loss + backward of both directions at
   batch 4 — ours against an "ARFlow-like" configuration of the same network (NCHW tensors, the
   shift-and-multiply correlation, one decoder pass per direction).

Prints the machine load (``os.getloadavg``) next to the numbers: other processes sharing the CPU inflate
them. Times are the minimum over ``--repeats`` runs after one warm-up run.
"""

from __future__ import annotations

import argparse
import json
import os
import time

import torch

import f2depth.flow.net.pwclite as pwclite_module
from f2depth.flow.loss import SINTEL_FT, flow_loss
from f2depth.flow.net.correlation import correlation, correlation_reference
from f2depth.flow.net.pwclite import PWCLite


def best_ms(fn, repeats: int) -> float:
    fn()
    best = float("inf")
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best * 1000


def peak_mb(fn) -> float:
    """Peak of the memory allocated by ``fn`` (MB): the running sum of the profiler's allocation and
    free events, in time order."""
    from torch.profiler import ProfilerActivity, profile

    with profile(activities=[ProfilerActivity.CPU], profile_memory=True) as prof:
        fn()
    current = peak = 0
    for event in sorted(prof.events(), key=lambda e: e.time_range.start):
        current += event.self_cpu_memory_usage
        peak = max(peak, current)
    return round(peak / 2**20, 1)


def time_correlation(impl: str, shape: tuple[int, int, int, int], repeats: int) -> dict:
    fn = {"banded_gemm": correlation, "shift_multiply": correlation_reference}[impl]
    g = torch.Generator().manual_seed(0)
    f1 = torch.randn(*shape, generator=g).requires_grad_()
    f2 = torch.randn(*shape, generator=g).requires_grad_()
    grad = torch.randn(shape[0], 81, *shape[2:], generator=g)

    def fwd():
        with torch.no_grad():
            fn(f1, f2)

    def fwd_bwd():
        torch.autograd.grad(fn(f1, f2), (f1, f2), grad)

    return {"forward_ms": round(best_ms(fwd, repeats), 1),
            "forward_backward_ms": round(best_ms(fwd_bwd, repeats), 1),
            "peak_memory_MB": peak_mb(fwd_bwd)}


def bench_correlation(repeats: int) -> dict:
    torch.set_num_threads(1)
    out = {}
    for name, shape in {"1/4": (8, 32, 80, 96), "1/8": (8, 64, 40, 48)}.items():
        row = {impl: time_correlation(impl, shape, repeats) for impl in ("banded_gemm", "shift_multiply")}
        row["speedup_forward_backward"] = round(row["shift_multiply"]["forward_backward_ms"]
                                                / row["banded_gemm"]["forward_backward_ms"], 2)
        out[f"{name} ({'×'.join(map(str, shape))})"] = row
    return out


class ArflowLike(PWCLite):
    """The same network run the way ARFlow's code runs it: NCHW, shift-and-multiply correlation, one
    decoder pass per direction (for the comparison only)."""

    def __init__(self) -> None:
        super().__init__(channels_last=False)

    def forward(self, img1, img2, with_backward=True):
        p1, p2 = self.features(img1), self.features(img2)
        saved = pwclite_module.correlation
        pwclite_module.correlation = correlation_reference
        try:
            up = [torch.nn.functional.interpolate(f * 4, scale_factor=4, mode="bilinear", align_corners=True)
                  for f in self.decode(p1, p2)]
            if not with_backward:
                return up, None
            bw = [torch.nn.functional.interpolate(f * 4, scale_factor=4, mode="bilinear", align_corners=True)
                  for f in self.decode(p2, p1)]
        finally:
            pwclite_module.correlation = saved
        return up, bw


def time_model(model: PWCLite, repeats: int) -> dict:
    g = torch.Generator().manual_seed(0)
    a, b = torch.rand(1, 3, 320, 384, generator=g), torch.rand(1, 3, 320, 384, generator=g)
    a4, b4 = torch.rand(4, 3, 320, 384, generator=g), torch.rand(4, 3, 320, 384, generator=g)
    model.eval()
    with torch.no_grad():
        fw_ms = best_ms(lambda: model(a, b, with_backward=False), repeats)
        both_ms = best_ms(lambda: model(a, b, with_backward=True), repeats)
    model.train()

    def step():
        model.zero_grad(set_to_none=True)
        fw, bw = model(a4, b4, with_backward=True)
        flow_loss(fw, bw, a4, b4, SINTEL_FT)[0].backward()

    return {"forward_b1_ms": round(fw_ms, 1), "forward_both_directions_b1_ms": round(both_ms, 1),
            "train_step_b4_s": round(best_ms(step, max(1, repeats // 2)) / 1000, 2)}


def bench_model(repeats: int) -> dict:
    torch.set_num_threads(2)
    torch.manual_seed(0)
    return {"ours": time_model(PWCLite(), repeats), "arflow_like": time_model(ArflowLike(), repeats)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--skip-model", action="store_true")
    ap.add_argument("--out", default=None, help="also write the results as JSON here")
    args = ap.parse_args()
    res = {"load_before": os.getloadavg()}
    res["correlation_1_thread"] = bench_correlation(args.repeats)
    if not args.skip_model:
        res["model_2_threads_320x384"] = bench_model(args.repeats)
    res["load_after"] = os.getloadavg()
    print(json.dumps(res, indent=2))
    if args.out:
        from f2depth.io import write_json

        write_json(args.out, res)


if __name__ == "__main__":
    main()
