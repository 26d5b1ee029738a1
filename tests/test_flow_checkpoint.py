"""Checkpoint import and our own format (f2depth.flow.checkpoint), with broken files made in tmp_path."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from f2depth.flow import PWCLite
from f2depth.flow.checkpoint import (
    CheckpointError,
    load_arflow_checkpoint,
    load_flow_model,
    read_flow_checkpoint,
    save_flow_model,
)

REF = Path(__file__).resolve().parents[2] / "shared" / "data" / "arflow_reference" / "pwclite_seed0.pth.tar"


@pytest.fixture(scope="module")
def ref_sd() -> dict[str, torch.Tensor]:
    assert REF.is_file(), f"reference checkpoint missing: {REF}"
    return torch.load(REF, map_location="cpu", weights_only=True)["state_dict"]


def _same_weights(model: PWCLite, sd: dict[str, torch.Tensor]) -> bool:
    return all(torch.equal(v, sd[k]) for k, v in model.state_dict().items())


def test_reference_checkpoint_loads_by_name(ref_sd):
    model = load_arflow_checkpoint(REF)
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
    assert _same_weights(load_arflow_checkpoint(path), ref_sd)
    assert _same_weights(load_flow_model(path), ref_sd)


def test_lists_missing_unexpected_and_misshaped_keys(tmp_path, ref_sd):
    sd = dict(ref_sd)
    del sd["conv_1x1.4.0.bias"]
    sd["extra.weight"] = torch.zeros(1)
    sd["flow_estimators.conv1.0.weight"] = torch.zeros(128, 198, 3, 3)  # 3-frame model shape
    path = tmp_path / "broken.pth.tar"
    torch.save({"state_dict": sd}, path)
    with pytest.raises(CheckpointError) as err:
        load_arflow_checkpoint(path)
    msg = str(err.value)
    assert str(path) in msg
    assert "1 missing key(s): conv_1x1.4.0.bias" in msg
    assert "1 unexpected key(s): extra.weight" in msg
    assert "flow_estimators.conv1.0.weight (128, 198, 3, 3) (PWC-Lite needs (128, 115, 3, 3))" in msg
    assert "3-frame" in msg


@pytest.mark.parametrize("content", [b"", b"hello, not a checkpoint\n", bytes(range(256)) * 4])
def test_not_a_checkpoint_file(tmp_path, content):
    path = tmp_path / "junk.pth.tar"
    path.write_bytes(content)
    with pytest.raises(CheckpointError, match=r"junk\.pth\.tar: not a PyTorch checkpoint"):
        load_arflow_checkpoint(path)


def test_checkpoint_of_something_else(tmp_path):
    path = tmp_path / "other.pt"
    torch.save({"epoch": 1, "losses": [0.1, 0.2]}, path)
    with pytest.raises(CheckpointError, match=r"other\.pt: not a checkpoint.*'epoch', 'losses'"):
        load_arflow_checkpoint(path)
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
    assert raw["format"] == "f2depth.pwclite" and raw["version"] == 1
    assert set(raw) == {"format", "version", "state_dict", "config", "params"}
    sd, meta = read_flow_checkpoint(path)
    assert meta["config"] == {"source": "test"} and meta["params"] == {"lr": 1e-4}
    assert _same_weights(load_flow_model(path), sd)
    assert all(torch.equal(v, sd[k]) for k, v in model.state_dict().items())


def test_own_format_wrong_kind_or_version(tmp_path):
    path = tmp_path / "m.pt"
    torch.save({"format": "f2depth.depth", "version": 1, "state_dict": {}}, path)
    with pytest.raises(CheckpointError, match="format 'f2depth.depth'"):
        load_flow_model(path)
    torch.save({"format": "f2depth.pwclite", "version": 2, "state_dict": PWCLite().state_dict()}, path)
    with pytest.raises(CheckpointError, match="version 2"):
        load_flow_model(path)
