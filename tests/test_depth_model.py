"""Tests for f2depth.depth: networks' shapes and ranges, pose convention, checkpoints."""

from __future__ import annotations

import pytest
import torch

from f2depth.depth import (
    DepthModel,
    DepthModelConfig,
    disp_to_depth,
    load_checkpoint,
    read_checkpoint,
    save_checkpoint,
)
from f2depth.depth.decoder import DepthDecoder, sigmoid_input_for_depth
from f2depth.depth.encoder import ResnetEncoder
from f2depth.depth.resnet import ResNet
from f2depth.errors import CheckpointError


@pytest.fixture(scope="module")
def model() -> DepthModel:
    torch.manual_seed(0)
    return DepthModel(DepthModelConfig(height=64, width=96)).eval()


def test_encoder_decoder_shapes():
    enc = ResnetEncoder(18)
    feats = enc(torch.rand(2, 3, 64, 96))
    assert [tuple(f.shape) for f in feats] == [
        (2, 64, 32, 48),
        (2, 64, 16, 24),
        (2, 128, 8, 12),
        (2, 256, 4, 6),
        (2, 512, 2, 3),
    ]
    for mode in ("nearest", "bilinear"):
        disp = DepthDecoder(upsample_mode=mode)(feats)
        assert disp.shape == (2, 1, 64, 96)
        assert (disp > 0).all() and (disp < 1).all()
    with pytest.raises(ValueError, match="upsample_mode"):
        DepthDecoder(upsample_mode="cubic")


def test_decoder_layout_is_monodepth2():
    dec = DepthDecoder()
    names = {k: tuple(v.shape) for k, v in dec.state_dict().items()}
    assert names["convs.upconv_4_0.conv.weight"] == (256, 512, 3, 3)
    assert names["convs.upconv_4_1.conv.weight"] == (256, 256 + 256, 3, 3)
    assert names["convs.upconv_1_1.conv.weight"] == (32, 32 + 64, 3, 3)
    assert names["convs.upconv_0_1.conv.weight"] == (16, 16, 3, 3)
    assert names["dispconv.weight"] == (1, 16, 3, 3)


def test_disp_to_depth_range():
    disp = torch.tensor([0.0, 0.5, 1.0])
    scaled, depth = disp_to_depth(disp, 0.1, 10.0)
    assert depth[0].item() == pytest.approx(10.0) and depth[2].item() == pytest.approx(0.1)
    assert torch.allclose(scaled * depth, torch.ones(3))


def test_sigmoid_input_for_depth_inverts_disp_to_depth():
    # hand-computed: 2 m in [0.1, 10] → disp = (0.5 − 0.1) / (10 − 0.1) = 0.040404,
    # x = ln(0.040404 / 0.959596) = ln(0.042105) = −3.16758
    assert sigmoid_input_for_depth(2.0) == pytest.approx(-3.16758, abs=1e-5)
    assert sigmoid_input_for_depth(1 / (0.1 + 9.9 * 0.5)) == pytest.approx(0.0, abs=1e-12)  # sigmoid 0.5
    for depth, lo, hi in ((0.3, 0.1, 10.0), (2.0, 0.1, 10.0), (9.5, 0.1, 10.0), (40.0, 0.5, 80.0)):
        x = torch.tensor(sigmoid_input_for_depth(depth, lo, hi), dtype=torch.float64)
        assert disp_to_depth(torch.sigmoid(x), lo, hi)[1].item() == pytest.approx(depth, rel=1e-9)
    for bad in (0.1, 10.0, 0.05, 12.0):
        with pytest.raises(ValueError, match="strictly between"):
            sigmoid_input_for_depth(bad)


def test_set_initial_depth_moves_the_untrained_prediction():
    torch.manual_seed(0)
    m = DepthModel(DepthModelConfig(height=64, width=64)).eval()
    img = torch.rand(2, 3, 64, 64)
    with torch.no_grad():
        assert m.predict_depth(img).median().item() == pytest.approx(0.198, abs=0.01)  # sigmoid ≈ 0.5
        weights = {k: v.clone() for k, v in m.state_dict().items()}
        for target in (0.5, 2.0, 5.0):
            m.set_initial_depth(target)
            depth = m.predict_depth(img)
            assert depth.median().item() == pytest.approx(target, rel=0.05)
            assert depth.std().item() > 0  # the random weights still vary the output
    changed = [k for k, v in m.state_dict().items() if not torch.equal(v, weights[k])]
    assert changed == ["depth_decoder.dispconv.bias"]
    with pytest.raises(ValueError, match="strictly between"):
        m.set_initial_depth(10.0)


def test_model_depth_and_pose(model):
    img = torch.rand(2, 3, 64, 96)
    with torch.no_grad():
        depth = model.predict_depth(img)
        assert depth.shape == (2, 1, 64, 96)
        assert (depth >= 0.1 - 1e-6).all() and (depth <= 10.0 + 1e-5).all()
        img2 = torch.rand(2, 3, 64, 96)
        T = model.predict_pose(img, img2)
        Ti = model.predict_pose(img, img2, invert=True)
    assert T.shape == (2, 4, 4)
    assert torch.allclose(T @ Ti, torch.eye(4).expand(2, 4, 4), atol=1e-5)
    assert torch.allclose(T[:, 3], torch.tensor([0.0, 0.0, 0.0, 1.0]).expand(2, 4))
    with torch.no_grad():
        disp, depth2, poses = model(img, [(img, img2, False), (img2, img, True)])
    assert torch.equal(depth2, depth) and torch.allclose(disp_to_depth(disp)[1], depth)
    assert torch.equal(poses[0], T)
    with torch.no_grad():
        assert torch.allclose(poses[1], model.predict_pose(img2, img, invert=True))
    names = [n for n, _ in model.named_children()]
    assert names == ["depth_encoder", "depth_decoder", "pose_encoder", "pose_decoder"]
    assert model.pose_encoder.conv1.weight.shape == (64, 6, 7, 7)
    assert model.pose_decoder.pose_2.weight.shape == (12, 256, 1, 1)


def test_input_normalisation():
    enc = ResnetEncoder(18).eval()
    ref = ResNet(18, 3).eval()
    ref.load_state_dict(enc.state_dict())
    x = torch.rand(1, 3, 32, 32)
    with torch.no_grad():
        assert torch.allclose(enc(x)[-1], ref.features((x - 0.45) / 0.225)[-1])


def test_config_validation():
    with pytest.raises(ValueError, match="multiples of 32"):
        DepthModelConfig(height=100, width=128)
    with pytest.raises(ValueError, match="min_depth"):
        DepthModelConfig(height=64, width=64, min_depth=5, max_depth=1)
    with pytest.raises(ValueError, match="unknown DepthModelConfig keys"):
        DepthModelConfig.from_dict({"height": 64, "width": 64, "depth_net": "x"})
    cfg = DepthModelConfig(height=64, width=96, upsample_mode="bilinear")
    assert DepthModelConfig.from_dict(cfg.to_dict()) == cfg


def test_checkpoint_round_trip(tmp_path, model):
    path = tmp_path / "depth.pt"
    save_checkpoint(path, model, params={"weights": {"feature": 3.0}}, epoch=2)
    ckpt = read_checkpoint(path)
    assert ckpt["format"] == "f2depth.depth" and ckpt["version"] == 1 and ckpt["epoch"] == 2
    assert ckpt["params"] == {"weights": {"feature": 3.0}}
    loaded = load_checkpoint(path).eval()
    assert loaded.config == model.config
    img = torch.rand(1, 3, 64, 96)
    with torch.no_grad():
        assert torch.equal(loaded.predict_depth(img), model.predict_depth(img))


def test_checkpoint_errors(tmp_path, model):
    # Small hand-made checkpoints: every check fires before any weights are needed.
    ckpt = {
        "format": "f2depth.depth",
        "version": 1,
        "state_dict": {},
        "config": model.config.to_dict(),
        "params": {},
    }
    cases = {
        "format": ({**ckpt, "format": "f2depth.pwclite"}, "not a DepthCNN/PoseCNN checkpoint"),
        "version": ({**ckpt, "version": 7}, "version 7 is not supported"),
        "keys": ({k: v for k, v in ckpt.items() if k != "config"}, r"lacks \['config'\]"),
        "config": ({**ckpt, "config": {**ckpt["config"], "encoder": "vit"}}, "unknown DepthModelConfig keys"),
        "state": (
            {**ckpt, "state_dict": {"depth_encoder.conv1.weight": torch.zeros(64, 3, 7, 7)}},
            "missing",
        ),
    }
    for name, (bad, msg) in cases.items():
        p = tmp_path / f"{name}.pt"
        torch.save(bad, p)
        with pytest.raises(CheckpointError, match=msg):  # a DataError: one line in a stage
            load_checkpoint(p)
    with pytest.raises(CheckpointError, match="train_depth"):
        load_checkpoint(tmp_path / "missing.pt")
    with pytest.raises(ValueError, match="clash"):
        save_checkpoint(tmp_path / "x.pt", model, format="other")


def test_model_load_imagenet(tmp_path):
    torch.manual_seed(1)
    ref = ResNet(18, 3, num_classes=1000)
    torch.save(ref.state_dict(), tmp_path / "r18.pth")
    m = DepthModel(DepthModelConfig(height=32, width=32))
    m.load_imagenet(tmp_path / "r18.pth")
    assert torch.equal(m.depth_encoder.layer2[0].conv1.weight, ref.layer2[0].conv1.weight)
    assert torch.allclose(m.pose_encoder.conv1.weight[:, 3:], ref.conv1.weight / 2)


@pytest.mark.parametrize("content", [b"", b"\x00\x01\x02\x03", b"PK\x03\x04 not a zip"])
def test_junk_checkpoint_files_give_a_clear_error(tmp_path, content):
    path = tmp_path / "junk.pt"
    path.write_bytes(content)
    with pytest.raises(ValueError, match="junk.pt: not a readable torch checkpoint"):
        read_checkpoint(path)


def test_the_inference_copy_folds_batchnorm_and_predicts_the_same_depth():
    """Issue 26 item 3: BatchNorm folded into the convolutions (f2depth.depth.fused) gives the training
    graph's depth to 1e-5 relative, on BatchNorm statistics far from the identity; the model is untouched."""
    from torch import nn

    from f2depth.depth.fused import fold_batchnorm, inference_copy

    torch.manual_seed(0)
    model = DepthModel(DepthModelConfig(height=64, width=96)).eval()
    g = torch.Generator().manual_seed(1)
    with torch.no_grad():
        for m in model.modules():
            if isinstance(m, nn.BatchNorm2d):
                m.running_mean.copy_(torch.rand(m.num_features, generator=g) - 0.5)
                m.running_var.copy_(0.3 + 2 * torch.rand(m.num_features, generator=g))
                m.weight.copy_(0.5 + torch.rand(m.num_features, generator=g))
                m.bias.copy_(0.4 * torch.rand(m.num_features, generator=g) - 0.2)
    fused = inference_copy(model)
    assert not any(isinstance(m, nn.BatchNorm2d) for m in fused.depth_encoder.modules())
    assert sum(isinstance(m, nn.BatchNorm2d) for m in model.depth_encoder.modules()) == 20  # untouched
    x = torch.rand(2, 3, 64, 96, generator=g)
    with torch.inference_mode():
        ref = model.predict_depth(x)
        got = fused.to(memory_format=torch.channels_last).predict_depth(
            x.contiguous(memory_format=torch.channels_last))
        pose_ref = model.predict_pose(x, x.flip(-1), False)
        pose_got = fused.predict_pose(x, x.flip(-1), False)
    rel = ((got - ref).abs() / ref.abs()).max()
    assert rel < 1e-5 and ref.std() / ref.mean() > 0.005  # a varying depth map, not a constant
    assert torch.allclose(pose_got, pose_ref, rtol=1e-4, atol=1e-6)
    conv, bn = nn.Conv2d(3, 4, 3, padding=1, bias=True).double(), nn.BatchNorm2d(4).double().eval()
    with torch.no_grad():
        bn.running_mean.copy_(torch.tensor([0.1, -0.2, 0.3, 0.0]))
        bn.running_var.copy_(torch.tensor([0.5, 2.0, 1.0, 0.1]))
        bn.weight.copy_(torch.tensor([1.5, 0.5, -1.0, 2.0]))
        bn.bias.copy_(torch.tensor([0.0, 0.1, -0.1, 0.3]))
        u = torch.randn(1, 3, 8, 8, dtype=torch.float64, generator=g)
        assert torch.allclose(fold_batchnorm(conv, bn)(u), bn(conv(u)), atol=1e-12)


def test_the_cpu_layout_runs_layer4_in_nchw_and_the_rest_channels_last_with_the_same_depth():
    """Issue 26 item 3: the inference copy's CPU layout (f2depth.depth.fused.cpu_layout) keeps the
    training graph's depth (1e-5 relative) and the parameter names; layer4's weights and its input are
    NCHW, every other convolution's weights channels-last."""
    from torch import nn

    from f2depth.depth.fused import cpu_layout, inference_copy
    from f2depth.inference.backends import TorchBackend

    torch.manual_seed(0)
    model = DepthModel(DepthModelConfig(height=64, width=96)).eval()
    copy = cpu_layout(inference_copy(model))
    encoder = copy.depth_encoder
    assert encoder.state_dict().keys() == inference_copy(model).depth_encoder.state_dict().keys()
    for name, m in copy.named_modules():
        if isinstance(m, nn.Conv2d) and m.kernel_size != (1, 1):
            nchw = name.startswith("depth_encoder.layer4.")
            assert m.weight.is_contiguous(memory_format=torch.contiguous_format if nchw
                                          else torch.channels_last), name
    seen = []
    hook = encoder.layer4[0].conv1.register_forward_pre_hook(lambda m, a: seen.append(a[0].is_contiguous()))
    x = torch.rand(2, 3, 64, 96, generator=torch.Generator().manual_seed(4))
    with torch.inference_mode():
        ref = model.predict_depth(x)
        got = TorchBackend(model).depth(x)
        copy.predict_depth(x.contiguous(memory_format=torch.channels_last))
    hook.remove()
    assert seen == [True]
    assert float(((got - ref).abs() / ref.abs()).max()) < 1e-5 and ref.std() / ref.mean() > 0.005


def test_the_inference_decoder_folds_the_upsampling_into_the_convolution_with_the_same_values():
    """Issue 26 item 3: each upconv_i_1 of f2depth.depth.fused.InferenceDecoder (2×2 phase kernels on the
    low-resolution input, the skip part at full resolution) equals the 3×3 convolution of
    reflection_pad(cat(nearest_upsample(x), skip)) to float64 rounding (odd sizes, with and without a
    skip); the whole decoder gives the DepthDecoder's disparity; bilinear decoders keep the training
    graph's decoder."""
    import torch.nn.functional as F

    from f2depth.depth.decoder import DepthDecoder
    from f2depth.depth.fused import InferenceDecoder, inference_copy

    g = torch.Generator().manual_seed(3)
    decoder = DepthDecoder().double()
    fused = InferenceDecoder(decoder)
    for i, (h, w) in ((4, (3, 7)), (1, (5, 4)), (0, (2, 5))):
        conv = decoder.convs[f"upconv_{i}_1"].conv
        up = decoder.convs[f"upconv_{i}_0"].conv.out_channels
        x = torch.randn(2, up, h, w, generator=g, dtype=torch.float64)
        skip = (torch.randn(2, conv.in_channels - up, 2 * h, 2 * w, generator=g, dtype=torch.float64)
                if i > 0 else None)
        parts = [F.interpolate(x, scale_factor=2, mode="nearest")] + ([skip] if i > 0 else [])
        ref = conv(F.pad(torch.cat(parts, 1), (1, 1, 1, 1), mode="reflect"))
        with torch.no_grad():
            got = fused.upconv(i, x, skip)
        assert got.shape == ref.shape and torch.allclose(got, ref, rtol=0, atol=1e-12), i
    with pytest.raises(ValueError, match="does not match"):
        fused.upconv(3, torch.zeros(1, 128, 3, 3, dtype=torch.float64),
                     torch.zeros(1, 128, 5, 6, dtype=torch.float64))
    torch.manual_seed(0)
    model = DepthModel(DepthModelConfig(height=64, width=96)).eval()
    copy = inference_copy(model)
    assert isinstance(copy.depth_decoder, InferenceDecoder)
    assert copy.depth_decoder.state_dict().keys() == model.depth_decoder.state_dict().keys()
    feats = [f.contiguous(memory_format=torch.channels_last)
             for f in model.depth_encoder(torch.rand(2, 3, 64, 96, generator=g))]
    with torch.inference_mode():
        ref, got = model.depth_decoder(feats), copy.depth_decoder(feats)
    assert torch.allclose(got, ref, rtol=0, atol=1e-6) and ref.std() > 0
    bilinear = DepthModel(DepthModelConfig(height=64, width=96, upsample_mode="bilinear"))
    assert not isinstance(inference_copy(bilinear).depth_decoder, InferenceDecoder)
