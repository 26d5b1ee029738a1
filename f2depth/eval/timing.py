"""Inference time per image: batch 1, at the network size, with and without flip post-processing.

What is timed: ``predict_disparity`` on a (1,3,H,W) input already on the device, i.e. the network
forward pass (and, with PP, the doubled batch, the flips and the ramp blend at the network resolution).
Not timed: image decoding, resizing, host→device copies, upsampling to the ground truth. The clock is
``time.perf_counter`` around each call, with ``torch.cuda.synchronize`` before and after on CUDA (and
``torch.mps.synchronize`` on MPS) so asynchronous kernels are counted. The reported figure is the
median over ``repeats`` runs after ``warmup`` untimed runs. The paper reports 9.4 ms (13.5 ms with PP)
on an RTX 3090 (the paper §4.2.1); on a CPU expect far more, and set the thread count before timing.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import torch

from f2depth.depth.predict import PredictDisp, predict_disparity


def _synchronize(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)
    elif device.type == "mps":
        torch.mps.synchronize()


def time_inference(predict_disp: PredictDisp, *, height: int = 288, width: int = 384,
                   post_process: bool = False, repeats: int = 20, warmup: int = 3,
                   device: str | torch.device = "cpu", seed: int = 0) -> dict[str, Any]:
    """Milliseconds per image for ``predict_disp`` (img (1,3,H,W) → disp (1,1,H,W)) on ``device``.

    Returns ``{"ms_median", "ms_mean", "ms_min", "ms_max", "repeats", "warmup", "height", "width",
    "batch": 1, "post_process", "device", "threads"}``; ``threads`` is torch's intra-op thread count.
    """
    if repeats < 1 or warmup < 0:
        raise ValueError(f"need repeats ≥ 1 and warmup ≥ 0, got repeats={repeats}, warmup={warmup}")
    dev = torch.device(device)
    gen = torch.Generator().manual_seed(seed)
    img = torch.rand(1, 3, height, width, generator=gen).to(dev)
    times: list[float] = []
    with torch.no_grad():
        for i in range(warmup + repeats):
            _synchronize(dev)
            t0 = time.perf_counter()
            predict_disparity(predict_disp, img, post_process=post_process)
            _synchronize(dev)
            if i >= warmup:
                times.append((time.perf_counter() - t0) * 1000.0)
    ms = np.asarray(times)
    return {"ms_median": float(np.median(ms)), "ms_mean": float(ms.mean()), "ms_min": float(ms.min()),
            "ms_max": float(ms.max()), "repeats": repeats, "warmup": warmup, "height": height, "width": width,
            "batch": 1, "post_process": post_process, "device": str(dev), "threads": torch.get_num_threads()}
