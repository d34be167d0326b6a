"""Numba kernels behind :mod:`cartpole.agents.nn.population_optimizers` (imported on first use).

One pass over each seed's row does the whole update: read the gradient and state, write the state and
parameters. Torch's elementwise form of the same update makes about ten passes over ``[S, P]``
tensors, which for 100 seeds (3.7 MB each) no longer fit the core's cache.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numba import njit
from numpy.typing import NDArray

_JIT: dict[str, Any] = {"cache": True, "nogil": True, "error_model": "numpy"}


@njit(**_JIT)
def adam_rows(
    params: NDArray[np.float32],
    grads: NDArray[np.float32],
    exp_avg: NDArray[np.float32],
    exp_avg_sq: NDArray[np.float32],
    steps: NDArray[np.float64],
    lr: NDArray[np.float64],
    active: NDArray[np.bool_],
    beta1: float,
    beta2: float,
    eps: float,
) -> None:
    """Adam on the rows where ``active``: ``steps[r] += 1``, then torch.optim.Adam's update
    (``exp_avg`` lerps toward the gradient; bias corrections from the row's own step count)."""
    rows, size = params.shape
    weight1 = np.float32(1.0 - beta1)
    decay2, weight2 = np.float32(beta2), np.float32(1.0 - beta2)
    epsilon = np.float32(eps)
    for r in range(rows):
        if not active[r]:
            continue
        steps[r] += 1.0
        step_size = np.float32(lr[r] / (1.0 - beta1 ** steps[r]))
        correction2 = np.float32(np.sqrt(1.0 - beta2 ** steps[r]))
        for i in range(size):
            g = grads[r, i]
            m = exp_avg[r, i] + weight1 * (g - exp_avg[r, i])
            v = exp_avg_sq[r, i] * decay2 + weight2 * (g * g)
            exp_avg[r, i] = m
            exp_avg_sq[r, i] = v
            params[r, i] -= (m * step_size) / (np.sqrt(v) / correction2 + epsilon)


@njit(**_JIT)
def rmsprop_rows(
    params: NDArray[np.float32],
    grads: NDArray[np.float32],
    square_avg: NDArray[np.float32],
    lr: NDArray[np.float64],
    active: NDArray[np.bool_],
    alpha: float,
    eps: float,
) -> None:
    """RMSprop (no momentum, not centred) on the rows where ``active``."""
    rows, size = params.shape
    decay, weight = np.float32(alpha), np.float32(1.0 - alpha)
    epsilon = np.float32(eps)
    for r in range(rows):
        if not active[r]:
            continue
        rate = np.float32(lr[r])
        for i in range(size):
            g = grads[r, i]
            a = square_avg[r, i] * decay + weight * (g * g)
            square_avg[r, i] = a
            params[r, i] -= g / (np.sqrt(a) + epsilon) * rate
