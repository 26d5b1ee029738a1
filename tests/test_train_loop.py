"""Tests for f2depth.train.loop on f2depth.epochs: resume = uninterrupted, non-finite policy, history."""

from __future__ import annotations

import csv
from pathlib import Path

import pytest
import torch
import train_fakes
import yaml

from f2depth import epochs as ckpt
from f2depth.depth import DepthModel, DepthModelConfig
from f2depth.epochs import NonFiniteEpochError, history_csv, write_history
from f2depth.flow import PWCLite
from f2depth.train import loop as loop_module
from f2depth.train.data import DataConfig, TupleDataset
from f2depth.train.diagnostics import DIAGNOSTIC_KEYS
from f2depth.train.heldout import HELDOUT_KEYS
from f2depth.train.loop import (
    HISTORY_COLUMNS,
    HISTORY_FILES,
    VALIDATION_COLUMNS,
    LoopConfig,
    fit,
    seed_everything,
)
from f2depth.train.schedule import LRSchedule
from f2depth.train.step import StepConfig
from f2depth.train.teacher import FlowTeacher

EPOCHS = 2
CONFIG = LoopConfig(EPOCHS, 2, LRSchedule.scaled([1e-4, 1e-5, 1e-6], [27, 15, 2], EPOCHS), seed=7,
                    progress=False, **train_fakes.LOOP)
STEP = StepConfig({**train_fakes.WEIGHTS, "feature": 0.0, "rigid": 0.0}, min_area=40)


class Killed(Exception):
    """Stands in for the process being killed right after a checkpoint."""


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("loop")
    prep = train_fakes.write_prepared(root / "prepared", hw=(64, 64), scenes=1, frames=6)
    return TupleDataset(prep, root / "keypoints" / "train.npz", DataConfig(num_points=30), seed=7)


def fake_validate(model):
    return {"val_abs_rel": 0.5, "val_a1": 0.25}


def new_model() -> DepthModel:
    seed_everything(7)
    return DepthModel(DepthModelConfig(64, 64))


def test_resumed_run_ends_with_the_same_weights(dataset, tmp_path):
    torch.set_num_threads(1)
    ref = new_model()
    full = fit(ref, dataset, None, STEP, CONFIG, checkpoint=tmp_path / "a.pt", fingerprint="run",
               validate=fake_validate)
    assert [r["epoch"] for r in full.history] == [0, 1, 2] and full.resumed_from == 0
    assert [r["lr"] for r in full.history[1:]] == [1e-4, 1e-5]

    def kill_after_first(row):
        if row["epoch"] == 1:
            raise Killed

    with pytest.raises(Killed):
        fit(new_model(), dataset, None, STEP, CONFIG, checkpoint=tmp_path / "b.pt", fingerprint="run",
            validate=fake_validate, on_epoch=kill_after_first)
    state, _ = ckpt.load_state(tmp_path / "b.pt", "run")
    assert state["epoch"] == 1 and state["run"] == "train_depth"
    torch.manual_seed(12345)  # a new process: global RNG state differs until the checkpoint restores it
    replayed = []
    resumed_model = new_model()
    resumed = fit(resumed_model, dataset, None, STEP, CONFIG, checkpoint=tmp_path / "b.pt", fingerprint="run",
                  validate=fake_validate, on_epoch=replayed.append)
    assert resumed.resumed_from == 1
    assert [r["epoch"] for r in replayed] == [0, 1, 2]  # history replayed to the new logger, then epoch 2
    for (k, a), (k2, b) in zip(ref.state_dict().items(), resumed_model.state_dict().items()):
        assert k == k2 and torch.equal(a, b), k
    for a, b in zip(full.history, resumed.history):
        def timeless(row):
            return {k: v for k, v in row.items() if "seconds" not in k}

        assert timeless(a) == timeless(b)


def test_other_fingerprint_starts_afresh(dataset, tmp_path):
    cfg = LoopConfig(1, 2, LRSchedule.scaled([1e-4], [1], 1), seed=7, progress=False, **train_fakes.LOOP)
    fit(new_model(), dataset, None, STEP, cfg, checkpoint=tmp_path / "s.pt", fingerprint="one")
    again = fit(new_model(), dataset, None, STEP, cfg, checkpoint=tmp_path / "s.pt", fingerprint="one")
    assert again.resumed_from == 1 and len(again.history) == 1  # finished: nothing left to train
    state, note = ckpt.load_state(tmp_path / "s.pt", "two")
    assert state is None and "other settings or inputs" in note
    off = fit(new_model(), dataset, None, STEP, cfg, checkpoint=tmp_path / "s.pt", fingerprint="one",
              resume=False)
    assert off.resumed_from == 0 and off.resume_note == "resume disabled"


def test_val_every_measures_before_training_every_nth_epoch_and_after_the_last(dataset, tmp_path):
    calls = []

    def counting_validate(model):
        calls.append(model)
        return fake_validate(model)

    cfg = LoopConfig(5, 2, LRSchedule.scaled([1e-4], [1], 5), seed=7, progress=False,
                     **{**train_fakes.LOOP, "val_every": 2})
    assert [cfg.validates_after(e) for e in range(6)] == [True, False, True, False, True, True]
    result = fit(new_model(), dataset, None, STEP, cfg, checkpoint=tmp_path / "v.pt", fingerprint="v",
                 validate=counting_validate)
    measured = [r["epoch"] for r in result.history if "val_a1" in r]
    assert measured == [0, 2, 4, 5] and len(calls) == 4
    assert [r["epoch"] for r in result.history] == [0, 1, 2, 3, 4, 5]  # every epoch keeps its loss row
    assert all("total" in r for r in result.history[1:])
    with pytest.raises(ValueError, match="val_every"):
        LoopConfig(5, 2, LRSchedule.scaled([1e-4], [1], 5), **{**train_fakes.LOOP, "val_every": 0})


def test_all_non_finite_epoch_stops_the_loop_naming_the_term(dataset, tmp_path):
    torch.manual_seed(0)
    broken = PWCLite()
    with torch.no_grad():
        broken.flow_estimators.predict_flow[0].weight.fill_(float("nan"))
    with pytest.raises(NonFiniteEpochError, match=r"^train_depth: all 2 steps of epoch 1 had a non-finite "
                       r"loss \(last: loss term 'rigid' is nan \(epoch 1, step 1\)"):
        fit(new_model(), dataset, FlowTeacher(broken), StepConfig(train_fakes.WEIGHTS, min_area=40), CONFIG,
            checkpoint=tmp_path / "n.pt", fingerprint="nan")
    assert not (tmp_path / "n.pt").exists()  # nothing written for the failed epoch


def test_history_csv_columns_and_blanks():
    columns = [*HISTORY_COLUMNS, *VALIDATION_COLUMNS[1:]]
    text = history_csv([{"epoch": 0, "val_a1": 0.25, "val_abs_rel": 0.5},
                        {"epoch": 1, "ph": 0.1234567, "total": 0.2, "lr": 1e-4, "seconds": 1.5}],
                       columns)
    lines = text.splitlines()
    assert lines[0].split(",") == columns
    assert lines[1].split(",")[columns.index("val_a1")] == "0.25"
    assert lines[1].split(",")[columns.index("ph")] == ""
    assert lines[2].split(",")[columns.index("ph")] == "0.123457"


def test_history_files_hold_the_measured_rows_with_every_plotted_column_full(dataset, tmp_path):
    """Issue 52: DVC draws an empty cell as 0, so a column measured on some epochs only (validation every
    ``val_every`` epochs) lives in validation.csv with only those epochs' rows, history.csv has every training
    epoch, and no column dvc.yaml plots from them has an empty cell."""
    def full_validate(model):  # every key the stage's validation may add (f2depth.train.run._measure)
        return {**fake_validate(model), **dict.fromkeys(HELDOUT_KEYS, 0.1),
                **dict.fromkeys(DIAGNOSTIC_KEYS, 0.2)}

    cfg = LoopConfig(3, 2, LRSchedule.scaled([1e-4], [1], 3), seed=7, progress=False,
                     **{**train_fakes.LOOP, "val_every": 2})
    result = fit(new_model(), dataset, None, STEP, cfg, checkpoint=tmp_path / "h.pt", fingerprint="h",
                 validate=full_validate)
    files = {}
    for name, columns in HISTORY_FILES.items():
        write_history(tmp_path / name, result.history, columns)
        with (tmp_path / name).open(newline="") as fh:
            files[name] = list(csv.DictReader(fh))
        assert list(files[name][0]) == list(columns), name
    assert [r["epoch"] for r in files["history.csv"]] == ["1", "2", "3"]
    assert [r["epoch"] for r in files["validation.csv"]] == ["0", "2", "3"]  # untrained, every 2nd, last
    for name, rows in files.items():  # a column is measured on every row of its file or on none (a term off)
        for column in rows[0]:
            assert len({r[column] == "" for r in rows}) == 1, (name, column)
    assert all(r["val_a1"] and r["train_a1"] and r["heldout_ph"] for r in files["validation.csv"])
    dvc = yaml.safe_load((Path(__file__).resolve().parents[1] / "dvc.yaml").read_text())
    plotted = [(Path(path).name, field) for plot in dvc["plots"] for spec in plot.values()
               for path, fields in spec["y"].items() if path.startswith("metrics/train_depth/")
               for field in ([fields] if isinstance(fields, str) else fields)]
    assert len(plotted) >= 20
    for name, field in plotted:
        assert name in files and all(r[field] != "" for r in files[name]), (name, field)


def test_fingerprint_covers_settings_and_files(tmp_path):
    f = tmp_path / "w.bin"
    f.write_bytes(b"abc")
    a = ckpt.fingerprint({"lr": 1e-4}, {"flow": f, "none": None})
    assert a == ckpt.fingerprint({"lr": 1e-4}, {"flow": f, "none": None})
    assert a != ckpt.fingerprint({"lr": 1e-5}, {"flow": f, "none": None})
    f.write_bytes(b"abd")
    assert a != ckpt.fingerprint({"lr": 1e-4}, {"flow": f, "none": None})
    with pytest.raises(FileNotFoundError, match="missing input"):
        ckpt.fingerprint({}, {"x": tmp_path / "nope"})


def test_state_every_writes_the_resume_state_after_every_nth_and_the_last_epoch(dataset, tmp_path):
    torch.set_num_threads(1)
    cfg = LoopConfig(3, 2, LRSchedule.scaled([1e-4], [1], 3), seed=7, progress=False,
                     **{**train_fakes.LOOP, "state_every": 2})
    state_file = tmp_path / "every.pt"
    saved = []

    def note_state(row):
        state, _ = ckpt.load_state(state_file, "run")
        saved.append(None if state is None else state["epoch"])
        if row["epoch"] == 1 and len(saved) == 1:
            raise Killed  # killed after epoch 1: nothing to resume from yet

    with pytest.raises(Killed):
        fit(new_model(), dataset, None, STEP, cfg, checkpoint=state_file, fingerprint="run",
            on_epoch=note_state)
    assert saved == [None] and not state_file.exists()
    again = fit(new_model(), dataset, None, STEP, cfg, checkpoint=state_file, fingerprint="run",
                on_epoch=note_state)
    assert again.resumed_from == 0 and saved == [None, None, 2, 3]
    with pytest.raises(ValueError, match="state_every"):
        LoopConfig(3, 2, LRSchedule.scaled([1e-4], [1], 3), **{**train_fakes.LOOP, "state_every": 0})


def test_fit_fades_the_flow_terms_epoch_by_epoch(dataset, tmp_path, monkeypatch):
    """LoopConfig.flow_fade_epochs reaches every step: with a fade of 2 epochs over 3, the steps of epoch 1
    train L_rigid at its weight, epoch 2's at half of it and epoch 3's at 0; the other terms keep theirs."""
    seen: dict[int, set] = {}
    real = loop_module.train_step

    def recording(model, optimizer, batch, teacher, config, *args, **kwargs):
        epoch = int(kwargs["context"].split(",")[0].removeprefix("epoch "))
        seen.setdefault(epoch, set()).add((config.weights["rigid"], config.weights["smooth"]))
        return real(model, optimizer, batch, teacher, config, *args, **kwargs)

    monkeypatch.setattr(loop_module, "train_step", recording)
    step = StepConfig({**train_fakes.WEIGHTS, "feature": 0.0, "rigid": 0.4}, min_area=40)
    cfg = LoopConfig(3, 2, LRSchedule.scaled([1e-4], [1], 3), seed=7, progress=False,
                     **{**train_fakes.LOOP, "flow_fade_epochs": 2})
    torch.manual_seed(0)
    fit(new_model(), dataset, FlowTeacher(PWCLite()), step, cfg, checkpoint=tmp_path / "f.pt",
        fingerprint="f")
    smooth = train_fakes.WEIGHTS["smooth"]
    assert seen == {1: {(0.4, smooth)}, 2: {(0.2, smooth)}, 3: {(0.0, smooth)}}
