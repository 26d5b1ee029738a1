"""The epoch skeleton (f2depth.epochs) and its one non-finite policy, in all three trainers: a step whose
loss is NaN/inf is skipped (no update) and counted in the epoch's row; an epoch of nothing else stops the
run with one line naming it, and the resume file keeps the last good epoch."""

from __future__ import annotations

import itertools
from pathlib import Path

import fakes
import pytest
import torch
import train_fakes
from test_flow_pretrain import make_set

from f2depth.depth import DepthModel, DepthModelConfig
from f2depth.epochs import EpochLoop, NonFiniteEpochError, clear_state, load_state, save_state
from f2depth.flow import PWCLite
from f2depth.flow import finetune as flow_finetune
from f2depth.flow import pretrain as flow_pretrain
from f2depth.flow.finetune import FinetuneConfig
from f2depth.flow.finetune_data import FlowPairs
from f2depth.flow.pretrain import PretrainConfig, pretrain
from f2depth.formats.prepared import PreparedSet
from f2depth.formats.sintel import list_pairs
from f2depth.keypoints import KeypointFile
from f2depth.train.data import DataConfig, TupleDataset
from f2depth.train.loop import LoopConfig, fit, seed_everything
from f2depth.train.schedule import LRSchedule
from f2depth.train.step import StepConfig
from f2depth.train.teacher import FlowTeacher

EVERY = range(10**6)


class Counter(torch.nn.Module):
    """A one-weight model whose step ``value`` is the loss; NaN where the batch says so."""

    def __init__(self) -> None:
        super().__init__()
        self.w = torch.nn.Parameter(torch.ones(()))


def test_loop_skips_counts_and_stops_on_an_all_non_finite_epoch(tmp_path):
    model = Counter()
    opt = torch.optim.SGD(model.parameters(), lr=0.1)
    seen = []

    def step(value: float) -> dict[str, float]:
        loss = model.w * value
        opt.zero_grad()
        if not torch.isfinite(loss):
            raise FloatingPointError(f"loss is {loss.item()}")
        loss.backward()
        opt.step()
        return {"loss": loss.item()}

    data = {1: [1.0, float("nan"), 3.0], 2: [float("inf"), float("nan")]}
    loop = EpochLoop("toy", 2, {"model": model, "optimizer": opt}, tmp_path / "s" / "state.pt", "fp",
                     progress=False)
    with pytest.raises(NonFiniteEpochError) as info:
        loop.run_epochs(data.__getitem__, step, end_epoch=lambda row: {"extra": row["epoch"] * 10},
                        on_epoch=seen.append)
    message = str(info.value)
    assert message == "toy: all 2 steps of epoch 2 had a non-finite loss (last: loss is nan)"
    assert "\n" not in message
    (row,) = seen
    assert row["steps"] == 2 and row["skipped_steps"] == 1 and row["extra"] == 10
    assert row["loss"] == pytest.approx((1.0 + 3.0 * 0.9) / 2)  # the NaN step changed nothing
    assert model.w.item() == pytest.approx(1.0 - 0.1 - 0.3)  # epoch 2 updated nothing either
    state, note = load_state(tmp_path / "s" / "state.pt", "fp")
    assert note == "" and state["epoch"] == 1 and state["run"] == "toy" and state["history"] == seen
    # a new run of the same fingerprint resumes after epoch 1 and replays its row first
    fresh = Counter()
    parts = {"model": fresh, "optimizer": torch.optim.SGD(fresh.parameters(), lr=0.1)}
    again = EpochLoop("toy", 1, parts, tmp_path / "s" / "state.pt", "fp")
    assert again.restore() == 1 and fresh.w.item() == pytest.approx(0.6)
    replayed = []
    again.run_epochs(data.__getitem__, step, on_epoch=replayed.append)
    assert replayed == seen
    assert load_state(tmp_path / "s" / "state.pt", "other")[0] is None
    clear_state(tmp_path / "s" / "state.pt")
    assert not (tmp_path / "s").exists()


def test_a_damaged_resume_state_starts_afresh(tmp_path):
    """Issue 53 item 2: a resume state whose model weights changed after it was written (flipped bytes) is
    not resumed; the reason names the file and the part."""
    model = torch.nn.Linear(32, 32)
    path = tmp_path / "state.pt"
    save_state(path, run="toy", fingerprint="fp", epoch=1, history=[], parts={"model": model})
    assert load_state(path, "fp")[1] == ""
    fakes.flip_weight_bytes(path, 64)
    state, reason = load_state(path, "fp")
    assert state is None and reason == (f"{path} (model): damaged: its weights do not match the sha256 "
                                        "digest written with them (the file changed after it was written); "
                                        "starting afresh")


def nan_on(net: torch.nn.Module, calls) -> None:
    """Make the flow network's output NaN on the given (0-based) forward calls (depth: the frozen teacher)."""
    count = itertools.count()

    def hook(module, args, out):
        if next(count) in calls:
            fw, bw = out
            return [f * float("nan") for f in fw], None if bw is None else [f * float("nan") for f in bw]
        return None

    net.register_forward_hook(hook)


def nan_loss(monkeypatch, module, name: str, calls) -> None:
    """Make the loss that ``module.name`` returns NaN on the given (0-based) calls (flow training: a NaN
    flow would stop ARFlow's range map before the loss)."""
    real, count = getattr(module, name), itertools.count()

    def wrapped(*args, **kwargs):
        loss, stats = real(*args, **kwargs)
        return (loss * float("nan") if next(count) in calls else loss), stats

    monkeypatch.setattr(module, name, wrapped)


def run_pretrain(tmp: Path, calls, monkeypatch) -> dict:
    pairs = list_pairs(make_set(tmp / "sintel", seqs=("a_1",)), ("clean",), ["a_1"])  # 2 pairs
    nan_loss(monkeypatch, flow_pretrain, "flow_loss", calls)
    torch.manual_seed(0)
    cfg = PretrainConfig(height=64, width=64, raw_epochs=1, census_epochs=0, batch_size=1)
    return pretrain(PWCLite(), pairs, cfg, tmp / "resume", progress=False)["history"][-1]


def run_finetune(tmp: Path, calls, monkeypatch) -> dict:
    prep = train_fakes.write_prepared(tmp / "prepared", hw=(64, 64), scenes=1, frames=4, seed=4)
    ds = PreparedSet(prep)
    pairs = FlowPairs(ds, ds.pairs[:2], KeypointFile(tmp / "keypoints" / "train.npz"))
    nan_loss(monkeypatch, flow_finetune, "batch_loss", calls)
    torch.manual_seed(0)
    cfg = FinetuneConfig(epochs=1, batch_size=1, occlusion="range_map")
    return flow_finetune.finetune(PWCLite(), pairs, cfg, (), tmp / "resume.pt", progress=False)["history"][-1]


def run_depth(tmp: Path, calls, monkeypatch) -> dict:
    prep = train_fakes.write_prepared(tmp / "prepared", hw=(64, 64), scenes=1, frames=6)
    data = TupleDataset(prep, tmp / "keypoints" / "train.npz", DataConfig(num_points=30), seed=7)
    torch.manual_seed(0)
    net = PWCLite()
    nan_on(net, calls)
    seed_everything(7)
    config = LoopConfig(1, 2, LRSchedule.scaled([1e-4], [1], 1), seed=7, progress=False, **train_fakes.LOOP)
    step = StepConfig(train_fakes.WEIGHTS, 40)
    return fit(DepthModel(DepthModelConfig(64, 64)), data, FlowTeacher(net), step,
               config, checkpoint=tmp / "resume.pt", fingerprint="x").history[-1]


@pytest.mark.parametrize(("name", "run"), [("flow_pretrain", run_pretrain),
                                           (r"flow_finetune\[patch\]", run_finetune),
                                           ("train_depth", run_depth)])
def test_every_trainer_skips_a_non_finite_step_and_stops_on_a_non_finite_epoch(tmp_path, monkeypatch, name,
                                                                                 run):
    torch.set_num_threads(1)
    row = run(tmp_path / "one", {0}, monkeypatch)  # the first step is NaN: skipped; the second runs
    assert row["epoch"] == 1 and row["steps"] == 1 and row["skipped_steps"] == 1
    with pytest.raises(NonFiniteEpochError, match=rf"^{name}: all 2 steps of epoch 1 had a non-finite loss "
                       r"\(last: .*nan") as info:
        run(tmp_path / "all", EVERY, monkeypatch)
    assert "\n" not in str(info.value)
