"""Checkpoint import and our own format (f2depth.flow.net.checkpoint), with broken files made in tmp_path;
other networks than PWC-Lite: tests/test_flow_network.py."""

from __future__ import annotations

from pathlib import Path

import fakes
import pytest
import torch

from f2depth.flow import PWCLite
from f2depth.flow.net.checkpoint import (
    CheckpointError,
    load_flow_model,
    read_flow_checkpoint,
    save_flow_model,
)

REF = Path(__file__).resolve().parent / "data" / "arflow" / "pwclite_seed0.pth.tar"


@pytest.fixture(scope="module")
def ref_sd() -> dict[str, torch.Tensor]:
    assert REF.is_file(), f"reference checkpoint missing: {REF}"
    return torch.load(REF, map_location="cpu", weights_only=True)["state_dict"]


def _same_weights(model: PWCLite, sd: dict[str, torch.Tensor]) -> bool:
    return all(torch.equal(v, sd[k]) for k, v in model.state_dict().items())


def test_reference_checkpoint_loads_by_name(ref_sd):
    model = load_flow_model(REF)
    assert not model.training and _same_weights(model, ref_sd)


@pytest.mark.parametrize("zip_format", [True, False])
@pytest.mark.parametrize("layout", ["epoch_state_dict", "model_state_dict", "bare", "module_prefix"])
def test_accepts_arflow_layouts_in_both_serialisations(tmp_path, ref_sd, zip_format, layout):
    sd = {f"module.{k}": v for k, v in ref_sd.items()} if layout == "module_prefix" else dict(ref_sd)
    obj = {"epoch": 3, "state_dict": sd} if layout in ("epoch_state_dict", "module_prefix") else sd
    if layout == "model_state_dict":
        obj = {"model_state_dict": sd}
    path = tmp_path / "ck.pth.tar"
    torch.save(obj, path, _use_new_zipfile_serialization=zip_format)
    model, meta = read_flow_checkpoint(path)
    assert isinstance(model, PWCLite) and not model.training and _same_weights(model, ref_sd)
    assert meta["format"] == "foreign" and meta["network"] == "pwclite"
    assert meta["epoch"] == (3 if layout in ("epoch_state_dict", "module_prefix") else None)


def test_lists_missing_unexpected_and_misshaped_keys(tmp_path, ref_sd):
    sd = dict(ref_sd)
    del sd["conv_1x1.4.0.bias"]
    sd["extra.weight"] = torch.zeros(1)
    sd["flow_estimators.conv1.0.weight"] = torch.zeros(128, 198, 3, 3)  # 3-frame model shape
    path = tmp_path / "broken.pth.tar"
    torch.save({"state_dict": sd}, path)
    with pytest.raises(CheckpointError) as err:
        load_flow_model(path)
    msg = str(err.value)
    assert str(path) in msg
    assert "1 missing key(s): conv_1x1.4.0.bias" in msg
    assert "1 unexpected key(s): extra.weight" in msg
    assert "does not fit the flow network 'pwclite'" in msg
    assert "flow_estimators.conv1.0.weight (128, 198, 3, 3) (pwclite needs (128, 115, 3, 3))" in msg
    assert "3-frame" in msg


@pytest.mark.parametrize("content", [b"", b"hello, not a checkpoint\n", bytes(range(256)) * 4])
def test_not_a_checkpoint_file(tmp_path, content):
    path = tmp_path / "junk.pth.tar"
    path.write_bytes(content)
    with pytest.raises(CheckpointError, match=r"junk\.pth\.tar: not a readable torch checkpoint"):
        load_flow_model(path)


def test_checkpoint_of_something_else(tmp_path):
    path = tmp_path / "other.pt"
    torch.save({"epoch": 1, "losses": [0.1, 0.2]}, path)
    with pytest.raises(CheckpointError, match=r"other\.pt: not a checkpoint.*'epoch', 'losses'"):
        load_flow_model(path)
    torch.save(torch.zeros(3), path)
    with pytest.raises(CheckpointError, match="found Tensor"):
        load_flow_model(path)


def test_pickled_code_is_refused(tmp_path):
    path = tmp_path / "evil.pt"
    torch.save({"state_dict": {"x": torch.zeros(1)}, "obj": Path("x")}, path)  # needs a non-weights class
    with pytest.raises(CheckpointError, match="weights_only"):
        load_flow_model(path)


def test_missing_file(tmp_path):
    with pytest.raises(CheckpointError, match="not found"):
        load_flow_model(tmp_path / "nope.pt")


def test_own_format_round_trip(tmp_path):
    model = PWCLite()
    path = tmp_path / "models" / "flow.pt"
    save_flow_model(path, model, config={"source": "test"}, params={"lr": 1e-4})
    raw = torch.load(path, weights_only=True)
    assert raw["format"] == "f2depth.flow" and raw["version"] == 2
    assert raw["network"] == "pwclite" and raw["network_kwargs"] == {}
    assert set(raw) == {"format", "version", "network", "network_kwargs", "state_dict", "weights_sha256",
                        "config", "params"}
    loaded, meta = read_flow_checkpoint(path)
    assert meta["config"] == {"source": "test"} and meta["params"] == {"lr": 1e-4}
    assert meta["network"] == "pwclite" and isinstance(loaded, PWCLite) and not loaded.training
    assert _same_weights(loaded, raw["state_dict"]) and _same_weights(model, raw["state_dict"])


def test_a_damaged_flow_model_is_refused_and_one_without_a_digest_loads(tmp_path):
    """Issue 53 item 2: 64 flipped bytes in a weight leave the file loadable; the digest written with the
    weights refuses it, naming the file. A model written before the digest existed still loads."""
    model = PWCLite()
    path = tmp_path / "flow.pt"
    save_flow_model(path, model)
    fakes.flip_weight_bytes(path, 64)
    with pytest.raises(CheckpointError) as info:
        load_flow_model(path)
    assert str(info.value) == (f"{path}: damaged: its weights do not match the sha256 digest written with "
                               "them (the file changed after it was written); re-run the stage that wrote it "
                               "(`dvc repro flow_pretrain`, `dvc repro flow_finetune`)")
    older = torch.load(path, weights_only=True)
    del older["weights_sha256"]
    torch.save(older, tmp_path / "older.pt")
    assert isinstance(load_flow_model(tmp_path / "older.pt"), PWCLite)


def test_checkpoints_written_before_the_network_was_recorded_load_as_pwclite(tmp_path):
    model = PWCLite()
    path = tmp_path / "old.pt"
    torch.save({"format": "f2depth.pwclite", "version": 1, "state_dict": model.state_dict(),
                "config": {"origin": "synthetic"}, "params": {"lr": 4e-4}}, path)
    loaded, meta = read_flow_checkpoint(path)
    assert isinstance(loaded, PWCLite) and _same_weights(loaded, model.state_dict())
    assert (meta["format"], meta["version"], meta["network"]) == ("f2depth.pwclite", 1, "pwclite")
    assert meta["config"] == {"origin": "synthetic"} and meta["params"] == {"lr": 4e-4}


def test_own_format_wrong_kind_or_version(tmp_path):
    path = tmp_path / "m.pt"
    torch.save({"format": "f2depth.depth", "version": 1, "state_dict": {}}, path)
    with pytest.raises(CheckpointError, match="format 'f2depth.depth'"):
        load_flow_model(path)
    torch.save({"format": "f2depth.pwclite", "version": 2, "state_dict": PWCLite().state_dict()}, path)
    with pytest.raises(CheckpointError, match="f2depth.pwclite version 2"):
        load_flow_model(path)
    torch.save({"format": "f2depth.flow", "version": 3, "network": "pwclite", "state_dict": {}}, path)
    with pytest.raises(CheckpointError, match="flow version 3, this code reads f2depth.flow version 2"):
        load_flow_model(path)


def test_a_stage_given_a_bad_flow_checkpoint_ends_with_one_line(tmp_path, capsys):
    from f2depth.flow.net.checkpoint import load_flow_model
    from f2depth.stage import run_stage

    depth_model = tmp_path / "seed0.pt"
    torch.save({"format": "f2depth.depth", "state_dict": {}}, depth_model)
    for bad in (tmp_path / "missing.pt", depth_model):
        with pytest.raises(SystemExit) as exit_:
            run_stage("train_depth", lambda argv, p=bad: load_flow_model(p), [])
        assert exit_.value.code == 1
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and err.startswith(f"train_depth: {bad}: "), err
