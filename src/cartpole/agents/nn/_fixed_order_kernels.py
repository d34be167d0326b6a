"""The numba kernels behind :mod:`cartpole.agents.nn.fixed_order` (imported on first use).

Each output element is one float32 sum in one order, written out here: from 0 it adds
``a[s, i, p] * b[s, p, j]`` for ``p = 0, 1, ..., k - 1``, then its bias (the order of a greedy
policy's compiled layers, :mod:`._greedy_play_kernels`), each a multiply rounded to float32 and then
an add rounded to float32 (no fast-math, no ``contract``, so LLVM may not fuse the
two into an FMA nor reorder the sum). LLVM vectorizes across ``j``, the independent output columns,
which changes no element's order: the bits are those of the scalar loop on any x86-64 or arm64 CPU
and vector width, and a seed's do not depend on the seeds beside it, their number or its position.
The rows are taken four at a time so that each loaded row of ``b`` serves four output rows.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numba import njit
from numpy.typing import NDArray

_JIT: dict[str, Any] = {"cache": True, "nogil": True, "error_model": "numpy", "boundscheck": False}

ROW_BLOCK = 4
"""Output rows computed together (each loaded row of ``b`` multiplied into four rows)."""


@njit(**_JIT, inline="always")
def add_row(row: NDArray[np.float32], last: NDArray[np.float32], by_column: bool) -> None:
    """``row += last``, ``last`` one value for every column unless ``by_column``."""
    if by_column:
        for j in range(row.shape[0]):
            row[j] += last[j]
    else:
        value = last[0]
        for j in range(row.shape[0]):
            row[j] += value


@njit(**_JIT)
def matmul_into(
    a: NDArray[np.float32], b: NDArray[np.float32], c: NDArray[np.float32], out: NDArray[np.float32]
) -> None:
    """``out[s] = a[s] @ b[s] + c[s]`` for ``a`` [S, n, k] (any strides), ``b`` [S, k, m]
    (C-contiguous), ``c`` [S or 1, n or 1, m or 1] (broadcast) and ``out`` [S, n, m] (C-contiguous),
    each element summed in the order of the module docstring, ``c`` added last."""
    seeds, n, k = a.shape
    m = b.shape[2]
    c_by_seed, c_by_row, c_by_column = c.shape[0] > 1, c.shape[1] > 1, c.shape[2] > 1
    for s in range(seeds):
        cs = c[s if c_by_seed else 0]
        bs = b[s]
        i = 0
        while i + ROW_BLOCK <= n:
            # One 2-D tile, not four rows: LLVM vectorizes across j after run-time checks that
            # what it writes does not overlap what it reads; four rows and b's row need ten
            # checks (past its default limit of eight), the tile and b's row one. 1.5-1.8x faster.
            tile = out[s, i : i + ROW_BLOCK]
            tile[:, :] = np.float32(0.0)
            for p in range(k):
                x0, x1, x2, x3 = a[s, i, p], a[s, i + 1, p], a[s, i + 2, p], a[s, i + 3, p]
                bp = bs[p]
                for j in range(m):
                    v = bp[j]
                    tile[0, j] += x0 * v
                    tile[1, j] += x1 * v
                    tile[2, j] += x2 * v
                    tile[3, j] += x3 * v
            i += ROW_BLOCK
        while i < n:
            row = out[s, i]
            row[:] = np.float32(0.0)
            for p in range(k):
                x = a[s, i, p]
                bp = bs[p]
                for j in range(m):
                    row[j] += x * bp[j]
            i += 1
        for i in range(n):
            add_row(out[s, i], cs[i if c_by_row else 0], c_by_column)


@njit(**_JIT)
def row_sums_into(x: NDArray[np.float32], out: NDArray[np.float32]) -> None:
    """``out[s, j] = x[s, 0, j] + x[s, 1, j] + ...`` in that order, for ``x`` [S, B, m] (any strides)
    and ``out`` [S, m]: 0 plus each row in turn."""
    seeds, rows, m = x.shape
    for s in range(seeds):
        total = out[s]
        for j in range(m):
            total[j] = np.float32(0.0)
        for b in range(rows):
            row = x[s, b]
            for j in range(m):
                total[j] += row[j]


@njit(**_JIT)
def row_norms_into(x: NDArray[np.float32], out: NDArray[np.float32]) -> None:
    """``out[s] = sqrt(x[s, 0]^2 + x[s, 1]^2 + ...)``, the squares added in that order, for ``x``
    [S, P] (any strides) and ``out`` [S]."""
    for s in range(x.shape[0]):
        total = np.float32(0.0)
        row = x[s]
        for p in range(row.shape[0]):
            total += row[p] * row[p]
        out[s] = np.sqrt(total)
