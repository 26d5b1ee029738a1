"""Tests for f2depth.depth.resnet: torchvision-compatible names, ImageNet loading, 6-channel init."""

from __future__ import annotations

import pytest
import torch

from f2depth.depth.encoder import ResnetEncoder
from f2depth.depth.resnet import ResNet, load_imagenet_resnet

BN = ("weight", "bias", "running_mean", "running_var", "num_batches_tracked")


def torchvision_resnet18_keys() -> list[str]:
    """The state_dict names of torchvision.models.resnet18, written out from its documented layout."""
    keys = ["conv1.weight"] + [f"bn1.{s}" for s in BN]
    for layer in range(1, 5):
        for block in range(2):
            p = f"layer{layer}.{block}"
            keys += [f"{p}.conv1.weight"] + [f"{p}.bn1.{s}" for s in BN]
            keys += [f"{p}.conv2.weight"] + [f"{p}.bn2.{s}" for s in BN]
            if layer > 1 and block == 0:
                keys += [f"{p}.downsample.0.weight"] + [f"{p}.downsample.1.{s}" for s in BN]
    return keys + ["fc.weight", "fc.bias"]


def test_names_match_torchvision():
    expected = torchvision_resnet18_keys()
    assert len(expected) == 122
    assert list(ResNet(18, 3, num_classes=1000).state_dict()) == expected
    # The encoder is the same tree without the classifier.
    assert list(ResnetEncoder(18).state_dict()) == expected[:-2]
    shapes = ResNet(18, 3, num_classes=1000).state_dict()
    assert shapes["layer3.0.downsample.0.weight"].shape == (256, 128, 1, 1)
    assert shapes["fc.weight"].shape == (1000, 512)
    n_params = sum(p.numel() for p in ResNet(18, 3, num_classes=1000).parameters())
    assert n_params == 11_689_512  # torchvision's resnet18 parameter count


def _fake_imagenet_file(tmp_path, drop_nbt: bool = False):
    torch.manual_seed(0)
    net = ResNet(18, 3, num_classes=1000)
    for p in net.parameters():
        p.data.normal_()
    state = net.state_dict()
    if drop_nbt:  # older torchvision files have no num_batches_tracked
        state = {k: v for k, v in state.items() if not k.endswith("num_batches_tracked")}
    path = tmp_path / "resnet18.pth"
    torch.save(state, path)
    return path, state


@pytest.mark.parametrize("drop_nbt", [False, True])
def test_imagenet_state_dict_loads_by_path(tmp_path, drop_nbt):
    path, state = _fake_imagenet_file(tmp_path, drop_nbt)
    loaded = load_imagenet_resnet(path, 18)
    enc = ResnetEncoder(18)
    enc.load_imagenet(loaded)
    for k, v in enc.state_dict().items():
        if not k.endswith("num_batches_tracked"):
            assert torch.equal(v, state[k]), k


def test_six_channel_conv_is_halved_duplicate(tmp_path):
    path, state = _fake_imagenet_file(tmp_path)
    enc = ResnetEncoder(18, num_input_images=2)
    enc.load_imagenet(load_imagenet_resnet(path, 18))
    w = enc.conv1.weight.detach()
    assert w.shape == (64, 6, 7, 7)
    assert torch.allclose(w[:, :3], state["conv1.weight"] / 2)
    assert torch.allclose(w[:, 3:], state["conv1.weight"] / 2)
    assert torch.equal(enc.layer4[1].conv2.weight, state["layer4.1.conv2.weight"])
    # Same image twice → same first-layer response as the 3-channel ImageNet conv.
    x = torch.rand(1, 3, 32, 32)
    ref = torch.nn.functional.conv2d(x, state["conv1.weight"], stride=2, padding=3)
    assert torch.allclose(enc.conv1(torch.cat((x, x), 1)), ref, atol=1e-4)


def test_wrong_files_raise_clear_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="imagenet_weights"):
        load_imagenet_resnet(tmp_path / "nope.pth", 18)
    path, state = _fake_imagenet_file(tmp_path)
    bad = dict(state)
    del bad["layer2.0.downsample.0.weight"]
    bad["head.weight"] = torch.zeros(1)
    torch.save(bad, tmp_path / "bad.pth")
    with pytest.raises(ValueError, match=r"bad\.pth.*missing.*layer2\.0\.downsample\.0\.weight"):
        load_imagenet_resnet(tmp_path / "bad.pth", 18)
    wrong = dict(state)
    wrong["layer1.0.conv1.weight"] = torch.zeros(64, 64, 1, 1)
    torch.save(wrong, tmp_path / "wrong.pth")
    with pytest.raises(ValueError, match="layer1.0.conv1.weight has shape"):
        load_imagenet_resnet(tmp_path / "wrong.pth", 18)
    (tmp_path / "text.pth").write_text("not a checkpoint")
    with pytest.raises(ValueError, match="text.pth"):
        load_imagenet_resnet(tmp_path / "text.pth", 18)


def test_random_init_is_torchvision_style():
    torch.manual_seed(0)
    enc = ResnetEncoder(18)
    assert torch.equal(enc.bn1.weight, torch.ones(64)) and torch.equal(enc.bn1.bias, torch.zeros(64))
    std = enc.layer1[0].conv1.weight.std().item()
    assert abs(std - (2.0 / (64 * 9)) ** 0.5) < 0.01  # Kaiming fan_out
