"""Tests for f2depth.inference.export and the onnxruntime backend: parity, dynamic batch, metadata,
failed exports leave nothing, foreign ONNX files are refused."""

from __future__ import annotations

import fakes
import inference_data
import numpy as np
import onnx
import pytest
import torch

from f2depth.errors import DataError
from f2depth.inference.backends import OnnxBackend, TorchBackend, load_depth_model
from f2depth.inference.export import ExportError, export_onnx
from f2depth.inference.predict import Predictor


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    torch.set_num_threads(1)
    folder = tmp_path_factory.mktemp("onnx")
    ckpt = inference_data.make_checkpoint(folder / "depth.pt", seed=1)
    model = load_depth_model(ckpt)
    parity = export_onnx(model, folder / "depth.onnx", source=str(ckpt))
    return model, ckpt, folder / "depth.onnx", parity


def test_export_parity_and_metadata(exported):
    model, ckpt, path, parity = exported
    assert parity.hw == inference_data.NET_HW and parity.batch == 2
    assert parity.max_abs < 1e-4 and parity.max_rel < 1e-4
    meta = {p.key: p.value for p in onnx.load(str(path)).metadata_props}
    assert meta["format"] == "f2depth.depth.onnx" and meta["version"] == "1"
    assert (meta["height"], meta["width"], meta["source"]) == ("64", "96", str(ckpt))
    backend = OnnxBackend(path)
    assert backend.input_hw == (64, 96) and backend.max_depth == 10.0
    for batch in (1, 3):  # dynamic batch axis
        x = torch.rand(batch, 3, 64, 96, generator=torch.Generator().manual_seed(batch))
        with torch.no_grad():
            ref = model.predict_depth(x)
        torch.testing.assert_close(backend.depth(x), ref, rtol=1e-4, atol=1e-5)


def test_predict_through_onnx_matches_pytorch(exported):
    _, ckpt, path, _ = exported
    rgbs = [fakes.smooth_image((70, 90), 0), fakes.smooth_image((64, 96), 1)]
    for pp in (False, True):
        a = Predictor(TorchBackend.from_checkpoint(ckpt), post_process=pp).predict(rgbs)
        b = Predictor(OnnxBackend(path), post_process=pp).predict(rgbs)
        for x, y in zip(a, b):
            np.testing.assert_allclose(y, x, rtol=1e-4)


def test_export_at_another_size(exported, tmp_path):
    model = exported[0]
    parity = export_onnx(model, tmp_path / "big.onnx", height=96, width=128)
    assert parity.hw == (96, 128) and OnnxBackend(tmp_path / "big.onnx").input_hw == (96, 128)
    with pytest.raises(ValueError, match="multiples of 32"):
        export_onnx(model, tmp_path / "bad.onnx", height=100)
    assert not (tmp_path / "bad.onnx").exists()


def test_failed_parity_writes_nothing(exported, tmp_path):
    model = exported[0]
    with pytest.raises(ExportError, match="parity check failed"):
        export_onnx(model, tmp_path / "x.onnx", rtol=-1.0)
    assert list(tmp_path.iterdir()) == []


def test_foreign_onnx_files_are_refused(exported, tmp_path):
    path = exported[2]
    proto = onnx.load(str(path))
    del proto.metadata_props[:]
    onnx.save(proto, str(tmp_path / "plain.onnx"))
    with pytest.raises(DataError, match=r"plain\.onnx: ONNX model without f2depth metadata"):
        OnnxBackend(tmp_path / "plain.onnx")
    (tmp_path / "junk.onnx").write_bytes(b"junk")
    with pytest.raises(DataError, match=r"junk\.onnx: not a loadable ONNX model"):
        OnnxBackend(tmp_path / "junk.onnx")
    with pytest.raises(DataError, match="ONNX model not found"):
        OnnxBackend(tmp_path / "none.onnx")
