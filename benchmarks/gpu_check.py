"""The paper's scale on one GPU, checked and measured in one run: CUDA correctness first, then throughput,
memory and a projected `make paper` wall time. Writes ``gpu_check.json`` and ``gpu_check.md`` to ``--out``.

Run: ``python benchmarks/gpu_check.py`` (= ``make gpu-check``: CUDA, 288×384, depth batch 12, flow batch 20)
or ``python benchmarks/gpu_check.py --device cpu --quick`` (tiny sizes; what CI runs).

1. Correctness (any failure is listed and makes the exit status 1):
   * one depth training step of every variant of params.yaml (its loss weights; a random frozen PWC-Lite
     for the variants with a flow model) without and with mixed precision: finite terms, and the mixed
     precision loss equals the float32 loss of the same weights and batch to ``--amp-rtol`` (variants
     with equal weights and the same random teacher, e.g. ``full`` and ``flow_pretrained``, share one
     run: their rows name it in ``same_as``);
   * one flow fine-tuning step, patch and full loss, without and with mixed precision (same checks);
   * the correlation layer: on CUDA forward and backward against the CPU result; on a CPU against the
     plain shift-and-multiply reference;
   * ``torchrun`` (``python -m torch.distributed.run --standalone --nproc_per_node=1``) of a one-epoch
     ``f2depth.train.loop.fit`` with the NCCL backend (gloo on a CPU) and a DDP-wrapped model.
2. Throughput (CUDA events / synchronised clocks after ``--warmup`` untimed steps, median of
   ``--repeats``): a ``train_depth`` step of ``full`` with and without AMP (steps/s, peak memory), the frozen
   teacher's share of that step, a flow fine-tuning step, data loading's share of a real loader + step loop
   with ``--workers`` processes, and inference latency at batch 1 with and without flip post-processing.
   ``--compile`` (``torch.compile`` of the depth model) and ``--channels-last`` are parameters.
3. Projection: ``flow_epochs·⌈N/flow_batch⌉ / flow steps/s + depth_epochs·⌊N/depth_batch⌋ / depth
   steps/s`` (+ the data-loading stall measured in 2) with N = 21,483 training images (the paper §4.1),
   for the mixed precision setting of params.yaml's `paper` profile (float32) and for AMP.

The data is a seeded synthetic prepared set written to a temporary folder; the networks are randomly
initialised (speed does not depend on the weights). Goals (issue #18): inference ≤ 5 ms at 288×384, the
teacher ≤ 25 % of a depth step, data loading ≤ 10 %, `make paper` within one day on one GPU.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

import torch
from torch.utils.data import DataLoader, default_collate

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_train_step import write_set  # noqa: E402  (the benchmarks' shared synthetic prepared set)

from f2depth import params as P  # noqa: E402
from f2depth.depth import DepthModel, DepthModelConfig  # noqa: E402
from f2depth.eval.suite import model_disparity  # noqa: E402
from f2depth.eval.timing import time_inference  # noqa: E402
from f2depth.flow import PWCLite  # noqa: E402
from f2depth.flow import finetune as ft  # noqa: E402
from f2depth.flow.finetune_data import FlowPairs, collate  # noqa: E402
from f2depth.flow.net.correlation import correlation, correlation_reference  # noqa: E402
from f2depth.formats.prepared import PreparedSet  # noqa: E402
from f2depth.io import write_json, write_text  # noqa: E402
from f2depth.keypoints.store import KeypointFile  # noqa: E402
from f2depth.precision import grad_scaler  # noqa: E402
from f2depth.superpixels import scaled_min_area  # noqa: E402
from f2depth.train.data import DataConfig, TupleDataset  # noqa: E402
from f2depth.train.settings import loss_weights, settings_from_params  # noqa: E402
from f2depth.train.step import (  # noqa: E402
    StepConfig,
    batch_to,
    teacher_forward,
    train_step,
)
from f2depth.train.teacher import FlowTeacher  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
PAPER_TRAIN_IMAGES = 21483  # NYU Depth V2 training images (the paper §4.1)


# ---- helpers -------------------------------------------------------------------------------------

def sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def timed(fn: Callable[[], Any], device: torch.device, repeats: int, warmup: int) -> float:
    """Median seconds of ``fn()`` over ``repeats`` runs after ``warmup`` untimed ones (synchronised)."""
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        sync(device)
        t0 = time.perf_counter()
        fn()
        sync(device)
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def mb(value: float | None) -> str:
    return "—" if value is None else f"{value:.0f} MB"


def peak_mb(device: torch.device) -> float | None:
    return round(torch.cuda.max_memory_allocated(device) / 2**20, 1) if device.type == "cuda" else None


def reset_peak(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.empty_cache()
        torch.cuda.reset_peak_memory_stats(device)


def finite(logs: dict[str, float]) -> bool:
    return all(math.isfinite(v) for v in logs.values())


def rel_diff(a: float, b: float) -> float:
    return abs(a - b) / max(abs(b), 1e-12)


class Checks:
    def __init__(self) -> None:
        self.rows: list[dict[str, Any]] = []

    def add(self, name: str, ok: bool, **info: Any) -> None:
        self.rows.append({"check": name, "ok": bool(ok), **info})
        print(f"  [{'ok' if ok else 'FAIL'}] {name} {json.dumps(info, default=str)}", flush=True)

    @property
    def failed(self) -> list[str]:
        return [r["check"] for r in self.rows if not r["ok"]]


# ---- data ----------------------------------------------------------------------------------------

def make_data(root: Path, hw: tuple[int, int], items: int) -> tuple[TupleDataset, FlowPairs]:
    write_set(root, hw, tuples=items, points=2000, pairs=True)
    prepared = PreparedSet(root / "prepared")
    kp = root / "keypoints" / "train.npz"
    return (TupleDataset(prepared, kp, DataConfig(num_points=3000)),
            FlowPairs(prepared, list(prepared.pairs), KeypointFile(kp)))


def depth_batch(ds: TupleDataset, n: int, device: torch.device, channels_last: bool
                ) -> dict[str, torch.Tensor]:
    batch = batch_to(default_collate([ds.item(i % len(ds), 0) for i in range(n)]), device)
    if channels_last:
        batch = {k: v.contiguous(memory_format=torch.channels_last) if v.dim() == 4 else v
                 for k, v in batch.items()}
    return batch


def flow_batch(ds: FlowPairs, n: int, cfg: ft.FinetuneConfig) -> dict[str, torch.Tensor]:
    batch = collate([ds[i % len(ds)] for i in range(n)])
    return ft.prepare_batch(batch, cfg, torch.Generator().manual_seed(0))


# ---- 1. correctness ------------------------------------------------------------------------------

def check_depth_variants(checks: Checks, params: dict, ds: TupleDataset, device: torch.device,
                         batch_size: int, rtol: float) -> None:
    h, w = ds.prepared.hw
    batch = depth_batch(ds, batch_size, device, channels_last=False)
    teacher = FlowTeacher(PWCLite(), device)
    ran: dict[tuple, tuple[str, list[dict[str, Any]]]] = {}  # (weights, teacher or not) → variant, rows
    for variant in params["variants"]:
        s = settings_from_params(params, variant)
        key = (tuple(sorted(s.weights.items())), s.flow_model is not None)
        if key in ran:  # the same loss on the same batch and random teacher as an earlier variant
            first, rows = ran[key]
            for row in rows:
                info = {k: v for k, v in row.items() if k not in ("check", "ok")}
                checks.add(row["check"].replace(f" {first} ", f" {variant} ", 1), row["ok"], same_as=first,
                           **info)
            continue
        start = len(checks.rows)
        torch.manual_seed(0)
        base = DepthModel(DepthModelConfig(h, w))
        state = {k: v.clone() for k, v in base.state_dict().items()}
        losses = {}
        for amp in (False, True):
            model = DepthModel(DepthModelConfig(h, w)).to(device).train()
            model.load_state_dict(state)
            cfg = StepConfig(s.weights, scaled_min_area(h, w), amp=amp)
            tch = teacher if s.flow_model else None
            opt = torch.optim.Adam(model.parameters(), lr=1e-4)
            scaler = grad_scaler(device, amp)
            loss, logs = train_step(model, opt, batch, tch, cfg, scaler)
            losses[amp] = float(loss)  # computed before the update: the same weights and batch for both
            checks.add(f"depth step {variant} {'amp' if amp else 'fp32'}", finite(logs), total=logs["total"])
        d = rel_diff(losses[True], losses[False])
        checks.add(f"depth loss {variant} amp vs fp32", d <= rtol, rel_diff=d, fp32=losses[False],
                   amp=losses[True])
        ran[key] = (variant, checks.rows[start:])


def check_flow_steps(checks: Checks, ds: FlowPairs, device: torch.device, batch_size: int,
                     rtol: float) -> None:
    for loss_name in ft.LOSSES:
        losses = {}
        for amp in (False, True):
            cfg = ft.FinetuneConfig(loss=loss_name, batch_size=batch_size, w_scales=(1.0, 1.0, 1.0, 1.0, 0.0),
                                    backward=True, occlusion="range_map", amp=amp)
            torch.manual_seed(0)
            model = PWCLite().to(device).train()
            batch = flow_batch(ds, batch_size, cfg)
            stats = ft.train_step(model, ft.make_optimizer(model, cfg), batch, cfg, device,
                                  grad_scaler(device, cfg.amp))
            ok = stats is not None and finite(stats)
            losses[amp] = stats["loss"] if ok else math.nan  # computed before the update
            checks.add(f"flow step {loss_name} {'amp' if amp else 'fp32'}", ok,
                       loss=None if stats is None else stats["loss"])
        d = rel_diff(losses[True], losses[False])
        checks.add(f"flow loss {loss_name} amp vs fp32", d <= rtol, rel_diff=d, fp32=losses[False],
                   amp=losses[True])


def check_correlation(checks: Checks, device: torch.device) -> None:
    g = torch.Generator().manual_seed(0)
    f1, f2 = (torch.randn(2, 32, 40, 48, generator=g) for _ in range(2))
    grad = torch.randn(2, 81, 40, 48, generator=g)

    def run(fn, dev):
        a, b = f1.to(dev).requires_grad_(), f2.to(dev).requires_grad_()
        out = fn(a, b)
        ga, gb = torch.autograd.grad(out, (a, b), grad.to(dev))
        return out.detach().cpu(), ga.cpu(), gb.cpu()

    ref = run(correlation_reference if device.type == "cpu" else correlation, torch.device("cpu"))
    got = run(correlation, device)
    err = max(float((x - y).abs().max() / y.abs().max().clamp_min(1e-12)) for x, y in zip(got, ref))
    what = "CPU shift-and-multiply reference" if device.type == "cpu" else "CPU result"
    checks.add(f"correlation fwd+bwd on {device.type} vs {what}", err <= 1e-4, max_rel_err=err)


def check_torchrun(checks: Checks, args: argparse.Namespace) -> None:
    cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node=1", __file__,
           "--ddp-worker", "--device", args.device, "--size", args.size, "--depth-batch", "2"]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=600,
                         env={**os.environ, "F2DEPTH_MLFLOW": "0", "OMP_NUM_THREADS": "1"})
    line = next((x for x in res.stdout.splitlines()[::-1] if x.startswith("{")), "{}")
    info = json.loads(line)
    want = "nccl" if args.device.startswith("cuda") else "gloo"
    ok = res.returncode == 0 and info.get("backend") == want and info.get("ddp") and info.get("finite")
    checks.add(f"torchrun world size 1, {want}, DDP, one epoch of fit", bool(ok), **info,
               **({} if ok else {"stderr": res.stderr[-2000:]}))


def ddp_worker(args: argparse.Namespace) -> None:
    """Inside torchrun: a process group at world size 1, a DDP-wrapped model, one epoch of ``fit``."""
    import torch.distributed as dist

    from f2depth.train.distributed import cleanup, init_from_env
    from f2depth.train.loop import LoopConfig, fit
    from f2depth.train.schedule import LRSchedule

    ctx = init_from_env(args.device)
    hw = parse_size(args.size)
    with tempfile.TemporaryDirectory() as tmp:
        ds, _ = make_data(Path(tmp), hw, 4)
        model = DepthModel(DepthModelConfig(*hw))
        captured = {}

        def on_epoch(row):
            captured.update(row)

        weights = loss_weights(P.load(args.params))  # full's: every term on
        fit(model, ds, FlowTeacher(PWCLite(), ctx.device), StepConfig(weights, scaled_min_area(*hw)),
            LoopConfig(1, args.depth_batch, LRSchedule.scaled((1e-4,), (1,), 1), workers=0, sync_bn=True,
                       val_every=1, state_every=1, flow_fade_epochs=None, progress=False),
            ctx=ctx, on_epoch=on_epoch)
    total = captured.get("total", math.nan)
    print(json.dumps({"backend": dist.get_backend() if dist.is_initialized() else None,
                      "ddp": ctx.distributed, "finite": math.isfinite(total), "total": total}))
    cleanup(ctx)


# ---- 2. throughput -------------------------------------------------------------------------------

def measure_depth(ds: TupleDataset, device: torch.device, args: argparse.Namespace) -> dict[str, Any]:
    h, w = ds.prepared.hw
    batch = depth_batch(ds, args.depth_batch, device, args.channels_last)
    teacher = FlowTeacher(PWCLite(), device)
    if args.channels_last:
        teacher.net.to(memory_format=torch.channels_last)
    out: dict[str, Any] = {}
    for amp in (False, True):
        torch.manual_seed(0)
        model = DepthModel(DepthModelConfig(h, w)).to(device).train()
        if args.channels_last:
            model = model.to(memory_format=torch.channels_last)
        net = torch.compile(model) if args.compile else model
        opt = torch.optim.Adam(model.parameters(), lr=1e-4)
        cfg = StepConfig(args.weights, scaled_min_area(h, w), amp=amp)
        scaler = grad_scaler(device, amp)
        reset_peak(device)
        step = timed(partial(train_step, net, opt, batch, teacher, cfg, scaler), device, args.repeats,
                     args.warmup)
        mem = peak_mb(device)

        t_teacher = timed(partial(teacher_forward, teacher, batch, True, amp), device, args.repeats,
                          args.warmup)
        out["amp" if amp else "fp32"] = {"step_s": step, "steps_per_s": 1.0 / step, "peak_mb": mem,
                                         "teacher_s": t_teacher, "teacher_share": t_teacher / step}
    return out


def measure_data_share(ds: TupleDataset, device: torch.device, args: argparse.Namespace, step_s: float
                       ) -> dict[str, Any]:
    """Data loading's share of a real loop: the loop of ``steps`` batches from a DataLoader with ``workers``
    processes, each followed by a step-length wait on the device, against ``steps × step`` alone."""
    steps = max(3, args.repeats)
    loader = DataLoader(ds, batch_size=args.depth_batch, shuffle=True, num_workers=args.workers,
                        pin_memory=device.type == "cuda", persistent_workers=args.workers > 0)
    it = iter(loader)
    next(it)  # start-up of the workers is not per-step cost
    t0 = time.perf_counter()
    n = 0
    while n < steps:
        try:
            batch = next(it)
        except StopIteration:
            it = iter(loader)
            continue
        batch_to(batch, device)
        time.sleep(step_s)  # stands for the step: workers prefetch meanwhile, as in training
        n += 1
    sync(device)
    loop = time.perf_counter() - t0
    stall = max(0.0, loop - steps * step_s) / steps
    return {"workers": args.workers, "stall_s_per_step": stall, "share": stall / (stall + step_s)}


def measure_flow(ds: FlowPairs, device: torch.device, args: argparse.Namespace) -> dict[str, Any]:
    out = {}
    for amp in (False, True):
        cfg = ft.FinetuneConfig(loss="patch", batch_size=args.flow_batch, w_scales=(1.0, 1.0, 1.0, 1.0, 0.0),
                                backward=True, occlusion="forward_backward", amp=amp)
        torch.manual_seed(0)
        model = PWCLite().to(device).train()
        opt, scaler = ft.make_optimizer(model, cfg), grad_scaler(device, cfg.amp)
        batch = flow_batch(ds, args.flow_batch, cfg)
        reset_peak(device)
        step = timed(partial(ft.train_step, model, opt, batch, cfg, device, scaler), device, args.repeats,
                     args.warmup)
        out["amp" if amp else "fp32"] = {"step_s": step, "steps_per_s": 1.0 / step,
                                         "peak_mb": peak_mb(device)}
    return out


def measure_inference(device: torch.device, hw: tuple[int, int], args: argparse.Namespace) -> dict[str, Any]:
    torch.manual_seed(0)
    model = DepthModel(DepthModelConfig(*hw, upsample_mode="bilinear")).to(device).eval()
    if args.channels_last:
        model = model.to(memory_format=torch.channels_last)
    predict = model_disparity(torch.compile(model) if args.compile else model)
    reps, warm = max(args.repeats, 20), max(args.warmup, 5)
    return {pp: time_inference(predict, height=hw[0], width=hw[1], post_process=pp == "pp", repeats=reps,
                               warmup=warm, device=device)["ms_median"] for pp in ("no_pp", "pp")}


# ---- 3. projection and report --------------------------------------------------------------------

def project(depth: dict, flow: dict, data_share: float, args: argparse.Namespace) -> dict[str, Any]:
    n = args.train_images
    flow_steps = args.flow_epochs * math.ceil(n / args.flow_batch)
    depth_steps = args.depth_epochs * (n // args.depth_batch)
    out = {"train_images": n, "flow_steps": flow_steps, "depth_steps": depth_steps}
    for mode in ("fp32", "amp"):
        flow_h = flow_steps * flow[mode]["step_s"] / 3600
        depth_h = depth_steps * depth[mode]["step_s"] / (1 - data_share) / 3600
        out[mode] = {"flow_finetune_h": flow_h, "train_depth_h_per_variant": depth_h,
                     "full_only_h": flow_h + depth_h,
                     "all_variants_h": 2 * flow_h + len(args.variants) * depth_h}
    return out


def markdown(doc: dict) -> str:
    p, d, f = doc["settings"], doc["depth_step"], doc["flow_step"]
    inf, pr, data = doc["inference_ms"], doc["projection"], doc["data_loading"]
    lines = [f"# GPU check: {doc['device']['name']}", "",
             f"torch {doc['device']['torch']}, {p['size']}, depth batch {p['depth_batch']}, flow batch "
             f"{p['flow_batch']}, compile {p['compile']}, channels_last {p['channels_last']}, "
             f"{doc['seconds']:.0f} s.", "",
             "| check | result |", "|---|---|"]
    lines += [f"| {c['check']} | {'ok' if c['ok'] else '**FAIL**'} |" for c in doc["checks"]]
    lines += ["", "| measurement | fp32 | AMP | goal |", "|---|---|---|---|",
              f"| train_depth step (full) | {d['fp32']['steps_per_s']:.2f} steps/s | "
              f"{d['amp']['steps_per_s']:.2f} steps/s | |",
              f"| train_depth peak memory | {mb(d['fp32']['peak_mb'])} | {mb(d['amp']['peak_mb'])} | |",
              f"| teacher share of a depth step | {d['fp32']['teacher_share']:.0%} | "
              f"{d['amp']['teacher_share']:.0%} | ≤ 25 % |",
              f"| data loading share ({data['workers']} workers) | {data['share']:.0%} | | ≤ 10 % |",
              f"| flow fine-tuning step (patch) | {f['fp32']['steps_per_s']:.2f} steps/s | "
              f"{f['amp']['steps_per_s']:.2f} steps/s | |",
              f"| flow fine-tuning peak memory | {mb(f['fp32']['peak_mb'])} | {mb(f['amp']['peak_mb'])} | |",
              f"| inference, batch 1 | {inf['no_pp']:.2f} ms | | ≤ 5 ms |",
              f"| inference with PP | {inf['pp']:.2f} ms | | |",
              f"| projected `make paper`, `full` only | {pr['fp32']['full_only_h']:.1f} h | "
              f"{pr['amp']['full_only_h']:.1f} h | ≤ 24 h |",
              f"| projected `make paper`, every variant | {pr['fp32']['all_variants_h']:.1f} h | "
              f"{pr['amp']['all_variants_h']:.1f} h | |", "",
              f"Projection: {pr['flow_steps']} flow steps and {pr['depth_steps']} depth steps per variant "
              f"over {pr['train_images']} images; evaluation and validation not included."]
    return "\n".join(lines) + "\n"


def parse_size(text: str) -> tuple[int, int]:
    h, w = (int(v) for v in text.lower().split("x"))
    return h, w


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cuda")
    ap.add_argument("--size", default=None, help="HxW of training (default 288x384; --quick: 64x64)")
    ap.add_argument("--depth-batch", type=int, default=None, help="default 12 (--quick: 2)")
    ap.add_argument("--flow-batch", type=int, default=None, help="default 20 (--quick: 2)")
    ap.add_argument("--workers", type=int, default=None, help="data-loader processes for the data share "
                    "(default 4; --quick: 1)")
    ap.add_argument("--repeats", type=int, default=None, help="timed steps (default 10; --quick: 1)")
    ap.add_argument("--warmup", type=int, default=None, help="untimed steps first (default 3; --quick: 0)")
    ap.add_argument("--amp-rtol", type=float, default=0.03, help="mixed precision loss vs float32")
    ap.add_argument("--compile", action="store_true", help="torch.compile the depth model")
    ap.add_argument("--channels-last", action="store_true", help="channels_last memory format")
    ap.add_argument("--quick", action="store_true", help="tiny sizes and one repeat (CPU, CI)")
    ap.add_argument("--train-images", type=int, default=PAPER_TRAIN_IMAGES)
    ap.add_argument("--flow-epochs", type=int, default=37)
    ap.add_argument("--depth-epochs", type=int, default=44)
    ap.add_argument("--params", type=Path, default=ROOT / "params.yaml", help="variants and their weights")
    ap.add_argument("--out", type=Path, default=ROOT / "reports" / "benchmarks")
    ap.add_argument("--ddp-worker", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    quick = args.quick
    args.size = args.size or ("64x64" if quick else "288x384")
    args.depth_batch = args.depth_batch or (2 if quick else 12)
    args.flow_batch = args.flow_batch or (2 if quick else 20)
    args.repeats = args.repeats or (1 if quick else 10)
    args.warmup = args.warmup if args.warmup is not None else (0 if quick else 3)
    args.workers = args.workers if args.workers is not None else (1 if quick else 4)
    if args.ddp_worker:
        ddp_worker(args)
        return 0
    device = torch.device(P.resolve_device(args.device))
    args.out = args.out.resolve()
    os.chdir(args.params.resolve().parent)  # relative paths in params start here
    params = P.load(args.params.name)
    args.weights = loss_weights(params)  # full's loss weights (every term on) for the throughput steps
    params["allow_random_init"] = True  # random weights: speed and correctness do not need the real ones
    params["train_depth"]["imagenet_weights"] = None
    params.setdefault("flow_pretrain", {})["checkpoint"] = None
    args.variants = list(params["variants"])
    hw = parse_size(args.size)
    t0 = time.perf_counter()
    checks = Checks()
    with tempfile.TemporaryDirectory() as tmp:
        depth_ds, flow_ds = make_data(Path(tmp), hw, max(args.depth_batch, args.flow_batch) + 2)
        print("1. correctness", flush=True)
        check_correlation(checks, device)
        check_depth_variants(checks, params, depth_ds, device, min(args.depth_batch, 4), args.amp_rtol)
        check_flow_steps(checks, flow_ds, device, min(args.flow_batch, 4), args.amp_rtol)
        check_torchrun(checks, args)
        print("2. throughput", flush=True)
        depth = measure_depth(depth_ds, device, args)
        data = measure_data_share(depth_ds, device, args, depth["fp32"]["step_s"])
        flow = measure_flow(flow_ds, device, args)
    inference = measure_inference(device, (288, 384) if not quick else hw, args)
    name = torch.cuda.get_device_name(device) if device.type == "cuda" else f"CPU ({os.cpu_count()} cores)"
    doc = {
        "device": {"name": name, "type": device.type, "torch": torch.__version__,
                   "cuda": torch.version.cuda, "threads": torch.get_num_threads()},
        "settings": {"size": args.size, "depth_batch": args.depth_batch, "flow_batch": args.flow_batch,
                     "workers": args.workers, "repeats": args.repeats, "warmup": args.warmup,
                     "compile": args.compile, "channels_last": args.channels_last, "amp_rtol": args.amp_rtol},
        "checks": checks.rows, "failed": checks.failed,
        "depth_step": depth, "data_loading": data, "flow_step": flow, "inference_ms": inference,
        "projection": project(depth, flow, data["share"], args),
        "seconds": round(time.perf_counter() - t0, 1),
    }
    doc["goals"] = {"inference_le_5ms": inference["no_pp"] <= 5.0,
                    "teacher_le_25pct": depth["fp32"]["teacher_share"] <= 0.25,
                    "data_le_10pct": data["share"] <= 0.10,
                    "paper_within_one_day": doc["projection"]["fp32"]["full_only_h"] <= 24.0}
    stem = "gpu_check" if device.type == "cuda" else "gpu_check_cpu"
    write_json(args.out / f"{stem}.json", doc)
    write_text(args.out / f"{stem}.md", markdown(doc))
    print(markdown(doc))
    print(f"→ {args.out / stem}.json, .md; {len(checks.failed)} failed check(s)")
    return 1 if checks.failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
