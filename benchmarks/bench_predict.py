"""Throughput of ``f2depth predict`` on the CPU at the network size 288×384: PyTorch vs onnxruntime,
with and without flip post-processing, one thread each.

Timed: ``Predictor.predict`` on batches of 480×640 RGB images (resize to 288×384, network, disparity
resized back, inversion), i.e. what ``predict`` does per frame minus file writing. A random-weight
DepthModel (ResNet-18) is used: the speed does not depend on the weights.

Run: ``python benchmarks/bench_predict.py [--batch-size 4] [--batches 3] [--out file.json]``.
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import cv2  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402

from f2depth.depth import DepthModel, DepthModelConfig  # noqa: E402
from f2depth.inference.backends import OnnxBackend, TorchBackend  # noqa: E402
from f2depth.inference.export import export_onnx  # noqa: E402
from f2depth.inference.predict import Predictor  # noqa: E402
from f2depth.io import write_json  # noqa: E402

NET_HW = (288, 384)
IMAGE_HW = (480, 640)


def images(count: int, seed: int = 0) -> list[np.ndarray]:
    """Seeded smooth 480×640 RGB images."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(count):
        coarse = rng.uniform(20, 235, (12, 16, 3)).astype(np.float32)
        out.append(np.clip(cv2.resize(coarse, IMAGE_HW[::-1], interpolation=cv2.INTER_CUBIC), 0, 255)
                   .astype(np.uint8))
    return out


def time_predictor(predictor: Predictor, batch: list[np.ndarray], batches: int) -> list[float]:
    """Seconds per image of each timed batch (after one warm-up batch)."""
    predictor.predict(batch)
    per_image = []
    for _ in range(batches):
        t0 = time.perf_counter()
        predictor.predict(batch)
        per_image.append((time.perf_counter() - t0) / len(batch))
    return per_image


def main() -> None:
    fmt = argparse.RawDescriptionHelpFormatter
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=fmt)
    parser.add_argument("--batch-size", type=int, default=4, help="images per predict call (default 4)")
    parser.add_argument("--batches", type=int, default=3, help="timed batches per configuration (default 3)")
    parser.add_argument("--out", type=Path, default=None, help="also write the numbers as JSON here")
    args = parser.parse_args()
    torch.set_num_threads(1)
    cv2.setNumThreads(1)
    torch.manual_seed(0)
    model = DepthModel(DepthModelConfig(*NET_HW)).eval()
    batch = images(args.batch_size)
    load_before = os.getloadavg()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        onnx_path = Path(tmp) / "depth.onnx"
        t0 = time.perf_counter()
        parity = export_onnx(model, onnx_path)
        export_s = time.perf_counter() - t0
        backends = {"pytorch": TorchBackend(model, "cpu"), "onnxruntime": OnnxBackend(onnx_path, threads=1)}
        for name, backend in backends.items():
            for pp in (False, True):
                per_image = time_predictor(Predictor(backend, post_process=pp), batch, args.batches)
                rows.append((name, pp, statistics.median(per_image)))
    load_after = os.getloadavg()
    print(f"predict at {NET_HW[0]}×{NET_HW[1]} on {IMAGE_HW[0]}×{IMAGE_HW[1]} images, 1 thread, "
          f"batch {args.batch_size}, median of {args.batches} batches (torch {torch.__version__})")
    print(f"ONNX export {export_s:.1f} s, parity max |Δdepth| {parity.max_abs:.2g} m")
    print(f"{'backend':<12} {'post-process':<13} {'ms/image':>9} {'images/s':>9}")
    for name, pp, sec in rows:
        print(f"{name:<12} {('yes' if pp else 'no'):<13} {1000 * sec:9.1f} {1 / sec:9.2f}")
    if args.out:
        write_json(args.out, {
            "net_hw": NET_HW, "image_hw": IMAGE_HW, "batch_size": args.batch_size,
            "export_s": round(export_s, 2), "parity_max_abs_m": parity.max_abs,
            "ms_per_image": [{"backend": n, "post_process": pp, "ms": round(1000 * sec, 2)}
                             for n, pp, sec in rows],
            "load_before": load_before, "load_after": load_after})
    print(f"load average (1, 5, 15 min): before {tuple(round(x, 2) for x in load_before)}, "
          f"after {tuple(round(x, 2) for x in load_after)} on {os.cpu_count()} cores")


if __name__ == "__main__":
    main()
