"""Median per-image time of the DSO pixel selector at 640×480, presets ``dso`` and ``p2net``, one thread.

Run: ``python benchmarks/bench_keypoints.py [--repeats N] [--images DIR] [--out file.json]``.
Uses DSO's reference images (``REFERENCE``, the folder the exactness tests read) when present, otherwise
seeded synthetic images.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import cv2  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402

from f2depth.io import write_json  # noqa: E402
from f2depth.keypoints import KeypointSelector  # noqa: E402

REFERENCE = Path(__file__).resolve().parents[1] / "tests" / "data" / "dso"


def synthetic_images(count: int, seed: int = 0) -> list[np.ndarray]:
    """Seeded 480×640 grey images: smoothed noise, rectangles and a gradient (natural-ish statistics)."""
    rng = np.random.default_rng(seed)
    images = []
    for _ in range(count):
        base = cv2.GaussianBlur(rng.normal(128, 60, (480, 640)).astype(np.float32), (0, 0), 3)
        for _ in range(20):
            x0, y0 = rng.integers(0, 600), rng.integers(0, 440)
            base[y0 : y0 + rng.integers(20, 200), x0 : x0 + rng.integers(20, 200)] += rng.normal(0, 40)
        base += np.linspace(-30, 30, 640, dtype=np.float32)[None, :]
        images.append(np.clip(base + rng.normal(0, 2, base.shape), 0, 255).astype(np.uint8))
    return images


def load_images(folder: Path | None) -> tuple[list[np.ndarray], str]:
    folder = folder or REFERENCE
    files = sorted(folder.glob("*.pgm")) + sorted(folder.glob("*.png"))
    images = [cv2.imread(str(f), cv2.IMREAD_GRAYSCALE) for f in files]
    images = [cv2.resize(im, (640, 480)) if im.shape != (480, 640) else im for im in images if im is not None]
    if images:
        return images, f"{len(images)} images from {folder}"
    return synthetic_images(4), "4 seeded synthetic images"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeats", type=int, default=15, help="timed runs per image (after one warm-up)")
    parser.add_argument("--images", type=Path, default=None, help="folder of grey images (pgm/png)")
    parser.add_argument("--out", type=Path, default=None, help="also write the numbers as JSON here")
    args = parser.parse_args()
    torch.set_num_threads(1)
    cv2.setNumThreads(1)
    images, source = load_images(args.images)
    load = os.getloadavg()
    print(f"DSO pixel selector, 640x480, {source}, {args.repeats} runs each, 1 thread; "
          f"load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f} on {os.cpu_count()} cores")
    results: dict = {"source": source, "repeats": args.repeats, "load_before": list(load)}
    for preset in ("dso", "p2net"):
        for image in images:  # warm-up: random pattern, lookup tables, visiting orders
            KeypointSelector(preset)(image)
        times, cpu, counts = [], [], []
        for _ in range(args.repeats):
            for image in images:
                start, start_cpu = time.perf_counter(), time.process_time()
                points = KeypointSelector(preset)(image)
                cpu.append(time.process_time() - start_cpu)
                times.append(time.perf_counter() - start)
                counts.append(len(points))
        print(f"  {preset:6s} median {1000 * statistics.median(times):6.1f} ms/image wall "
              f"(min {1000 * min(times):.1f}, max {1000 * max(times):.1f}), "
              f"{1000 * statistics.median(cpu):.1f} ms CPU; points per image {min(counts)}..{max(counts)}")
        results[preset] = {"median_ms": round(1000 * statistics.median(times), 2),
                           "min_ms": round(1000 * min(times), 2), "max_ms": round(1000 * max(times), 2),
                           "median_cpu_ms": round(1000 * statistics.median(cpu), 2),
                           "points_min": min(counts), "points_max": max(counts)}
    if args.out:
        write_json(args.out, results)


if __name__ == "__main__":
    main()
