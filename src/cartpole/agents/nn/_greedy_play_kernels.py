"""Numba kernels behind :mod:`cartpole.agents.nn.greedy_play` (imported lazily, on first use).

:func:`forward` is a small MLP's forward pass on one row, the one place a greedy policy's arithmetic
is written: :func:`forward_rows` runs it over rows (a policy acting on observations), and
:func:`play_episodes` plays whole episodes with it, step after step the forward pass on the float32
observation, its argmax, and one step of the simulator's own float64 physics
(:func:`cartpole.envs._fast_kernels.advance`, the one place the equations are written). So a policy
acts the same, bit for bit, in both. The layers' products run output-innermost (each output a sum
over the inputs in order), which LLVM vectorizes across a layer's units; the activations are ReLU
and the rational tanh of :func:`~cartpole.agents.nn._tanh_kernels.tanh_f32`.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numba import njit
from numpy.typing import NDArray

from cartpole.agents.nn._tanh_kernels import tanh_f32
from cartpole.agents.nn.greedy_play import RELU, TANH
from cartpole.envs._fast_kernels import FORCE_MAG, advance, physics_constants

# No fastmath: LLVM neither reorders nor fuses (FMA) a float operation, so a policy's actions are the
# same on every CPU, and the physics inlined here keeps Gymnasium's bits.
_JIT: dict[str, Any] = {"cache": True, "nogil": True, "error_model": "numpy"}


@njit(**_JIT, inline="always")
def forward(
    w: NDArray[np.float32],
    shapes: NDArray[np.int64],
    activations: NDArray[np.int64],
    first: NDArray[np.float32],
    second: NDArray[np.float32],
) -> NDArray[np.float32]:
    """The outputs of network ``w`` (its layers one after the other, each a weight ``[in, out]`` then
    a bias ``[out]``, flat; ``shapes[l]`` is layer l's ``(in, out)``, ``activations[l]`` what follows
    it) for the input in ``first[:in]``: a view of ``first`` or ``second`` (both as wide as the widest
    layer, and overwritten)."""
    inputs, outputs = first, second
    offset = 0
    n_out = 0
    for layer in range(shapes.shape[0]):
        n_in, n_out = shapes[layer, 0], shapes[layer, 1]
        # Slices, not w[offset + j]: indices from range() need no wraparound check, so the loops
        # over j vectorize.
        acc = outputs[:n_out]
        acc[:] = 0.0
        for i in range(n_in):
            value = inputs[i]
            row = w[offset + i * n_out : offset + (i + 1) * n_out]
            for j in range(n_out):
                acc[j] += value * row[j]
        offset += n_in * n_out
        bias = w[offset : offset + n_out]
        offset += n_out
        for j in range(n_out):
            acc[j] += bias[j]
        if activations[layer] == RELU:
            for j in range(n_out):
                acc[j] = max(acc[j], np.float32(0.0))
        elif activations[layer] == TANH:
            for j in range(n_out):
                acc[j] = tanh_f32(acc[j])
        inputs, outputs = outputs, inputs
    return inputs[:n_out]


@njit(**_JIT, inline="always")
def scratch(shapes: NDArray[np.int64]) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """:func:`forward`'s two buffers, as wide as the input and the widest layer."""
    width = shapes[0, 0]
    for layer in range(shapes.shape[0]):
        width = max(width, shapes[layer, 1])
    return np.empty(width, dtype=np.float32), np.empty(width, dtype=np.float32)


@njit(**_JIT)
def forward_rows(
    weights: NDArray[np.float32],
    shapes: NDArray[np.int64],
    activations: NDArray[np.int64],
    x: NDArray[np.float32],
    rows_per_network: int,
    out: NDArray[np.float32],
) -> None:
    """``out[r]`` = the outputs of network ``r // rows_per_network`` (``weights[b]``: see
    :func:`forward`) for input row ``x[r]``."""
    first, second = scratch(shapes)
    n_in = shapes[0, 0]
    for r in range(x.shape[0]):
        for i in range(n_in):
            first[i] = x[r, i]
        result = forward(weights[r // rows_per_network], shapes, activations, first, second)
        for j in range(result.shape[0]):
            out[r, j] = result[j]


@njit(**_JIT)
def play_episodes(
    weights: NDArray[np.float32],
    shapes: NDArray[np.int64],
    activations: NDArray[np.int64],
    states: NDArray[np.float64],
    block_size: int,
    p: NDArray[np.float64],
    max_episode_steps: int,
    lengths: NDArray[np.int64],
) -> None:
    """Play episode ``e`` from start state ``states[:, e]`` (``(4, n)``, float64) with network
    ``e // block_size`` (``weights[b]``: see :func:`forward`) until it terminates or reaches
    ``max_episode_steps``; its length into ``lengths[e]``. The action is the first index of the
    largest output (numpy's argmax); the observation, the float32 state (the envs' own)."""
    first, second = scratch(shapes)
    constants = physics_constants(p)
    force_mag = p[FORCE_MAG]
    for e in range(states.shape[1]):
        w = weights[e // block_size]
        x, x_dot, theta, theta_dot = states[0, e], states[1, e], states[2, e], states[3, e]
        steps = 0
        done = False
        while not done:
            first[0], first[1] = np.float32(x), np.float32(x_dot)
            first[2], first[3] = np.float32(theta), np.float32(theta_dot)
            scores = forward(w, shapes, activations, first, second)
            action = 0
            for k in range(1, scores.shape[0]):
                if scores[k] > scores[action]:
                    action = k
            force = force_mag if action == 1 else -force_mag
            x, x_dot, theta, theta_dot, terminated = advance(x, x_dot, theta, theta_dot, force, constants)
            steps += 1
            done = terminated or steps >= max_episode_steps
        lengths[e] = steps
