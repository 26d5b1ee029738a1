"""Depth inference (DepthCNN, ResNet-18, 288×384, batch 1) against this machine's FLOP bound (issue 26).

The bound is measured, not assumed: every convolution of the depth network is timed alone (the faster of
NCHW and channels-last, best of ``--repeats``), the best throughput among them (GFLOP/s, a FLOP = a
multiply or an add) is this machine's convolution speed, and ``bound = network FLOPs / that speed`` — the
time the network would take if every layer ran like its best convolution and nothing else cost anything.
Each path's ratio is its time ÷ the bound (1.0 = at the bound):

- ``training_graph``: ``DepthModel.predict_depth`` as trained (BatchNorm layers, NCHW);
- ``inference``: what ``f2depth predict`` runs (``TorchBackend``: BatchNorm folded, channels-last);
- ``onnx``: the ONNX export run by onnxruntime (when installed).

The inference path's depth is compared with the training graph's (max relative difference; goal 1e-5).
Random weights and BatchNorm statistics: speed does not depend on them.

Run: ``python benchmarks/bench_inference.py [--threads 1] [--repeats 7] [--rounds 3] [--out file.json]``.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import torch  # noqa: E402
from torch import nn  # noqa: E402

from f2depth.depth import DepthModel, DepthModelConfig  # noqa: E402
from f2depth.inference.backends import OnnxBackend, TorchBackend  # noqa: E402
from f2depth.io import write_json  # noqa: E402

NET_HW = (288, 384)


def best_time(fn, repeats: int) -> float:
    """The fastest of ``repeats`` calls (s), after one warm-up call."""
    fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def conv_layers(model: DepthModel, x: torch.Tensor) -> list[tuple[nn.Conv2d, torch.Tensor, float]]:
    """Each convolution of the depth path with its input and FLOPs (2 · MACs) at input ``x``."""
    found = []

    def hook(conv, inputs, output):
        k = conv.kernel_size[0] * conv.kernel_size[1] * conv.in_channels // conv.groups
        found.append((conv, inputs[0].detach().clone(), 2.0 * k * output.numel()))

    convs = [m for part in (model.depth_encoder, model.depth_decoder) for m in part.modules()
             if isinstance(m, nn.Conv2d)]
    handles = [m.register_forward_hook(hook) for m in convs]
    with torch.inference_mode():
        model.predict_depth(x)
    for h in handles:
        h.remove()
    return found


def conv_speed(layers, repeats: int) -> tuple[float, list[dict]]:
    """The best GFLOP/s of the network's convolutions run alone, and each layer's."""
    rows = []
    with torch.inference_mode():
        for conv, inp, flops in layers:
            seconds = best_time(lambda c=conv, i=inp: c(i), repeats)
            cl_conv = nn.Conv2d(conv.in_channels, conv.out_channels, conv.kernel_size, conv.stride,
                                conv.padding, bias=conv.bias is not None)
            cl_conv = cl_conv.to(memory_format=torch.channels_last)
            cl_in = inp.contiguous(memory_format=torch.channels_last)
            seconds = min(seconds, best_time(lambda c=cl_conv, i=cl_in: c(i), repeats))
            rows.append({"shape": f"{conv.in_channels}→{conv.out_channels} k{conv.kernel_size[0]} "
                                  f"s{conv.stride[0]} {tuple(inp.shape[-2:])}", "gflops": flops / 1e9,
                         "gflop_per_s": flops / seconds / 1e9})
    return max(r["gflop_per_s"] for r in rows), rows


def randomised(model: DepthModel) -> DepthModel:
    """BatchNorm statistics away from the identity, so folding them is really exercised."""
    g = torch.Generator().manual_seed(1)
    with torch.no_grad():
        for m in model.modules():
            if isinstance(m, nn.BatchNorm2d):
                m.running_mean.copy_(torch.rand(m.num_features, generator=g) - 0.5)
                m.running_var.copy_(0.5 + torch.rand(m.num_features, generator=g))
                m.weight.copy_(0.5 + torch.rand(m.num_features, generator=g))
                m.bias.copy_(0.2 * torch.rand(m.num_features, generator=g) - 0.1)
    return model.eval()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--rounds", type=int, default=3,
                    help="interleaved rounds of (every convolution alone, every path); each figure is its "
                         "best over the rounds, so a passing slowdown of the machine cannot fall on one side "
                         "of a ratio")
    ap.add_argument("--out", default=None, help="also write the numbers to this JSON file")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    model = randomised(DepthModel(DepthModelConfig(height=NET_HW[0], width=NET_HW[1])))
    x = torch.rand(1, 3, *NET_HW, generator=torch.Generator().manual_seed(2))
    layers = conv_layers(model, x)
    flops = sum(f for _, _, f in layers)
    backend = TorchBackend(model)
    paths = {"training_graph": lambda: model.predict_depth(x), "inference": lambda: backend.depth(x)}
    with torch.inference_mode():
        reference = model.predict_depth(x)
        rel = float(((backend.depth(x) - reference).abs() / reference.abs()).max())
    with tempfile.TemporaryDirectory() as tmp:
        try:
            from f2depth.inference.export import export_onnx

            export_onnx(model, Path(tmp) / "depth.onnx")
            onnx = OnnxBackend(Path(tmp) / "depth.onnx", threads=args.threads)
            paths["onnx"] = lambda: onnx.depth(x)
        except ImportError as exc:
            print(f"onnx: skipped ({exc})")
        rows: list[dict] = []
        times = dict.fromkeys(paths, float("inf"))
        for _ in range(args.rounds):
            _, now = conv_speed(layers, args.repeats)
            rows = [max(a, b, key=lambda r: r["gflop_per_s"]) for a, b in zip(rows, now)] if rows else now
            with torch.inference_mode():
                for k, fn in paths.items():
                    times[k] = min(times[k], best_time(fn, args.repeats))
    speed = max(r["gflop_per_s"] for r in rows)
    bound = flops / (speed * 1e9)
    result = {"threads": args.threads, "rounds": args.rounds, "input_hw": list(NET_HW),
              "network_gflops": flops / 1e9,
              "conv_gflop_per_s_best": speed, "bound_ms": 1e3 * bound,
              "ms": {k: 1e3 * v for k, v in times.items()},
              "ratio_to_bound": {k: v / bound for k, v in times.items()},
              "inference_max_relative_difference": rel, "layers": rows}
    print(f"DepthCNN 288×384, {args.threads} thread(s): {flops / 1e9:.1f} GFLOP; best convolution "
          f"{speed:.0f} GFLOP/s → bound {1e3 * bound:.0f} ms")
    for k, v in times.items():
        print(f"  {k:15s} {1e3 * v:7.1f} ms  = {v / bound:.2f}× the bound")
    print(f"  inference vs training graph: max relative difference {rel:.1e} (goal ≤ 1e-5)")
    if args.out:
        write_json(args.out, result)


if __name__ == "__main__":
    main()
