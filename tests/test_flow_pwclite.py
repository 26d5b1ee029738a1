"""PWC-Lite (f2depth.flow.net.pwclite): ARFlow's parameter names, exact outputs, sizes, features."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from f2depth.flow import PWCLite, load_flow_model

REF_DIR = Path(__file__).resolve().parent / "data" / "arflow"


@pytest.fixture(scope="module")
def ref():
    assert (REF_DIR / "pwclite_seed0_io.npz").is_file(), f"reference bundle missing: {REF_DIR}"
    return dict(np.load(REF_DIR / "pwclite_seed0_io.npz"))


def test_parameter_names_shapes_and_order_equal_arflow():
    lines = (REF_DIR / "pwclite_state_dict_keys.txt").read_text().splitlines()
    expected = [tuple(line.split("\t")[:2]) for line in lines if not line.startswith("TOTAL")]
    assert len(expected) == 60
    sd = PWCLite().state_dict()
    assert [(k, str(tuple(v.shape))) for k, v in sd.items()] == expected
    assert sum(v.numel() for v in sd.values()) == 2_236_660


@pytest.mark.parametrize(("dtype", "channels_last"), [(torch.float32, True), (torch.float32, False),
                                                       (torch.float64, True)])
def test_reproduces_the_official_flows_within_1e4(ref, dtype, channels_last):
    model = PWCLite(channels_last=channels_last)
    model.load_state_dict(load_flow_model(REF_DIR / "pwclite_seed0.pth.tar").state_dict())
    model = model.to(dtype).eval()
    x = torch.from_numpy(ref["input"]).to(dtype)
    with torch.no_grad():
        flows_fw, flows_bw = model(x[:, :3], x[:, 3:], with_backward=True)
    assert len(flows_fw) == len(flows_bw) == 5
    for i in range(5):
        for name, flows in (("fw", flows_fw), ("bw", flows_bw)):
            expected = ref[f"flows_{name}_{i}"]
            assert flows[i].shape == expected.shape
            err = np.abs(flows[i].double().numpy() - expected).max()
            assert err <= 1e-4, f"flows_{name}_{i}: max error {err:.2e}"


def test_forward_only_equals_the_forward_half(ref):
    model = load_flow_model(REF_DIR / "pwclite_seed0.pth.tar")
    x = torch.from_numpy(ref["input"])
    with torch.no_grad():
        fw, bw = model(x[:, :3], x[:, 3:], with_backward=False)
    assert bw is None
    assert np.abs(fw[0].numpy() - ref["flows_fw_0"]).max() <= 1e-4


def test_sizes_not_multiple_of_64_are_resized_and_rescaled():
    model = PWCLite().eval()
    torch.manual_seed(0)
    a, b = torch.rand(2, 3, 96, 136), torch.rand(2, 3, 96, 136)
    with torch.no_grad():
        fw, bw = model(a, b)
        # the same pair resized by hand to 128×192, flow resized back with u·136/192, v·96/128
        big = [torch.nn.functional.interpolate(t, size=(128, 192), mode="bilinear", align_corners=True)
               for t in (a, b)]
        ref_fw, _ = model(*big)
    assert [tuple(f.shape[-2:]) for f in fw] == [(96, 136), (48, 68), (24, 34), (12, 17), (6, 9)]
    back = torch.nn.functional.interpolate(ref_fw[0], size=(96, 136), mode="bilinear", align_corners=True)
    back = back * torch.tensor([136 / 192, 96 / 128]).view(1, 2, 1, 1)
    assert torch.allclose(fw[0], back, atol=1e-5)


def test_features_six_levels_finest_first():
    model = PWCLite()
    feats = model.features(torch.rand(2, 3, 96, 128))
    assert [f.shape[1] for f in feats] == [16, 32, 64, 96, 128, 192]
    assert [tuple(f.shape[-2:]) for f in feats] == [(48, 64), (24, 32), (12, 16), (6, 8), (3, 4), (2, 2)]


def test_gradients_reach_every_parameter():
    model = PWCLite()
    a, b = torch.rand(1, 3, 64, 64), torch.rand(1, 3, 64, 64)
    fw, bw = model(a, b)
    sum(f.abs().mean() for f in fw + bw).backward()
    assert all(p.grad is not None and torch.isfinite(p.grad).all() for p in model.parameters())
    assert sum(int(p.grad.abs().sum() > 0) for p in model.parameters()) == 60


def test_rejects_bad_inputs():
    with pytest.raises(ValueError, match=r"\(B,3,H,W\)"):
        PWCLite()(torch.rand(1, 3, 64, 64), torch.rand(1, 3, 64, 32))
