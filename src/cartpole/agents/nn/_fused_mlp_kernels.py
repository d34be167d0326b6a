"""Numba kernels behind :mod:`cartpole.agents.nn.fused_mlp` (imported on first use): a stacked tanh
MLP's forward pass and its gradients by hand, each in one compiled call for every seed.

They add no arithmetic of their own: every product is :func:`._fixed_order_kernels.matmul_into`, every
bias gradient :func:`._fixed_order_kernels.row_sums_into`, every tanh and its gradient the kernels of
:mod:`._tanh_kernels`, called as compiled functions (each keeps its own floating-point flags), in the
order that :func:`~cartpole.agents.nn.stacked_linear.mlp_gradients` and the layer-by-layer forward
pass call them from Python. So the bits are theirs, and what is saved is the Python around a small
network's dozen calls (tests/test_fused_mlp.py checks both paths bit for bit).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numba import njit
from numpy.typing import NDArray

from cartpole.agents.nn._fixed_order_kernels import matmul_into, row_sums_into
from cartpole.agents.nn._tanh_kernels import tanh_backward_into, tanh_in_place

_JIT: dict[str, Any] = {"cache": True, "nogil": True, "error_model": "numpy", "boundscheck": False}

Array = NDArray[np.float32]


@njit(**_JIT)
def hidden_forward(x: Array, weights_t: Any, biases: Any, hidden: Any) -> None:
    """The hidden layers: ``hidden[l] = tanh(h @ weights_t[l] + biases[l])``, ``h`` the layer's input
    (``x`` [S, B, in], then ``hidden[l - 1]``); ``weights_t[l]`` [S, in, out] and ``hidden[l]`` [S, B,
    out] C-contiguous, ``biases[l]`` [S, 1, out]."""
    matmul_into(x, weights_t[0], biases[0], hidden[0])
    tanh_in_place(hidden[0].ravel())
    for layer in range(1, len(weights_t)):
        matmul_into(hidden[layer - 1], weights_t[layer], biases[layer], hidden[layer])
        tanh_in_place(hidden[layer].ravel())


@njit(**_JIT)
def forward(
    x: Array, weights_t: Any, biases: Any, hidden: Any, head_t: Array, head_bias: Array, out: Array
) -> None:
    """The hidden layers (:func:`hidden_forward`), then ``out = h @ head_t + head_bias``, ``out``
    [S, B, m]."""
    hidden_forward(x, weights_t, biases, hidden)
    matmul_into(hidden[len(hidden) - 1], head_t, head_bias, out)


@njit(**_JIT)
def forward_narrow_head(
    x: Array, weights_t: Any, biases: Any, hidden: Any, head: Array, head_bias: Array, out_t: Array
) -> None:
    """:func:`forward` with the head computed the other way round, ``out_t = head @ h^T + bias``, ``out_t``
    [S, m, B] (``head`` [S, m, in], ``head_bias`` [S, m, 1]): the same sums, the rows as the
    vectorized columns (a head of few outputs)."""
    hidden_forward(x, weights_t, biases, hidden)
    last = hidden[len(hidden) - 1]
    matmul_into(head, np.ascontiguousarray(last.transpose((0, 2, 1))), head_bias, out_t)


@njit(**_JIT)
def _weight_gradient(grad: Array, x: Array) -> Array:
    """``grad^T @ x`` [S, out, in] (plus 0, as the Python path adds a zero bias), the wider side as the
    kernel's columns."""
    seeds, _, outputs = grad.shape
    inputs = x.shape[2]
    if outputs <= inputs:
        result = np.empty((seeds, outputs, inputs), dtype=np.float32)
        zeros = np.zeros((1, 1, inputs), dtype=np.float32)
        matmul_into(grad.transpose((0, 2, 1)), np.ascontiguousarray(x), zeros, result)
        return result
    transposed = np.empty((seeds, inputs, outputs), dtype=np.float32)
    zeros = np.zeros((1, 1, outputs), dtype=np.float32)
    matmul_into(x.transpose((0, 2, 1)), grad, zeros, transposed)
    return transposed.transpose((0, 2, 1))


@njit(**_JIT)
def _add_into(target: Any, values: Any) -> None:
    """``target += values`` elementwise, [S, out, in] arrays of one shape (any strides)."""
    for s in range(target.shape[0]):
        for i in range(target.shape[1]):
            for j in range(target.shape[2]):
                target[s, i, j] += values[s, i, j]


@njit(**_JIT)
def _add_rows_into(target: Any, values: Any) -> None:
    """``target += values`` elementwise, [S, out] arrays of one shape (any strides)."""
    for s in range(target.shape[0]):
        for j in range(target.shape[1]):
            target[s, j] += values[s, j]


@njit(**_JIT)
def _input_gradient(grad: Array, weight: Array) -> Array:
    """``grad @ weight`` [S, B, in] (plus 0); for one output, the broadcast product itself."""
    seeds, rows, outputs = grad.shape
    inputs = weight.shape[2]
    result = np.empty((seeds, rows, inputs), dtype=np.float32)
    if outputs == 1:
        for s in range(seeds):
            for b in range(rows):
                g = grad[s, b, 0]
                for i in range(inputs):
                    result[s, b, i] = g * weight[s, 0, i]
        return result
    matmul_into(grad, weight, np.zeros((1, 1, inputs), dtype=np.float32), result)
    return result


@njit(**_JIT)
def backward(
    grad: Array, x: Array, hidden: Any, weights: Any, head: Array, weight_grads: Any, bias_grads: Any
) -> None:
    """Add to ``weight_grads[l]`` [S, out, in] and ``bias_grads[l]`` [S, out] (the hidden layers', then
    the head's last) the gradients of each layer from ``grad`` [S, B, m] (C-contiguous), the gradient of
    the head's output: the network's input ``x``, its hidden outputs ``hidden``, its hidden weights
    ``weights`` [S, out, in] and head ``head`` [S, m, in], all C-contiguous. The calls of
    :func:`~cartpole.agents.nn.stacked_linear.mlp_gradients`, in its order."""
    layers = len(hidden)
    head_grad = _weight_gradient(grad, hidden[layers - 1])
    _add_into(weight_grads[layers], head_grad)
    bias = np.empty((grad.shape[0], grad.shape[2]), dtype=np.float32)
    row_sums_into(grad, bias)
    _add_rows_into(bias_grads[layers], bias)
    through = _input_gradient(grad, head)
    for layer in range(layers - 1, -1, -1):
        y = hidden[layer]
        g = np.empty_like(y)
        tanh_backward_into(y.ravel(), through.ravel(), g.ravel())
        layer_input = x if layer == 0 else hidden[layer - 1]
        _add_into(weight_grads[layer], _weight_gradient(g, layer_input))
        bias = np.empty((g.shape[0], g.shape[2]), dtype=np.float32)
        row_sums_into(g, bias)
        _add_rows_into(bias_grads[layer], bias)
        if layer:
            through = _input_gradient(g, weights[layer])
