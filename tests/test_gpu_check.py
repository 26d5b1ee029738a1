"""benchmarks/gpu_check.py on a CPU (`--device cpu --quick`): every correctness check runs and passes (the
depth step of every variant of params.yaml and the flow fine-tuning step with and without mixed precision,
the correlation against its reference, torchrun with DDP at world size 1), every measurement is a
positive number, and the JSON and Markdown reports are written. On a GPU the same script is `make
gpu-check`."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_gpu_check_runs_on_cpu_and_reports(tmp_path):
    env = {**os.environ, "F2DEPTH_MLFLOW": "0", "OMP_NUM_THREADS": "1"}
    cmd = [sys.executable, str(ROOT / "benchmarks" / "gpu_check.py"), "--device", "cpu", "--quick", "--out",
           str(tmp_path)]
    res = subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=900)
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    doc = json.loads((tmp_path / "gpu_check_cpu.json").read_text())
    assert doc["failed"] == [] and doc["device"]["type"] == "cpu"
    names = [c["check"] for c in doc["checks"]]
    variants = yaml.safe_load((ROOT / "params.yaml").read_text())["variants"]
    for v in variants:
        for what in ("fp32", "amp"):
            assert f"depth step {v} {what}" in names
        assert f"depth loss {v} amp vs fp32" in names
    for loss in ("patch", "full"):
        expected = {f"flow step {loss} fp32", f"flow step {loss} amp", f"flow loss {loss} amp vs fp32"}
        assert expected <= set(names)
    assert any(n.startswith("correlation fwd+bwd on cpu") for n in names)
    ddp = next(c for c in doc["checks"] if c["check"].startswith("torchrun"))
    assert ddp["backend"] == "gloo" and ddp["ddp"] is True and math.isfinite(ddp["total"])
    for c in doc["checks"]:
        if "rel_diff" in c:
            assert c["rel_diff"] <= doc["settings"]["amp_rtol"] and c["rel_diff"] > 0  # autocast did act
    for mode in ("fp32", "amp"):
        for part in ("depth_step", "flow_step"):
            assert 0 < doc[part][mode]["step_s"] < 120 and doc[part][mode]["steps_per_s"] > 0
        assert 0 < doc["depth_step"][mode]["teacher_share"] < 1
        proj = doc["projection"][mode]
        assert proj["all_variants_h"] > proj["full_only_h"] > proj["flow_finetune_h"] > 0
    assert 0 <= doc["data_loading"]["share"] < 1
    # both timed (their order is a speed question for benchmarks/: beside a busy process it flips)
    assert doc["inference_ms"]["pp"] > 0 and doc["inference_ms"]["no_pp"] > 0
    goals = {"inference_le_5ms", "teacher_le_25pct", "data_le_10pct", "paper_within_one_day"}
    assert set(doc["goals"]) == goals
    md = (tmp_path / "gpu_check_cpu.md").read_text()
    assert md.startswith("# GPU check: CPU")
    assert "| torchrun world size 1, gloo, DDP, one epoch of fit | ok |" in md
    assert "projected `make paper`" in md
