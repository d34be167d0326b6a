"""Small MLP policies' greedy forward pass, compiled, and whole episodes of our CartPole played by it.

An evaluation on our simulator steps every episode with a forward pass, an argmax and a physics
step; through NumPy and the vector env each is a handful of calls whose overhead costs more than
their arithmetic (a 10-episode screen of PPO's 16x16 network: about 20 us per step of all ten).
:meth:`CompiledMLP.play_cartpole` runs the policy and the physics together in one numba loop
(:mod:`cartpole.agents.nn._greedy_play_kernels`): a fraction of that CPU (benchmarks/README.md#kernels,
the greedy-episodes rows). The physics is the simulator's own float64 step, and the greedy policies
(:class:`~cartpole.agents.nn.numpy_mlp.NumpyMLP`, a population's
:class:`~cartpole.agents.nn.numpy_mlp.StackedGreedyActor`) compute their outputs with the same
compiled forward pass wherever they act (:meth:`CompiledMLP.__call__`), so the episodes are those
the same policy plays on Gymnasium's own env, bit for bit. Compiled without ``fastmath``, a policy's
outputs are the same on every CPU.

What compiles: plans (:data:`~cartpole.agents.nn.numpy_mlp.Step` lists) of linear layers, each
followed by ReLU, tanh or nothing. Anything else (standardized observations, other activations, a
dueling head) has no compiled form: it acts through NumPy, and the vector env steps its episodes.
"""

from __future__ import annotations

import functools
from types import ModuleType
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from cartpole.envs.fast import packed_params
from cartpole.envs.params import CartPoleParams

if TYPE_CHECKING:  # numpy_mlp imports this module
    from cartpole.agents.nn.numpy_mlp import Step


@functools.cache
def _kernels() -> ModuleType:
    """The numba kernel, compiled on first use (importing this module does not import numba)."""
    from cartpole.agents.nn import _greedy_play_kernels

    return _greedy_play_kernels


NO_ACTIVATION, RELU, TANH = 0, 1, 2
"""The kernel's codes of what follows a linear layer."""


class CompiledMLP:
    """One network, or a stack of S networks of one shape, in the kernels' form: each network's
    layers flat in a row of ``weights`` ``[S, P]``, the layers' shapes ``[L, 2]`` and the code of
    the activation after each ``[L]``. Called, it gives the outputs of rows; :meth:`play_cartpole`
    plays whole episodes with them."""

    def __init__(
        self, weights: NDArray[np.float32], shapes: NDArray[np.int64], activations: NDArray[np.int64]
    ):
        self.weights, self.shapes, self.activations = weights, shapes, activations

    @classmethod
    def of(cls, plan: list[Step], activation_codes: dict[Any, int]) -> CompiledMLP | None:
        """The kernel form of ``plan`` (weights ``[S, in, out]`` and biases ``[S, 1, out]``, or one
        network's ``[in, out]`` and ``[out]``; ``activation_codes`` maps the plan's activation
        functions to the kernels' codes); None unless the plan is linear layers with those
        activations after them."""
        layers: list[tuple[np.ndarray, np.ndarray]] = []
        activations: list[int] = []
        for step in plan:
            if isinstance(step, tuple):
                layers.append(step)
                activations.append(NO_ACTIVATION)
            elif layers and activations[-1] == NO_ACTIVATION and step in activation_codes:
                activations[-1] = activation_codes[step]
            else:
                return None
        if not layers:
            return None
        networks = 1 if layers[0][0].ndim == 2 else layers[0][0].shape[0]
        rows = []
        for weight, bias in layers:
            rows += [weight.reshape(networks, -1), bias.reshape(networks, -1)]
        flat = np.ascontiguousarray(np.concatenate(rows, axis=1), dtype=np.float32)
        shapes = np.array([weight.shape[-2:] for weight, _ in layers], dtype=np.int64)
        return cls(flat, shapes, np.array(activations, dtype=np.int64))

    @property
    def count(self) -> int:
        """How many networks (S)."""
        return len(self.weights)

    def subset(self, networks: np.ndarray) -> CompiledMLP:
        """Networks ``networks`` (indices) only, in that order."""
        return CompiledMLP(np.ascontiguousarray(self.weights[networks]), self.shapes, self.activations)

    def __call__(self, x: np.ndarray) -> NDArray[np.float32]:
        """The outputs ``[..., out]`` of inputs ``x``: ``[S, B, in]`` (network b's rows in ``x[b]``),
        or ``[B, in]`` for one network."""
        rows = np.ascontiguousarray(x, dtype=np.float32).reshape(-1, self.shapes[0, 0])
        out = np.empty((len(rows), self.shapes[-1, 1]), dtype=np.float32)
        per_network = max(len(rows) // self.count, 1)
        _kernels().forward_rows(self.weights, self.shapes, self.activations, rows, per_network, out)
        return out.reshape(*x.shape[:-1], self.shapes[-1, 1])

    def play_cartpole(
        self, states: NDArray[np.float64], params: CartPoleParams, max_episode_steps: int, block_size: int
    ) -> NDArray[np.int64] | None:
        """The lengths ``[n]`` of greedy episodes (the argmax of the outputs) from start states
        ``states`` ``[n, 4]`` on cart-poles of ``params``, truncated at ``max_episode_steps``: episode
        e played by network ``e // block_size``. None unless the networks take CartPole's 4
        observations and there are as many blocks as networks."""
        if self.shapes[0, 0] != 4 or len(states) != self.count * block_size:
            return None
        lengths = np.zeros(len(states), dtype=np.int64)
        columns = np.ascontiguousarray(np.asarray(states, dtype=np.float64).T)
        p = packed_params(params, np.dtype(np.float64))
        _kernels().play_episodes(
            self.weights, self.shapes, self.activations, columns, block_size, p, max_episode_steps, lengths
        )
        return lengths


__all__ = ["NO_ACTIVATION", "RELU", "TANH", "CompiledMLP"]
