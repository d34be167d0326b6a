"""``tanh`` for float32 arrays and tensors on the CPU, for the networks' hot paths.

Why: torch's float32 ``tanh`` on the CPU, and NumPy's on CPUs without AVX-512, cost more than the
matrix products around them (a 64x64 tanh MLP spends most of its forward pass in it). The rational
approximation of :mod:`cartpole.agents.nn._tanh_kernels` is several times cheaper than torch's, and
within a few float32 ulps of the exact value, the size of the differences between two CPUs' kernels
(benchmarks/README.md#kernels times all three and gives its largest error). Used by the NumPy twins
(:mod:`~cartpole.agents.nn.numpy_mlp`) and the stacked networks (``TORCH_ACTIVATIONS``); the
``nn.Module`` networks keep ``torch.tanh``.

``tanh`` (torch) is differentiable: its gradient is ``(1 - y^2) * grad`` from the saved output. Other
dtypes and devices fall back to NumPy's and torch's own ``tanh``.
"""

from __future__ import annotations

import functools
from types import ModuleType
from typing import Any

import numpy as np
import torch


@functools.cache
def _kernels() -> ModuleType:
    """The numba kernels, compiled on first use (importing this module does not import numba)."""
    from cartpole.agents.nn import _tanh_kernels

    return _tanh_kernels


def tanh_array(x: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """``tanh(x)``; into ``out`` when given (``out`` may be ``x``, of ``x``'s shape and dtype).
    Float32 C-contiguous arrays take the fast kernel, anything else ``np.tanh``."""
    if out is None:
        out = np.empty_like(x)
    if x.dtype != np.float32 or not x.flags.c_contiguous or not out.flags.c_contiguous:
        return np.tanh(x, out=out)
    if out is x:
        _kernels().tanh_in_place(x.ravel())
    elif np.may_share_memory(x, out):
        return np.tanh(x, out=out)
    else:
        _kernels().tanh_into(x.ravel(), out.ravel())
    return out


class _FastTanh(torch.autograd.Function):
    """Fast ``tanh`` of a float32 CPU tensor, with its gradient ``(1 - y^2) * grad``."""

    @staticmethod
    def forward(ctx: Any, x: torch.Tensor) -> torch.Tensor:
        y = torch.from_numpy(tanh_array(x.detach().contiguous().numpy()))
        ctx.save_for_backward(y)
        return y

    @staticmethod
    def backward(ctx: Any, grad: torch.Tensor) -> torch.Tensor:
        (y,) = ctx.saved_tensors
        return tanh_gradient(grad, y)


def tanh_gradient(grad: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """The gradient ``(1 - y^2) * grad`` through ``y = tanh(x)``: one kernel pass for float32 CPU
    tensors (the backward of :func:`tanh`), torch's arithmetic otherwise."""
    if y.device.type != "cpu" or y.dtype != torch.float32:
        return grad * (1.0 - y * y)
    y = y.contiguous()
    out = torch.empty_like(y)
    flat = [t.numpy().reshape(-1) for t in (y, grad.contiguous(), out)]
    _kernels().tanh_backward_into(*flat)
    return out


def tanh(x: torch.Tensor) -> torch.Tensor:
    """``tanh(x)``: the fast kernel for float32 CPU tensors (differentiable), ``torch.tanh`` otherwise."""
    if x.device.type != "cpu" or x.dtype != torch.float32:
        return torch.tanh(x)
    if x.requires_grad and torch.is_grad_enabled():
        return _FastTanh.apply(x)
    return torch.from_numpy(tanh_array(x.contiguous().numpy()))


__all__ = ["tanh", "tanh_array", "tanh_gradient"]
