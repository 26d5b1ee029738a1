"""The PWC-Lite cost volume (f2depth.flow.net.correlation): semantics, gradients, both inputs, odd sizes."""

from __future__ import annotations

import pytest
import torch

from f2depth.flow.net.correlation import correlation, correlation_reference


def _explicit(f1: torch.Tensor, f2: torch.Tensor, b: int, y: int, x: int, dy: int, dx: int) -> float:
    """One output element from the definition (zero outside the image, mean over channels)."""
    h, w = f1.shape[-2:]
    if not (0 <= y + dy < h and 0 <= x + dx < w):
        return 0.0
    return float((f1[b, :, y, x] * f2[b, :, y + dy, x + dx]).mean())


def test_matches_the_definition_elementwise():
    g = torch.Generator().manual_seed(0)
    f1, f2 = torch.randn(2, 5, 6, 7, generator=g), torch.randn(2, 5, 6, 7, generator=g)
    out = correlation(f1, f2)
    assert out.shape == (2, 81, 6, 7)
    cases = [(0, 0, 0, 0, 0), (1, 3, 2, -4, 4), (0, 5, 6, 1, -3), (1, 0, 6, 4, -4), (0, 2, 3, -1, 2)]
    for b, y, x, dy, dx in cases:
        k = (dy + 4) * 9 + (dx + 4)  # dy outer, dx inner
        assert out[b, k, y, x].item() == pytest.approx(_explicit(f1, f2, b, y, x, dy, dx), abs=1e-6)


@pytest.mark.parametrize("shape", [(1, 1, 1, 1), (2, 3, 9, 4), (3, 8, 5, 13), (1, 32, 20, 24)])
@pytest.mark.parametrize("block", [8, 16, 24])
def test_equals_shift_and_multiply_reference_forward_and_backward(shape, block):
    g = torch.Generator().manual_seed(sum(shape) + block)
    f1 = torch.randn(*shape, generator=g, dtype=torch.float64, requires_grad=True)
    f2 = torch.randn(*shape, generator=g, dtype=torch.float64, requires_grad=True)
    out, ref = correlation(f1, f2, block=block), correlation_reference(f1, f2)
    assert torch.allclose(out, ref, atol=1e-12)
    grad = torch.randn(ref.shape, generator=g, dtype=torch.float64)
    ours = torch.autograd.grad(out, (f1, f2), grad)
    theirs = torch.autograd.grad(ref, (f1, f2), grad)
    for a, b in zip(ours, theirs):
        assert torch.allclose(a, b, atol=1e-12)


def test_gradcheck_float64():
    g = torch.Generator().manual_seed(1)
    # 5×6 maps: every ±4 displacement also reaches the zero padding; full (not fast-mode) Jacobians
    f1 = torch.randn(1, 2, 5, 6, generator=g, dtype=torch.float64, requires_grad=True)
    f2 = torch.randn(1, 2, 5, 6, generator=g, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda a, b: correlation(a, b, block=8), (f1, f2))
    # a batch of 2 with 3 channels, in fast mode (random projections of the Jacobian)
    f1 = torch.randn(2, 3, 6, 7, generator=g, dtype=torch.float64, requires_grad=True)
    f2 = torch.randn(2, 3, 6, 7, generator=g, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda a, b: correlation(a, b, block=8), (f1, f2), fast_mode=True)


def test_gradient_to_one_input_only_and_channels_last_inputs():
    g = torch.Generator().manual_seed(2)
    f1 = torch.randn(2, 4, 10, 12, generator=g).contiguous(memory_format=torch.channels_last)
    f2 = torch.randn(2, 4, 10, 12, generator=g).requires_grad_()
    out = correlation(f1, f2)
    ref = correlation_reference(f1, f2)
    assert torch.allclose(out, ref, atol=1e-6)
    (gf2,) = torch.autograd.grad(out.square().sum(), f2)
    (rf2,) = torch.autograd.grad(ref.square().sum(), f2)
    assert torch.allclose(gf2, rf2, atol=1e-5)


def test_rejects_mismatched_inputs():
    with pytest.raises(ValueError, match="one shape"):
        correlation(torch.zeros(1, 2, 4, 4), torch.zeros(1, 2, 4, 5))
