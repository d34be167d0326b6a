"""Matrix products and sums over a batch whose every bit the project owns: what a seed's training
multiplies with, so that a seed gets the same bits alone, beside any other seeds, at any position.

Why not torch's ``bmm``: a BLAS chooses its kernel by the whole call, so one matrix of a batch can get
other bits than the same matrix alone or beside other neighbours. On an Intel Xeon (AVX-512, MKL)
``torch.bmm`` gives one matrix other bits in a batch of 3 than in a batch of 1 in 74 of 500 shapes,
40 even under ``MKL_CBWR=COMPATIBLE`` (``../shared/evidence/intel-xeon.md``), while on the AMD CPUs
this project was developed on it gave none: a promise that rested on the BLAS held there by chance.

Here each output element is one sum in a fixed order (:mod:`._fixed_order_kernels`: from 0, each
product in turn, then the bias; multiply and add each rounded, no FMA), so its bits follow from its own
inputs alone, on every x86-64 and arm64 CPU. ``tests/test_fixed_order.py`` checks it against that
sum written out in NumPy, and batch by batch. On the CPU, for float32 (every network here); other
devices and dtypes take torch's product, which promises no such thing (CUDA: docs/DESIGN.md).

What it costs: ``benchmarks/kernels.py --fixed-order`` times it beside ``torch.bmm`` on the agents'
shapes (benchmarks/README.md#kernels).
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np
import torch


def is_fixed_order(t: torch.Tensor) -> bool:
    """Whether products of ``t`` run in the fixed order: float32 on the CPU."""
    return t.device.type == "cpu" and t.dtype == torch.float32


def kernels() -> Any:
    """The numba kernels (:mod:`._fixed_order_kernels`), compiled or loaded on first use."""
    from cartpole.agents.nn import _fixed_order_kernels

    return _fixed_order_kernels


def _array(t: torch.Tensor) -> np.ndarray:
    """A NumPy view of ``t``'s values (no copy; the view shares ``t``'s strides)."""
    return (t.detach() if t.requires_grad else t).numpy()


@functools.cache
def _zeros(m: int) -> np.ndarray:
    """A bias of 0 for ``m`` columns, [1, 1, m] (kept: read only)."""
    zeros = np.zeros((1, 1, m), dtype=np.float32)
    zeros.flags.writeable = False
    return zeros


def check_shapes(a: tuple[int, ...], b: tuple[int, ...], c: tuple[int, ...]) -> None:
    """ValueError unless ``a`` [S, n, k] times ``b`` [S, k, m] plus ``c`` [S or 1, n or 1, m or 1] is a
    product (S may be 1 on one side): the kernels check no bounds."""
    fits = len(a) == len(b) == len(c) == 3 and a[2] == b[1]
    fits = fits and (a[0] == b[0] or 1 in (a[0], b[0]))
    seeds = max(a[0], b[0]) if fits else 0
    if not (fits and c[0] in (1, seeds) and c[1] in (1, a[1]) and c[2] in (1, b[2])):
        raise ValueError(f"cannot multiply {a} by {b} and add {c}")


NARROW = 8
"""Fewer output columns than this (a policy or value head's) are computed the other way round."""


def _narrow_matmul(a: torch.Tensor, b: torch.Tensor, c: torch.Tensor | None) -> torch.Tensor:
    """:func:`matmul` of a product with few columns and many rows, as ``(b^T a^T)^T``: the same sums in
    the same order (a product of two floats is the same either way round), with the many rows as
    the kernel's vectorized columns, several times faster. A transposed view [S, n, m]."""
    seeds, n, _ = a.shape
    m = b.shape[2]
    start = _zeros(1) if c is None else _array(c).transpose(0, 2, 1)
    result = np.empty((seeds, m, n), dtype=np.float32)
    columns = np.ascontiguousarray(_array(a).transpose(0, 2, 1))
    kernels().matmul_into(_array(b).transpose(0, 2, 1), columns, start, result)
    return torch.from_numpy(result).transpose(1, 2)


def matmul(
    a: torch.Tensor, b: torch.Tensor, c: torch.Tensor | None = None, out: torch.Tensor | None = None
) -> torch.Tensor:
    """``a @ b + c`` per seed, ``[S, n, m]``, for ``a`` [S, n, k], ``b`` [S, k, m] and ``c`` (default 0)
    broadcast from [S or 1, n or 1, m or 1]; each element summed in the fixed order of the module
    docstring, ``c`` added last. Written into ``out`` [S, n, m] when given. No autograd: callers
    differentiate by hand (:mod:`~cartpole.agents.nn.stacked_linear`,
    :mod:`~cartpole.agents.nn.stacked_conv`)."""
    if not is_fixed_order(a):
        product = torch.bmm(a, b) if c is None else torch.baddbmm(c, a, b)
        return product if out is None else out.copy_(product)
    check_shapes(tuple(a.shape), tuple(b.shape), (1, 1, 1) if c is None else tuple(c.shape))
    if a.shape[0] != b.shape[0]:
        raise ValueError(f"cannot multiply {tuple(a.shape)} by {tuple(b.shape)}: one network a seed")
    seeds, n, _ = a.shape
    m = b.shape[2]
    if m < NARROW <= n and out is None:
        return _narrow_matmul(a, b, c)
    start = _zeros(m) if c is None else _array(c)
    if out is not None and out.is_contiguous():
        kernels().matmul_into(_array(a), _array(b.contiguous()), start, _array(out))
        return out
    result = np.empty((seeds, n, m), dtype=np.float32)
    kernels().matmul_into(_array(a), _array(b.contiguous()), start, result)
    return torch.from_numpy(result) if out is None else out.copy_(torch.from_numpy(result))


def matmul_arrays(x: np.ndarray, weight: np.ndarray, bias: np.ndarray | None = None) -> np.ndarray:
    """``x @ weight + bias`` of NumPy arrays, in the order of :func:`matmul` (float32, or float64
    for the linear policies): ``x`` [S, B, in] or [B, in], ``weight`` [S, in, out] or [in, out],
    ``bias`` broadcast from [S or 1, 1 or B, out or 1] or [out] (default 0); the result has ``x``'s
    number of dimensions and dtype (a NumPy twin's layer, a linear policy's scores)."""
    dtype = x.dtype if x.dtype == np.float64 else np.dtype(np.float32)
    stacked = x.ndim == 3
    a = (x if stacked else x[None]).astype(dtype, copy=False)
    b = np.ascontiguousarray(weight if weight.ndim == 3 else weight[None], dtype=dtype)
    if bias is None:
        c = np.zeros((1, 1, 1), dtype=dtype)
    else:
        c = (bias if bias.ndim == 3 else bias.reshape(1, 1, -1)).astype(dtype, copy=False)
    check_shapes(a.shape, b.shape, c.shape)
    out = np.empty((max(a.shape[0], b.shape[0]), a.shape[1], b.shape[2]), dtype=dtype)
    if a.shape[0] != out.shape[0]:  # one input for every network
        a = np.broadcast_to(a, (out.shape[0], *a.shape[1:]))
    if b.shape[0] != out.shape[0]:  # one network for every input
        b = np.broadcast_to(b, (out.shape[0], *b.shape[1:]))
    kernels().matmul_into(a, b, c, out)
    return out if stacked or out.shape[0] > 1 else out[0]


def row_sums(x: torch.Tensor) -> torch.Tensor:
    """``x.sum(dim=1)`` of ``x`` [S, B, m], ``[S, m]``: 0 plus each row in turn (a bias's gradient)."""
    if not is_fixed_order(x):
        return x.sum(dim=1)
    totals = np.empty((x.shape[0], x.shape[2]), dtype=np.float32)
    kernels().row_sums_into(_array(x), totals)
    return torch.from_numpy(totals)


class _SeedSums(torch.autograd.Function):
    @staticmethod
    def forward(ctx: Any, x: torch.Tensor) -> torch.Tensor:
        ctx.shape = x.shape
        rows = x if x.dim() == 3 else x.unsqueeze(-1)
        totals = row_sums(rows)
        return totals if x.dim() == 3 else totals.squeeze(-1)

    @staticmethod
    def backward(ctx: Any, grad: torch.Tensor) -> torch.Tensor:
        return grad.unsqueeze(1).expand(ctx.shape)


def seed_sums(x: torch.Tensor) -> torch.Tensor:
    """``x.sum(dim=1)`` of ``x`` [S, B] or [S, B, m] (each seed's rows), in the order of
    :func:`row_sums`, differentiable. Torch's own sum splits one long row between its threads but
    gives each of several rows one thread, so on more than one thread a lone seed's sum could be
    another float than the same seed's among others (tests/test_fixed_order.py)."""
    if not is_fixed_order(x):
        return x.sum(dim=1)
    if torch.is_grad_enabled() and x.requires_grad:
        return _SeedSums.apply(x)
    rows = x if x.dim() == 3 else x.unsqueeze(-1)
    return row_sums(rows) if x.dim() == 3 else row_sums(rows).squeeze(-1)


def row_norms(x: torch.Tensor) -> torch.Tensor:
    """The Euclidean norm of each row of ``x`` [S, P], ``[S]``: the squares added in row order."""
    if not is_fixed_order(x):
        return torch.linalg.vector_norm(x, dim=1)
    norms = np.empty(x.shape[0], dtype=np.float32)
    kernels().row_norms_into(_array(x), norms)
    return torch.from_numpy(norms)


__all__ = ["is_fixed_order", "kernels", "matmul", "matmul_arrays", "row_norms", "row_sums", "seed_sums"]
