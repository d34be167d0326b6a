"""The fused tanh MLP (cartpole.agents.nn.fused_mlp) against the layer-by-layer path it replaces, bit
for bit, and a seed's bits alone and among others."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import torch

from cartpole.agents.nn import fused_mlp
from cartpole.agents.nn.fast_tanh import tanh, tanh_gradient
from cartpole.agents.nn.stacked_linear import mlp_gradients, stacked_linear

pytestmark = pytest.mark.independence

SHAPES = [  # (inputs, hidden sizes, outputs, rows)
    (4, [16, 16], 2, 256),
    (4, [16, 16], 1, 256),
    (4, [64, 64], 2, 37),
    (5, [9], 3, 6),
    (8, [7, 13, 5], 10, 19),
    (3, [16], 1, 1),
]


def network(rng: np.random.Generator, seeds: int, inputs: int, hidden: list[int], outputs: int):
    sizes = [inputs, *hidden, outputs]
    return [
        (
            torch.from_numpy(rng.standard_normal((seeds, o, i), dtype=np.float32) / np.float32(np.sqrt(i))),
            torch.from_numpy(rng.standard_normal((seeds, o), dtype=np.float32) * np.float32(0.1)),
        )
        for i, o in itertools.pairwise(sizes)
    ]


def layer_by_layer(x, layers):
    inputs = []
    for index, (weight, bias) in enumerate(layers):
        inputs.append(x)
        x = stacked_linear(x, weight, bias)
        if index < len(layers) - 1:
            x = tanh(x)
    return x, inputs


def bits(t: torch.Tensor) -> np.ndarray:
    return t.contiguous().numpy().view(np.uint32)


@pytest.mark.parametrize("shape", SHAPES, ids=str)
def test_the_fused_pass_gives_the_layer_by_layer_bits(shape):
    inputs, hidden, outputs, rows = shape
    rng = np.random.default_rng(len(hidden) * 100 + rows)
    seeds = 3
    layers = network(rng, seeds, inputs, hidden, outputs)
    x = torch.from_numpy(rng.standard_normal((seeds, rows, inputs), dtype=np.float32))
    assert fused_mlp.fusable(x, layers)
    out, kept = fused_mlp.forward(x, layers)
    expected, expected_inputs = layer_by_layer(x, layers)
    assert out.shape == expected.shape and out.stride() == expected.stride()
    np.testing.assert_array_equal(bits(out), bits(expected))
    for got, want in zip(kept, expected_inputs, strict=True):
        np.testing.assert_array_equal(bits(got), bits(want))

    grad = torch.from_numpy(rng.standard_normal(tuple(out.shape), dtype=np.float32))
    into = [(torch.zeros_like(w), torch.zeros_like(b)) for w, b in layers]
    fused_mlp.gradients(layers, kept, grad, into)
    want_grads = mlp_gradients(layers, expected_inputs, grad, tanh_gradient)
    for (gw, gb), (ww, wb) in zip(into, want_grads, strict=True):
        np.testing.assert_array_equal(bits(gw), bits(torch.zeros_like(ww).add_(ww)))
        np.testing.assert_array_equal(bits(gb), bits(torch.zeros_like(wb).add_(wb)))


def test_gradients_are_added_to_what_is_there():
    rng = np.random.default_rng(3)
    layers = network(rng, 2, 4, [16, 16], 2)
    x = torch.from_numpy(rng.standard_normal((2, 32, 4), dtype=np.float32))
    out, kept = fused_mlp.forward(x, layers)
    grad = torch.ones_like(out)
    once = [(torch.zeros_like(w), torch.zeros_like(b)) for w, b in layers]
    fused_mlp.gradients(layers, kept, grad, once)
    twice = [(torch.zeros_like(w), torch.zeros_like(b)) for w, b in layers]
    fused_mlp.gradients(layers, kept, grad, twice)
    fused_mlp.gradients(layers, kept, grad, twice)
    for (w1, b1), (w2, b2) in zip(once, twice, strict=True):
        torch.testing.assert_close(w2, 2 * w1)
        torch.testing.assert_close(b2, 2 * b1)


@pytest.mark.parametrize("neighbours", [1, 2, 4, 7])
def test_a_seed_gets_its_own_bits_at_every_position(neighbours):
    rng = np.random.default_rng(neighbours)
    inputs, hidden, outputs, rows = 4, [16, 16], 2, 64
    alone_layers = network(rng, 1, inputs, hidden, outputs)
    alone_x = torch.from_numpy(rng.standard_normal((1, rows, inputs), dtype=np.float32))
    alone_out, alone_kept = fused_mlp.forward(alone_x, alone_layers)
    alone_grad = torch.from_numpy(rng.standard_normal(tuple(alone_out.shape), dtype=np.float32))
    alone_into = [(torch.zeros_like(w), torch.zeros_like(b)) for w, b in alone_layers]
    fused_mlp.gradients(alone_layers, alone_kept, alone_grad, alone_into)
    for position in range(neighbours + 1):
        others = network(rng, neighbours, inputs, hidden, outputs)
        layers = [
            (torch.cat([tw[:position], mw, tw[position:]]), torch.cat([tb[:position], mb, tb[position:]]))
            for (mw, mb), (tw, tb) in zip(alone_layers, others, strict=True)
        ]
        other_x = torch.from_numpy(rng.standard_normal((neighbours, rows, inputs), dtype=np.float32))
        x = torch.cat([other_x[:position], alone_x, other_x[position:]])
        out, kept = fused_mlp.forward(x, layers)
        np.testing.assert_array_equal(bits(out[position : position + 1]), bits(alone_out))
        other_shape = (neighbours, *alone_out.shape[1:])
        other_grad = torch.from_numpy(rng.standard_normal(other_shape, dtype=np.float32))
        grad = torch.cat([other_grad[:position], alone_grad, other_grad[position:]])
        into = [(torch.zeros_like(w), torch.zeros_like(b)) for w, b in layers]
        fused_mlp.gradients(layers, kept, grad, into)
        for (gw, gb), (aw, ab) in zip(into, alone_into, strict=True):
            np.testing.assert_array_equal(bits(gw[position : position + 1]), bits(aw))
            np.testing.assert_array_equal(bits(gb[position : position + 1]), bits(ab))
