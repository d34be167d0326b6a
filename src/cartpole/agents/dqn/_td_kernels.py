"""The numba kernel behind :func:`cartpole.agents.dqn.dqn.td_gradient` (imported on first use).

One pass over every seed's minibatch rows does what about twenty small torch operations do (the
next action's choice, the Bellman target, the taken action's Q-value, the loss's slope and its
scatter into the Q-values' gradient), each of which costs more in dispatch than in arithmetic on
256 rows. The same float32 operations in the same order, without fast-math, so the bits are
torch's (``tests/test_dqn.py``).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numba import njit
from numpy.typing import NDArray

_JIT: dict[str, Any] = {"cache": True, "nogil": True, "error_model": "numpy"}


@njit(**_JIT)
def first_argmax(values: NDArray[np.float32], s: int, b: int) -> int:
    """``torch.argmax`` of ``values[s, b, :]``: the first largest, a NaN counting as the largest."""
    best = 0
    for a in range(1, values.shape[2]):
        value, held = values[s, b, a], values[s, b, best]
        if held != held:  # a NaN is held: torch keeps the first
            break
        if value > held or value != value:
            best = a
    return best


@njit(**_JIT)
def td_gradient_rows(
    q_all: NDArray[np.float32],
    actions: NDArray[np.int64],
    rewards: NDArray[np.float32],
    terminated: NDArray[np.float32],
    next_q_target: NDArray[np.float32],
    next_q_chooser: NDArray[np.float32],
    row_weights: NDArray[np.float32],
    gamma: float,
    huber: bool,
    gradient: NDArray[np.float32],
    targets: NDArray[np.float32],
) -> None:
    """Write the Bellman targets [S, B] and the gradient [S, B, A] of the weighted loss with respect
    to ``q_all``, as :func:`~cartpole.agents.dqn.dqn.td_gradient`'s torch form computes them."""
    seeds, rows, n_actions = q_all.shape
    discount, one, limit = np.float32(gamma), np.float32(1.0), np.float32(1.0)
    for s in range(seeds):
        for b in range(rows):
            chosen = first_argmax(next_q_chooser, s, b)
            target = rewards[s, b] + discount * (one - terminated[s, b]) * next_q_target[s, b, chosen]
            targets[s, b] = target
            taken = actions[s, b, 0]
            error = q_all[s, b, taken] - target
            if huber:  # clamp(-1, 1); a NaN stays NaN
                if error < -limit:
                    error = -limit
                elif error > limit:
                    error = limit
            else:
                error = np.float32(2.0) * error
            for a in range(n_actions):
                gradient[s, b, a] = 0.0
            gradient[s, b, taken] = error * row_weights[s, b]
