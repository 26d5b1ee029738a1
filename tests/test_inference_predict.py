"""Tests for f2depth.inference.predict / scaling / backends: sizes, batching, post-processing, scaling,
atomic outputs of an interrupted run, checkpoint errors."""

from __future__ import annotations

import cv2
import fakes
import inference_data
import numpy as np
import pytest
import torch

from f2depth.errors import DataError
from f2depth.inference.backends import TorchBackend, load_backend
from f2depth.inference.predict import Predictor, PredictSettings, run_predict
from f2depth.inference.scaling import median_ratio, read_reference_depth
from f2depth.ingest.sources import Frame, open_source
from f2depth.io import OUTPUT_MARKER


@pytest.fixture(scope="module")
def ckpt(tmp_path_factory):
    return inference_data.make_checkpoint(tmp_path_factory.mktemp("model") / "depth.pt")


@pytest.fixture(scope="module")
def backend(ckpt):
    torch.set_num_threads(1)
    return TorchBackend.from_checkpoint(ckpt, "cpu")


def test_backend_from_checkpoint(backend, ckpt):
    assert backend.input_hw == inference_data.NET_HW and not backend.model.training
    assert (backend.min_depth, backend.max_depth) == (0.1, 10.0)
    x = torch.rand(2, 3, *backend.input_hw)
    d = backend.depth(x)
    assert d.shape == (2, 1, *backend.input_hw) and float(d.min()) >= 0.1 and float(d.max()) <= 10.0
    assert load_backend(model=ckpt).name == "pytorch"


def test_depth_has_each_input_size_and_batching_is_exact(backend):
    rgbs = [fakes.smooth_image(hw, i) for i, hw in enumerate([(60, 80), (45, 70), (64, 96), (100, 90)])]
    predictor = Predictor(backend)
    together = predictor.predict(rgbs)
    alone = [predictor.predict([r])[0] for r in rgbs]
    for rgb, a, b in zip(rgbs, together, alone):
        assert a.shape == rgb.shape[:2] and a.dtype == np.float32
        np.testing.assert_allclose(a, b, rtol=1e-5)
        assert a.min() >= 0.1 and a.max() <= 10.0


def test_nearest_upsampling_keeps_network_values(backend):
    rgb = fakes.smooth_image((128, 192), 3)  # exactly 2× the network size
    near = Predictor(backend, upsample="nearest").predict([rgb])[0]
    small = Predictor(backend).predict([cv2.resize(rgb, (96, 64), interpolation=cv2.INTER_AREA)])[0]
    np.testing.assert_allclose(near[::2, ::2], small, rtol=1e-5)


def test_post_processing_gives_mirror_symmetric_depth_on_a_symmetric_image(backend):
    half = fakes.smooth_image((64, 48), 4)
    rgb = np.concatenate([half, half[:, ::-1]], axis=1)  # mirror-symmetric 64×96
    plain = Predictor(backend).predict([rgb])[0]
    pp = Predictor(backend, post_process=True).predict([rgb])[0]
    np.testing.assert_allclose(pp, pp[:, ::-1], rtol=1e-5)
    assert np.abs(plain - plain[:, ::-1]).max() > 1e-4  # the network itself is not symmetric
    assert np.abs(pp - plain).max() > 1e-5


def test_reference_depth_units(tmp_path):
    depth = np.full((20, 30), 2.5, np.float32)
    depth[0, 0] = 0
    mm = np.rint(depth * 1000).astype(np.uint16)
    mm[1, 1] = 65535
    cv2.imwrite(str(tmp_path / "ref.png"), mm)
    np.save(tmp_path / "ref.npy", depth)
    png, npy = read_reference_depth(tmp_path / "ref.png"), read_reference_depth(tmp_path / "ref.npy")
    assert png[0, 0] == 0 and png[1, 1] == 0 and png[2, 2] == pytest.approx(2.5)
    assert npy[0, 0] == 0 and npy[2, 2] == 2.5
    assert median_ratio(np.full((10, 15), 0.5, np.float32), png) == pytest.approx(5.0)  # resized to ref
    with pytest.raises(DataError, match="no valid pixel"):
        median_ratio(np.ones((20, 30)), np.zeros((20, 30), np.float32))
    cv2.imwrite(str(tmp_path / "rgb.png"), fakes.smooth_image((8, 8), 0))
    with pytest.raises(DataError, match=r"rgb\.png: expected a single-channel 16-bit image"):
        read_reference_depth(tmp_path / "rgb.png")
    with pytest.raises(DataError, match=r"unsupported reference depth type '\.txt'"):
        read_reference_depth(tmp_path / "ref.txt")


def _frames(tmp_path, n=3):
    inference_data.write_images(tmp_path / "in", n)
    return open_source(tmp_path / "in")


def test_scale_and_scale_from(backend, tmp_path):
    frames = _frames(tmp_path)
    predictor = Predictor(backend)
    raw = run_predict(frames, predictor, PredictSettings(tmp_path / "raw", batch_size=2, progress=False))
    assert raw["scale"] == 1.0 and not raw["metric"] and raw["frames"] == 3
    s = run_predict(frames, predictor, PredictSettings(tmp_path / "s", scale=2.5, progress=False))
    assert s["metric"] and s["scale_source"] == "--scale"
    for name in ("img_00", "img_02"):
        a, b = np.load(tmp_path / "raw" / f"{name}_depth.npy"), np.load(tmp_path / "s" / f"{name}_depth.npy")
        np.testing.assert_allclose(b, 2.5 * a, rtol=1e-6)
    ref = np.full((60, 80), 3.0, np.float32)
    ref[:10] = 0  # invalid rows are not counted
    ref[10:20] = 4.0
    np.save(tmp_path / "ref.npy", ref)
    m = run_predict(frames, predictor, PredictSettings(tmp_path / "m", scale_from=tmp_path / "ref.npy",
                                                       progress=False))
    first = np.load(tmp_path / "m" / "img_00_depth.npy")
    assert np.median(first[ref > 0]) == pytest.approx(3.0, rel=1e-5)
    ratio = m["scale"]
    np.testing.assert_allclose(np.load(tmp_path / "m" / "img_02_depth.npy"),
                               ratio * np.load(tmp_path / "raw" / "img_02_depth.npy"), rtol=1e-5)
    assert m["metric"] and "ref.npy" in m["scale_source"]
    with pytest.raises(ValueError, match="not both"):
        run_predict(frames, predictor, PredictSettings(tmp_path / "x", scale=1.0, scale_from=tmp_path / "r"))


def test_interrupted_run_leaves_complete_files_only(backend, tmp_path):
    good = [Frame(f"f{i}", fakes.smooth_image((40, 50), i), "mem") for i in range(3)]

    def frames():
        yield from good
        raise DataError(tmp_path / "bad.png", "unreadable image")

    with pytest.raises(DataError, match="bad.png"):
        run_predict(frames(), Predictor(backend), PredictSettings(tmp_path / "out", batch_size=2, ply=True,
                                                                  progress=False))
    names = sorted(p.name for p in (tmp_path / "out").iterdir() if p.name != OUTPUT_MARKER)
    assert not [n for n in names if n.startswith(".")]  # no temporary files
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]  # no temporary folder, no lock file
    assert "predict.json" not in names
    assert len(names) == 8  # frames f0, f1 (first batch) with 4 files each; the second batch never ran
    for i in range(2):
        assert np.load(tmp_path / "out" / f"f{i}_depth.npy").shape == (40, 50)
        mm = cv2.imread(str(tmp_path / "out" / f"f{i}_depth_mm.png"), cv2.IMREAD_UNCHANGED)
        assert mm.dtype == np.uint16


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ({"format": "f2depth.pwclite", "version": 1, "state_dict": {}}, "not 'f2depth.depth'"),
        ("version99", "checkpoint version 99 is not supported"),
        (b"not a checkpoint", "not a readable torch checkpoint"),
        (b"junk", "not a readable torch checkpoint"),
        (b"", "not a readable torch checkpoint"),
        (None, "depth checkpoint not found"),
    ],
)
def test_bad_checkpoints(ckpt, tmp_path, content, message):
    path = tmp_path / "model.pt"
    if content == "version99":
        data = torch.load(ckpt, weights_only=True)
        data["version"] = 99
        torch.save(data, path)
    elif isinstance(content, bytes):
        path.write_bytes(content)
    elif content is not None:
        torch.save(content, path)
    with pytest.raises(DataError, match=message) as info:
        TorchBackend.from_checkpoint(path)
    assert str(info.value).startswith(str(path)) and len(str(info.value)) <= 300


def test_the_torch_backend_runs_the_inference_copy_with_the_trained_depth(ckpt, backend):
    """predict's PyTorch path (BatchNorm folded, channels-last) = the checkpoint's training graph."""
    from f2depth.inference.backends import load_depth_model

    model = load_depth_model(ckpt)
    x = torch.rand(2, 3, *backend.input_hw, generator=torch.Generator().manual_seed(3))
    with torch.inference_mode():
        ref = model.predict_depth(x)
    got = backend.depth(x)
    assert got.is_contiguous() and got.shape == ref.shape
    assert float(((got - ref).abs() / ref.abs()).max()) < 1e-5
    assert not any(isinstance(m, torch.nn.BatchNorm2d) for m in backend.model.depth_encoder.modules())
