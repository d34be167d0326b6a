"""The fast float32 tanh (cartpole.agents.nn.fast_tanh): accurate, odd, NaN-preserving, differentiable."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from cartpole.agents.nn.fast_tanh import tanh, tanh_array


def grid() -> np.ndarray:
    """Dense over [-12, 12] (past the clamp), and every decade down to the smallest normal float32."""
    dense = np.linspace(-12.0, 12.0, 400_001)
    tiny = 10.0 ** np.arange(-37.0, 1.0, 0.01)
    return np.concatenate([dense, tiny, -tiny]).astype(np.float32)


def test_within_a_few_ulps_of_the_exact_tanh():
    x = grid()
    exact = np.tanh(x.astype(np.float64))
    error = np.abs(tanh_array(x).astype(np.float64) - exact)
    assert error.max() <= 3e-7
    assert (error / np.abs(exact).clip(min=1e-37)).max() <= 3e-7


def test_odd_keeps_the_sign_of_zero_and_passes_nan_through():
    x = grid()
    np.testing.assert_array_equal(tanh_array(-x), -tanh_array(x))
    special = tanh_array(np.array([0.0, -0.0, np.nan, np.inf, -np.inf], dtype=np.float32))
    assert special[0] == 0.0 and not np.signbit(special[0]) and np.signbit(special[1])
    assert np.isnan(special[2])
    assert special[3] == pytest.approx(1.0, abs=3e-7) and special[4] == pytest.approx(-1.0, abs=3e-7)


def test_writes_into_out_and_falls_back_to_numpy_for_other_arrays():
    x = np.linspace(-3, 3, 60, dtype=np.float32).reshape(6, 10)
    expected = tanh_array(x)
    tanh_array(x, out=x)
    np.testing.assert_array_equal(x, expected)
    as_float64 = np.linspace(-3, 3, 60).reshape(6, 10)
    np.testing.assert_array_equal(tanh_array(as_float64), np.tanh(as_float64))
    strided = np.linspace(-3, 3, 60, dtype=np.float32).reshape(6, 10)[:, ::2]
    np.testing.assert_array_equal(tanh_array(strided), np.tanh(strided))


def test_torch_tanh_matches_and_its_gradient_is_one_minus_y_squared():
    generator = torch.Generator().manual_seed(0)
    x = (3 * torch.randn(7, 33, generator=generator)).requires_grad_(True)
    upstream = torch.randn(7, 33, generator=generator)
    y = tanh(x)
    torch.testing.assert_close(y, torch.tanh(x), rtol=3e-7, atol=3e-7)
    (grad,) = torch.autograd.grad(y, x, upstream)
    torch.testing.assert_close(grad, upstream * (1 - y.detach() ** 2), rtol=1e-6, atol=1e-7)
    exact = torch.autograd.grad(torch.tanh(x), x, upstream)[0]
    torch.testing.assert_close(grad, exact, rtol=1e-5, atol=1e-6)


def test_torch_tanh_of_a_transposed_tensor_and_other_dtypes():
    x = torch.linspace(-4, 4, 48).view(6, 8).t()  # not contiguous
    torch.testing.assert_close(tanh(x), torch.tanh(x), rtol=3e-7, atol=3e-7)
    as_float64 = torch.linspace(-4, 4, 48, dtype=torch.float64)
    assert torch.equal(tanh(as_float64), torch.tanh(as_float64))
