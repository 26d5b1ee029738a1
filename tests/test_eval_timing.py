"""Tests for f2depth.eval.timing on a tiny network."""

from __future__ import annotations

import torch

from f2depth.eval import timing


class Tiny(torch.nn.Module):
    def __init__(self) -> None:
        super().__init__()
        self.conv = torch.nn.Conv2d(3, 1, 3, padding=1)
        self.batches: list[int] = []

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        self.batches.append(x.shape[0])
        return torch.sigmoid(self.conv(x))


def test_time_inference_reports_median_of_repeats():
    net = Tiny()
    out = timing.time_inference(net, height=16, width=24, repeats=4, warmup=2)
    assert net.batches == [1] * 6  # batch 1, warm-up runs included in the calls but not in the times
    assert out["ms_min"] <= out["ms_median"] <= out["ms_max"]
    assert out["ms_median"] > 0
    assert out["batch"] == 1 and out["repeats"] == 4 and out["device"] == "cpu"
    assert (out["height"], out["width"], out["post_process"]) == (16, 24, False)


def test_with_pp():
    net = Tiny()
    out = timing.time_inference(net, height=16, width=24, repeats=2, warmup=1, post_process=True)
    assert out["post_process"] is True and out["batch"] == 1
    assert net.batches == [2, 2, 2]  # PP runs the image and its flip together
