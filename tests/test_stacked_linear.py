"""agents/nn/stacked_linear.py: S linear layers at once, with the gradients of ``torch.baddbmm``."""

from __future__ import annotations

import pytest
import torch

from cartpole.agents.nn import stacked_linear as stacked_linear_module
from cartpole.agents.nn.stacked_linear import (
    relu_gradient,
    relu_gradient_by_where,
    relu_gradient_in_place,
    stacked_linear,
)


def reference(x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor) -> torch.Tensor:
    return torch.baddbmm(bias.unsqueeze(1), x, weight.transpose(1, 2))


@pytest.mark.parametrize(("inputs", "outputs"), [(4, 64), (64, 64), (64, 2), (64, 1), (3, 5)])
def test_output_and_gradients_are_those_of_baddbmm(inputs: int, outputs: int) -> None:
    generator = torch.Generator().manual_seed(inputs * 100 + outputs)
    seeds, batch = 5, 17
    tensors = [
        torch.randn(seeds, batch, inputs, generator=generator),
        torch.randn(seeds, outputs, inputs, generator=generator),
        torch.randn(seeds, outputs, generator=generator),
    ]
    upstream = torch.randn(seeds, batch, outputs, generator=generator)
    results = []
    for layer in (stacked_linear, reference):
        leaves = [t.clone().requires_grad_(True) for t in tensors]
        out = layer(*leaves)
        (out * upstream).sum().backward()
        results.append([out.detach(), *[leaf.grad for leaf in leaves]])
    for ours, theirs in zip(*results, strict=True):
        assert ours is not None and theirs is not None
        assert ours.shape == theirs.shape
        torch.testing.assert_close(ours, theirs, rtol=1e-5, atol=1e-5)


def test_a_seed_s_gradients_do_not_depend_on_the_others() -> None:
    generator = torch.Generator().manual_seed(0)
    x, weight, bias = (torch.randn(*s, generator=generator) for s in ((4, 9, 64), (4, 2, 64), (4, 2)))
    upstream = torch.randn(4, 9, 2, generator=generator)

    def seed_0_gradients(rows: list[int]) -> list[torch.Tensor]:
        leaves = [t[rows].clone().requires_grad_(True) for t in (x, weight, bias)]
        (stacked_linear(*leaves) * upstream[rows]).sum().backward()
        return [leaf.grad[0] for leaf in leaves if leaf.grad is not None]

    for ours, theirs in zip(seed_0_gradients([0, 1]), seed_0_gradients([0, 2, 3]), strict=True):
        assert torch.equal(ours, theirs)


@pytest.mark.parametrize(("inputs", "outputs"), [(6, 16), (4, 16), (16, 64), (64, 16), (64, 2), (64, 1)])
def test_on_two_threads_a_lone_seed_gets_the_bits_it_gets_among_others(inputs: int, outputs: int) -> None:
    """A batch of one goes to a threaded single matrix product, several to a batched one: a first
    layer's weight gradient with 6 inputs differs between the two on any CPU, with 4 under MKL's
    AVX2 code (``MKL_CBWR=AVX2``), unless the lone seed is multiplied as one of a batch."""
    torch.set_num_threads(2)  # conftest's autouse fixture sets one thread again for the next test
    generator = torch.Generator().manual_seed(inputs * 100 + outputs)
    seeds, batch = 3, 128
    shapes = ((seeds, batch, inputs), (seeds, outputs, inputs), (seeds, outputs), (seeds, batch, outputs))
    x, weight, bias, upstream = (torch.randn(*shape, generator=generator) for shape in shapes)

    def seed_0(rows: int) -> list[torch.Tensor]:
        leaves = [t[:rows].clone().requires_grad_(True) for t in (x, weight, bias)]
        out = stacked_linear(*leaves)
        (out * upstream[:rows]).sum().backward()
        return [out.detach()[0], *[leaf.grad[0] for leaf in leaves if leaf.grad is not None]]

    alone, among = seed_0(1), seed_0(seeds)
    assert len(alone) == 4
    for ours, theirs in zip(alone, among, strict=True):
        assert torch.equal(ours, theirs)


def test_inputs_that_need_no_gradient_get_none() -> None:
    x = torch.randn(2, 3, 4)  # observations: no gradient wanted
    weight = torch.randn(2, 5, 4, requires_grad=True)
    bias = torch.randn(2, 5, requires_grad=True)
    stacked_linear(x, weight, bias).sum().backward()
    assert x.grad is None and weight.grad is not None and bias.grad is not None
    with torch.no_grad():
        assert not stacked_linear(x, weight, bias).requires_grad


def test_the_relu_gradient_is_autograds_bit_for_bit_by_either_kernel() -> None:
    generator = torch.Generator().manual_seed(5)
    x = torch.randn(3, 40, 16, generator=generator)
    x[0, :5] = 0.0  # relu(0) = 0: no gradient passes there, as in autograd
    upstream = torch.randn(3, 40, 16, generator=generator)
    leaf = x.clone().requires_grad_(True)
    (torch.relu(leaf) * upstream).sum().backward()
    assert leaf.grad is not None
    y = torch.relu(x)
    overwritten = upstream.clone()
    in_place = relu_gradient_in_place(overwritten, y)
    assert in_place.data_ptr() == overwritten.data_ptr()  # written over its input: no new tensor
    for gradient in (relu_gradient(upstream, y), relu_gradient_by_where(upstream, y), in_place):
        # Bits, not values: -0.0 and 0.0 compare equal.
        assert torch.equal(gradient.view(torch.int32), leaf.grad.view(torch.int32))


@pytest.mark.parametrize(
    "missing", [("THRESHOLD_BACKWARD_INTO",), ("THRESHOLD_BACKWARD", "THRESHOLD_BACKWARD_INTO")]
)
def test_the_relu_gradient_falls_back_to_public_torch_with_the_same_bits(
    monkeypatch: pytest.MonkeyPatch, missing: tuple[str, ...]
) -> None:
    """A torch without autograd's kernel (or without its ``grad_input`` variant) gets the same bits."""
    generator = torch.Generator().manual_seed(6)
    y = torch.relu(torch.randn(2, 24, 8, generator=generator))
    upstream = torch.randn(2, 24, 8, generator=generator)
    expected = relu_gradient_by_where(upstream, y)
    for name in missing:
        monkeypatch.setattr(stacked_linear_module, name, None)
    for gradient in (relu_gradient(upstream, y), relu_gradient_in_place(upstream.clone(), y)):
        assert torch.equal(gradient.view(torch.int32), expected.view(torch.int32))
