"""A stacked tanh MLP's forward pass, and its gradients by hand, each one compiled call for every seed.

What the layer-by-layer path computes (:func:`~cartpole.agents.nn.stacked_linear.linear_forward`
and the fast ``tanh`` per layer forward, :func:`~cartpole.agents.nn.stacked_linear.mlp_gradients`
backward), the same kernels called in the same order from compiled code
(:mod:`._fused_mlp_kernels`), so the same bits: a seed's stay its own whatever its neighbours, as
:mod:`~cartpole.agents.nn.fixed_order` promises. Why: a PPO update of two 16x16 tanh networks makes
about thirty such calls per gradient step, each a few microseconds of Python and tensor-to-array
views around less than a microsecond of arithmetic; here they are two calls forward and two back.
Float32 on the CPU, an MLP of at least one hidden layer with tanh between its layers; anything else
takes the layer-by-layer path (:func:`fusable`).
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np
import torch

from cartpole.agents.nn.fixed_order import NARROW, is_fixed_order


@functools.cache
def _kernels() -> Any:
    """The numba kernels (:mod:`._fused_mlp_kernels`), compiled or loaded on first use."""
    from cartpole.agents.nn import _fused_mlp_kernels

    return _fused_mlp_kernels


def _array(t: torch.Tensor) -> np.ndarray:
    return (t.detach() if t.requires_grad else t).numpy()


Layers = list[tuple[torch.Tensor, torch.Tensor]]
"""An MLP's linear layers, in order: weights [S, out, in] and biases [S, out]."""


def fusable(x: torch.Tensor, layers: Layers) -> bool:
    """Whether :func:`forward` takes ``x`` through ``layers``: float32 CPU tensors, a hidden layer or
    more, [S, B, in] inputs with one network per seed."""
    if len(layers) < 2 or x.dim() != 3 or not is_fixed_order(x):
        return False
    return all(is_fixed_order(w) and is_fixed_order(b) and w.shape[0] == x.shape[0] for w, b in layers)


def forward(x: torch.Tensor, layers: Layers) -> tuple[torch.Tensor, list[torch.Tensor]]:
    """``x`` [S, B, in] through ``layers`` with tanh between them: the output [S, B, m] (a transposed
    view for a head of fewer than :data:`~cartpole.agents.nn.fixed_order.NARROW` outputs, as
    :func:`~cartpole.agents.nn.fixed_order.matmul` gives it) and each layer's input (``x``, then the
    hidden outputs), what :func:`gradients` takes."""
    seeds, rows, _ = x.shape
    hidden_layers = layers[:-1]
    weights_t = tuple(np.ascontiguousarray(_array(w).transpose(0, 2, 1)) for w, _ in hidden_layers)
    biases = tuple(np.ascontiguousarray(_array(b)[:, None, :]) for _, b in hidden_layers)
    hidden = tuple(np.empty((seeds, rows, w.shape[1]), dtype=np.float32) for w, _ in hidden_layers)
    head, head_bias = (_array(t) for t in layers[-1])
    outputs = head.shape[1]
    source = _array(x)
    if outputs < NARROW <= rows:
        out_t = np.empty((seeds, outputs, rows), dtype=np.float32)
        _kernels().forward_narrow_head(source, weights_t, biases, hidden, head, head_bias[:, :, None], out_t)
        out = torch.from_numpy(out_t).transpose(1, 2)
    else:
        out_a = np.empty((seeds, rows, outputs), dtype=np.float32)
        head_t = np.ascontiguousarray(head.transpose(0, 2, 1))
        _kernels().forward(source, weights_t, biases, hidden, head_t, head_bias[:, None, :], out_a)
        out = torch.from_numpy(out_a)
    return out, [x, *(torch.from_numpy(h) for h in hidden)]


def forward_arrays(
    x: np.ndarray, weights_t: tuple[np.ndarray, ...], biases: tuple[np.ndarray, ...]
) -> np.ndarray:
    """:func:`forward` of NumPy arrays: ``x`` [S, B, in] float32, ``weights_t`` [S, in, out] and
    ``biases`` [S, 1, out] C-contiguous float32 (a NumPy twin's, the head's last); the output [S, B,
    m], what :func:`~cartpole.agents.nn.numpy_mlp.run_steps` gives."""
    seeds, rows, _ = x.shape
    hidden = tuple(np.empty((seeds, rows, w.shape[2]), dtype=np.float32) for w in weights_t[:-1])
    out = np.empty((seeds, rows, weights_t[-1].shape[2]), dtype=np.float32)
    _kernels().forward(x, weights_t[:-1], biases[:-1], hidden, weights_t[-1], biases[-1], out)
    return out


def gradients(layers: Layers, inputs: list[torch.Tensor], grad: torch.Tensor, into: Layers) -> None:
    """Add each layer's weight and bias gradients to ``into`` (tensors of the layers' shapes, each
    [S, ...] written in place), from ``grad`` [S, B, m], the gradient of the output of the
    :func:`forward` whose ``inputs`` these are."""
    x = np.ascontiguousarray(_array(inputs[0]))
    hidden = tuple(_array(h) for h in inputs[1:])
    weights = tuple(np.ascontiguousarray(_array(w)) for w, _ in layers[:-1])
    head = np.ascontiguousarray(_array(layers[-1][0]))
    weight_grads = tuple(_array(w) for w, _ in into)
    bias_grads = tuple(_array(b) for _, b in into)
    head_grad = np.ascontiguousarray(_array(grad))
    _kernels().backward(head_grad, x, hidden, weights, head, weight_grads, bias_grads)


__all__ = ["Layers", "forward", "forward_arrays", "fusable", "gradients"]
