"""Pretraining (f2depth.flow.pretrain), scoring (f2depth.flow.validate) and the `flow_pretrain` stage on a
tiny Sintel-layout set made in tmp_path."""

from __future__ import annotations

import csv
import importlib.util
import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch
import train_fakes
import yaml

from f2depth.epochs import load_state
from f2depth.flow import FlowNetwork, PWCLite, bootstrap, load_flow_model
from f2depth.flow.pretrain import HISTORY_COLUMNS, PretrainConfig, clear_resume, pretrain, run_fingerprint
from f2depth.flow.validate import evaluate_sintel
from f2depth.formats.sintel import list_pairs, write_flo
from f2depth.params import ParamsError

HW = (40, 56)
STAGE = Path(__file__).resolve().parents[1] / "stages" / "flow_pretrain.py"


def _texture(rng: np.random.Generator, hw) -> np.ndarray:
    coarse = rng.uniform(0, 255, (hw[0] // 4 + 2, hw[1] // 4 + 2, 3)).astype(np.float32)
    return cv2.resize(coarse, (hw[1] + 8 * 4, hw[0] + 8 * 4), interpolation=cv2.INTER_CUBIC).clip(0, 255)


def make_set(root: Path, seqs=("a_1", "b_1", "c_1"), frames=3) -> Path:
    """Sequences panning over a texture by (2, 1) px per frame, with exact .flo and occlusions."""
    t = root / "training"
    for s, seq in enumerate(seqs):
        big = _texture(np.random.default_rng(s), HW)
        for i in range(frames):
            crop = big[16 - i: 16 - i + HW[0], 16 - 2 * i: 16 - 2 * i + HW[1]].astype(np.uint8)
            for p in ("clean", "final"):
                path = t / p / seq / f"frame_{i + 1:04d}.png"
                path.parent.mkdir(parents=True, exist_ok=True)
                cv2.imwrite(str(path), crop)
            if i + 1 < frames:
                write_flo(t / "flow" / seq / f"frame_{i + 1:04d}.flo",
                          np.broadcast_to(np.float32([2.0, 1.0]), (*HW, 2)).copy())
                occ = t / "occlusions" / seq / f"frame_{i + 1:04d}.png"
                occ.parent.mkdir(parents=True, exist_ok=True)
                cv2.imwrite(str(occ), np.zeros(HW, np.uint8))
    return root


TINY = PretrainConfig(height=64, width=64, raw_epochs=1, census_epochs=1, batch_size=2, lr=1e-4, seed=0)


def test_pretrain_runs_both_phases_and_resumes_identically(tmp_path):
    pairs = list_pairs(make_set(tmp_path / "s"), ("clean",), ["a_1"])  # 2 pairs: one step per epoch
    torch.manual_seed(0)
    straight = PWCLite()
    info = pretrain(straight, pairs, TINY, tmp_path / "r1", progress=False)
    assert info["epochs_run"] == 2 and [h["census"] for h in info["history"]] == [0.0, 1.0]
    assert all(math.isfinite(v) for h in info["history"] for v in h.values())

    torch.manual_seed(0)
    model = PWCLite()
    with pytest.raises(train_fakes.Crash):
        pretrain(model, pairs, TINY, tmp_path / "r2", on_epoch=train_fakes.crash_after(1), progress=False)
    assert (tmp_path / "r2" / "last.pt").is_file()
    resumed = PWCLite()  # different initial weights: they come from the resume file
    info = pretrain(resumed, pairs, TINY, tmp_path / "r2", progress=False)
    assert info["resumed_from"] == 1 and info["epochs_run"] == 1
    for k, v in straight.state_dict().items():
        assert torch.equal(v, resumed.state_dict()[k]), k  # the epoch's draws do not depend on the global RNG
    # another configuration or data set does not resume from a foreign state
    state_file = tmp_path / "r2" / "last.pt"
    assert load_state(state_file, run_fingerprint(TINY, pairs))[0] is not None
    other = PretrainConfig(**{**vars(TINY), "lr": 2e-4})
    assert load_state(state_file, run_fingerprint(other, pairs))[0] is None
    assert load_state(state_file, run_fingerprint(TINY, pairs[:1]))[0] is None
    # the same number of pairs, regenerated with other contents: starts afresh
    image = cv2.imread(str(pairs[0].image2))
    cv2.imwrite(str(pairs[0].image2), 255 - image)
    assert load_state(state_file, run_fingerprint(TINY, pairs))[0] is None
    again = pretrain(PWCLite(), pairs, TINY, tmp_path / "r2", progress=False)
    assert again["resumed_from"] == 0 and again["epochs_run"] == 2
    clear_resume(tmp_path / "r2")
    assert not (tmp_path / "r2").exists()


def test_the_arflow_route_draws_from_its_epoch_generator_only(tmp_path):
    """Issue 24 item 5: shuffling, flips and swaps come from (seed, epoch), never from torch's global
    generator, so whatever else draws from it, the same seed trains the same network and another differs."""
    pairs = list_pairs(make_set(tmp_path / "sintel", frames=4))
    weights = []
    for global_seed, seed in ((0, 0), (123, 0), (0, 5)):
        torch.manual_seed(global_seed)
        model = PWCLite()
        pretrain(model, pairs, PretrainConfig(**{**vars(TINY), "census_epochs": 0, "seed": seed}),
                 progress=False)
        weights.append(torch.cat([v.flatten() for v in model.state_dict().values()]))
    assert torch.equal(weights[0], weights[1])
    assert not torch.equal(weights[0], weights[2])


def test_evaluate_sintel_scores_model_and_zero_flow(tmp_path):
    pairs = list_pairs(make_set(tmp_path / "s"), ("clean",), ["c_1"], require_flow=True)
    res = evaluate_sintel(PWCLite().eval(), pairs, (64, 64), figure_dir=tmp_path / "fig", figures=1)
    assert res["pairs"] == 2
    assert res["zero_flow"]["epe_all"] == pytest.approx(5**0.5, rel=1e-5)
    assert res["zero_flow"]["pixels_all"] == 2 * HW[0] * HW[1] and res["zero_flow"]["epe_occ"] is None
    assert res["zero_flow"]["magnitude_ratio"] == 0 and res["zero_flow"]["cosine"] == 0
    assert math.isfinite(res["model"]["epe_all"]) and -1 <= res["model"]["cosine"] <= 1
    assert len(list((tmp_path / "fig").glob("*.png"))) == 1


class _ConstantFlow(FlowNetwork):
    """The same field (2, 1) px for every pair, whatever the images: no matching at all."""

    def forward(self, img1, img2, with_backward=True):
        f = img1.new_tensor([2.0, 1.0]).view(1, 2, 1, 1).expand(img1.shape[0], 2, *img1.shape[-2:])
        return [f], ([f] if with_backward else None)

    def features(self, img):
        return [img]


class _GlobalShift(_ConstantFlow):
    """Reads one integer shift per pair from the images (best of |d| ≤ 3 px by mean |I2(p + d) − I1(p)|)."""

    def forward(self, img1, img2, with_backward=True):
        h, w = img1.shape[-2:]
        shifts = [(dx, dy) for dx in range(-3, 4) for dy in range(-3, 4)]
        err = [(img2[..., 3 + dy:h - 3 + dy, 3 + dx:w - 3 + dx] - img1[..., 3:h - 3, 3:w - 3]).abs().mean()
               for dx, dy in shifts]
        f = img1.new_tensor(shifts[int(torch.stack(err).argmin())], dtype=img1.dtype)
        f = f.view(1, 2, 1, 1).expand(img1.shape[0], 2, h, w)
        return [f], ([-f] if with_backward else None)


def test_swap_consistency_exposes_a_constant_network_that_scores_perfectly(tmp_path):
    """Every sequence of make_set pans by (2, 1) px, so a constant (2, 1) field has EPE 0 and cosine 1 there —
    the way a pretrained PWC-Lite that had learnt an image-independent bias looked good on the animated set
    and anti-correlated on the prepared pairs. Only swap_consistency tells it from real matching."""
    pairs = list_pairs(make_set(tmp_path / "s"), ("clean",), ["c_1"], require_flow=True)
    const = evaluate_sintel(_ConstantFlow(), pairs, None)["model"]
    matched = evaluate_sintel(_GlobalShift(), pairs, None)["model"]
    assert const["epe_all"] == pytest.approx(0, abs=1e-5) and const["cosine"] == pytest.approx(1)
    assert matched["epe_all"] == pytest.approx(0, abs=1e-5) and matched["cosine"] == pytest.approx(1)
    assert const["swap_consistency"] == pytest.approx(-1)
    assert matched["swap_consistency"] == pytest.approx(1)


def tiny_chairs() -> dict:
    """A ``flow_pretrain.chairs`` section that runs in seconds."""
    return {"data": {"height": 64, "width": 64, "max_shift": 4, "small_share": 0.25, "rotation_deg": 5,
                     "scale": 0.05, "min_shapes": 1, "max_shapes": 2, "min_size": 0.2, "max_size": 0.4,
                     "supersample": 1, "textures": 3, "image_crops": 2},
            "batch_size": 2, "steps_per_epoch": 2, "feature_epochs": 1, "feature_lr": 2e-3, "epochs": 1,
            "lr": 3e-4, "final_lr": 1e-4, "matching_weight": 0.5, "matching_strides": [4, 8],
            "w_scales": [0.32, 0.08, 0.02, 0.01, 0.005],
            "calibration_pairs": 2, "heldout_pairs": 3, "average_epochs": 1,
            "amp": False, "cpu_ranks": None}


def run_stage(tmp_path: Path, monkeypatch, **section) -> dict:
    """The stage in ``tmp_path`` on :func:`make_set`'s sequences with tiny settings, ``section`` overriding
    keys of ``flow_pretrain``; returns its metrics."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("F2DEPTH_MLFLOW", "0")
    write_stage_inputs(tmp_path, **section)
    spec = importlib.util.spec_from_file_location("flow_pretrain_stage", STAGE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    module.main(["flow_pretrain.py", str(tmp_path / "params.yaml")])
    return json.loads((tmp_path / "metrics" / "flow_pretrain.json").read_text())


def write_stage_inputs(tmp_path: Path, **section) -> Path:
    """:func:`make_set`'s sequences and a tiny params.yaml in ``tmp_path`` (``section``: keys of
    ``flow_pretrain``); returns the params file."""
    make_set(tmp_path / "data" / "animated")
    params = {
        "seed": 0, "device": "cpu", "threads": 1, "allow_random_init": True,
        "data": {"sintel": "data/animated", "prepared": "data/prepared"},
        "flow_pretrain": {"network": "pwclite", "checkpoint": None, "source": "synthetic", "height": 64,
                          "width": 64, "raw_epochs": 1, "census_epochs": 1, "batch_size": 4, "lr": 1e-4,
                          "init": "msra", "holdout": 1, "passes": ["clean", "final"], "eval_prepared": False,
                          "eval_prepared_pairs": 4, "figures": 1, "figure_dir": "reports/flow",
                          "model": "models/flow_pretrained.pt", "resume_dir": "tmp/flow_pretrain",
                          "chairs": tiny_chairs(), **section},
    }
    (tmp_path / "params.yaml").write_text(yaml.safe_dump(params))
    return tmp_path / "params.yaml"


def test_stage_end_to_end(tmp_path, monkeypatch):
    metrics = run_stage(tmp_path, monkeypatch)
    assert metrics["train_sequences"] == ["a_1", "b_1"] and metrics["heldout_sequences"] == ["c_1"]
    for key in ("heldout_clean", "heldout_final"):
        assert metrics[key]["pairs"] == 2
        assert set(metrics[key]["model"]) >= {"epe_all", "epe_noc", "epe_low_texture", "magnitude_ratio",
                                              "cosine"}
    assert len(metrics["training"]["history"]) == 2
    history = list(csv.DictReader((tmp_path / "metrics" / "flow_pretrain" / "history.csv").open()))
    assert [int(r["epoch"]) for r in history] == [1, 2] and list(history[0]) == list(HISTORY_COLUMNS)
    assert float(history[1]["loss"]) == pytest.approx(metrics["training"]["history"][1]["loss"], rel=1e-5)
    model = load_flow_model(tmp_path / "models" / "flow_pretrained.pt")
    assert isinstance(model, PWCLite)
    assert len(list((tmp_path / "reports" / "flow").glob("*.png"))) == 2
    assert not (tmp_path / "tmp" / "flow_pretrain").exists()  # resume state removed after success


def test_stage_chairs_route_end_to_end(tmp_path, monkeypatch):
    metrics = run_stage(tmp_path, monkeypatch, source="chairs", passes=["clean"])
    assert metrics["source"] == "chairs" and metrics["random_init"] is True
    assert metrics["generated"]["pairs"] == 3 and metrics["heldout_clean"]["pairs"] == 2
    assert set(metrics["generated"]["model"]) >= {"epe_all", "swap_consistency", "cosine", "magnitude_ratio"}
    training = metrics["training"]
    assert [r["phase"] for r in training["history"]] == ["features", "all"]
    assert {"heldout_top1_s4", "heldout_top1_s8"} <= set(training["after_features"])
    history = list(csv.DictReader((tmp_path / "metrics" / "flow_pretrain" / "history.csv").open()))
    assert list(history[0]) == list(bootstrap.HISTORY_COLUMNS) and len(history) == 2
    phase_b = list(csv.DictReader((tmp_path / "metrics" / "flow_pretrain" / "phase_b.csv").open()))
    assert list(phase_b[0]) == list(bootstrap.PHASE_B_COLUMNS) and [r["epoch"] for r in phase_b] == ["2"]
    assert all(v != "" for r in history + phase_b for v in r.values())  # no gap a plot would draw as 0
    model = load_flow_model(tmp_path / "models" / "flow_pretrained.pt")
    assert isinstance(model, PWCLite)
    assert not (tmp_path / "tmp" / "flow_pretrain").exists()


def test_stage_imports_an_arflow_checkpoint(tmp_path, monkeypatch):
    ref = PWCLite()
    torch.save({"epoch": 7, "state_dict": ref.state_dict()}, tmp_path / "arflow.pth.tar",
               _use_new_zipfile_serialization=False)
    metrics = run_stage(tmp_path, monkeypatch, checkpoint="arflow.pth.tar", init="pytorch", holdout=2,
                        passes=["clean"], eval_prepared_pairs=None, figures=0)
    assert metrics["source"] == "arflow" and "training" not in metrics
    header = (tmp_path / "metrics" / "flow_pretrain" / "history.csv").read_text()
    assert header == ",".join(HISTORY_COLUMNS) + "\n"  # imported: no training epochs
    phase_b = (tmp_path / "metrics" / "flow_pretrain" / "phase_b.csv").read_text()
    assert phase_b == ",".join(bootstrap.PHASE_B_COLUMNS) + "\n"
    assert metrics["heldout_sequences"] == ["b_1", "c_1"] and metrics["heldout_clean"]["pairs"] == 4
    loaded = load_flow_model(tmp_path / "models" / "flow_pretrained.pt")
    assert all(torch.equal(v, loaded.state_dict()[k]) for k, v in ref.state_dict().items())


def test_stage_names_the_file_and_key_of_an_unknown_network(tmp_path, monkeypatch):
    with pytest.raises(ParamsError, match=r"params\.yaml: flow_pretrain\.network = 'raft' is not a flow "
                                          r"network; use one of \['pwclite'\]"):
        run_stage(tmp_path, monkeypatch, network="raft")


def test_config_rejects_an_unknown_init():
    with pytest.raises(ValueError, match="'msra' or 'pytorch'"):
        PretrainConfig(init="xavier")


def test_zero_training_epochs_are_refused(tmp_path, monkeypatch):
    """Before: raw_epochs 0 and census_epochs 0 exited 0 and saved the random initial weights as
    flow_pretrained.pt. Now the ARFlow route refuses it in one line, before anything is written."""
    with pytest.raises(ParamsError, match=r"flow_pretrain\.raw_epochs and census_epochs are both 0.*random "
                                            r"initial weights"):
        run_stage(tmp_path, monkeypatch, raw_epochs=0, census_epochs=0)
    assert not (tmp_path / "models").exists() and not (tmp_path / "metrics").exists()
