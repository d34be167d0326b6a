"""The numba kernel behind :func:`cartpole.agents.actor_critic.ppo.ppo_loss_gradients` on the CPU
(imported on first use): PPO's loss differentiated in closed form, each seed's rows in one pass.

The same formulas as the torch form beside it (whose docstring derives them), computed per row in
float64 and stored as float32; each seed's metrics summed over its rows in row order. So a seed's
bits follow from its own rows alone (no reduction spans seeds, nothing depends on the batch's
shape), and the whole loss is one call instead of some forty tensor operations, each of which costs
more than its arithmetic on a small batch.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numba import njit
from numpy.typing import NDArray

_JIT: dict[str, Any] = {"cache": True, "nogil": True, "error_model": "numpy", "boundscheck": False}


@njit(**_JIT)
def ppo_loss_gradients_into(
    logits: NDArray[np.float32],
    values: NDArray[np.float32],
    actions: NDArray[np.int64],
    old_log_probs: NDArray[np.float32],
    advantages: NDArray[np.float32],
    returns: NDArray[np.float32],
    mask: NDArray[np.float32],
    count: NDArray[np.float32],
    clip: NDArray[np.float32],
    ent_coef: float,
    vf_coef: float,
    logits_grad: NDArray[np.float32],
    values_grad: NDArray[np.float32],
    metrics: NDArray[np.float32],
) -> None:
    """For ``logits`` [S, B, A] and the [S, B] rest (``clip`` and ``count`` [S]), write ``logits_grad``
    [S, B, A], ``values_grad`` [S, B] and ``metrics`` [S, 5] (policy loss, value loss, entropy,
    approximate KL, clip fraction: each the mean over the seed's masked rows)."""
    seeds, rows, n_actions = logits.shape
    log_probs = np.empty(n_actions)
    for s in range(seeds):
        divisor = max(float(count[s]), 1.0)
        low, high = 1.0 - float(clip[s]), 1.0 + float(clip[s])
        sums = np.zeros(5)
        for b in range(rows):
            top = -np.inf
            for a in range(n_actions):
                top = max(top, float(logits[s, b, a]))
            total = 0.0
            for a in range(n_actions):
                total += np.exp(float(logits[s, b, a]) - top)
            shift = top + np.log(total)
            entropy = 0.0
            for a in range(n_actions):
                log_probs[a] = float(logits[s, b, a]) - shift
                entropy -= np.exp(log_probs[a]) * log_probs[a]
            action = actions[s, b]
            log_ratio = log_probs[action] - float(old_log_probs[s, b])
            ratio = np.exp(log_ratio)
            advantage = float(advantages[s, b])
            unclipped = -advantage * ratio
            clipped = -advantage * min(max(ratio, low), high)
            error = float(values[s, b]) - float(returns[s, b])
            weight = float(mask[s, b])
            sums[0] += max(unclipped, clipped) * weight
            sums[1] += 0.5 * error * error * weight
            sums[2] += entropy * weight
            sums[3] += ((ratio - 1.0) - log_ratio) * weight
            sums[4] += (1.0 if abs(ratio - 1.0) > float(clip[s]) else 0.0) * weight
            per_row = weight / divisor
            side = 1.0 if unclipped > clipped else (0.5 if unclipped == clipped else 0.0)
            inside = 1.0 if low < ratio < high else 0.0
            d_ratio = -advantage * (side + (1.0 - side) * inside)
            scale = d_ratio * ratio * per_row
            for a in range(n_actions):
                p = np.exp(log_probs[a])
                g = scale * ((1.0 if a == action else 0.0) - p)
                if ent_coef != 0.0:
                    g += ent_coef * per_row * p * (log_probs[a] + entropy)
                logits_grad[s, b, a] = g
            values_grad[s, b] = vf_coef * per_row * error
        for k in range(5):
            metrics[s, k] = sums[k] / divisor
