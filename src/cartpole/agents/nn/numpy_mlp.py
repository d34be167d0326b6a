"""NumPy twins of small torch MLPs, what the agents act through: :class:`NumpyMLP`, a frozen copy of
one network (the greedy policies, CategoricalPolicy and QNetworkPolicy), and :class:`StackedNumpyMLP`,
S networks of one shape run as one (a rollout's actors, DQN's epsilon-greedy step, a population's
evaluations).

Why NumPy: acting runs a few rows at a time (one per step in the web app, one per env in an
evaluation or a batched env step), where torch's per-op overhead costs more than the arithmetic, and
``np.matmul`` on the weights acts several times faster than torch's forward pass on the same ones
(benchmarks/README.md#kernels, the acting rows). Copying the weights also makes a policy a snapshot
that later training cannot change. A convolutional network has no twin: convolutions are torch's
strength, and it acts through torch.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable

import numpy as np
from torch import nn

from cartpole.agents.nn.fast_tanh import tanh_array
from cartpole.agents.nn.standardize import StandardizeObservations
from cartpole.evaluation import BlockActor


def _relu(x: np.ndarray) -> np.ndarray:
    return np.maximum(x, 0.0, out=x)


def _tanh(x: np.ndarray) -> np.ndarray:
    return tanh_array(x, out=x)


def _elu(x: np.ndarray) -> np.ndarray:
    return np.where(x > 0.0, x, np.expm1(np.minimum(x, 0.0)))


def _gelu(x: np.ndarray) -> np.ndarray:
    """``nn.GELU()``'s exact form, ``x * Phi(x)``."""
    from scipy.special import erf

    return (0.5 * x * (1.0 + erf(x / math.sqrt(2.0)))).astype(x.dtype)


NUMPY_ACTIVATIONS: dict[type[nn.Module], Callable[[np.ndarray], np.ndarray]] = {
    nn.ReLU: _relu,
    nn.Tanh: _tanh,
    nn.ELU: _elu,
    nn.GELU: _gelu,
}


Step = tuple[np.ndarray, np.ndarray] | Callable[[np.ndarray], np.ndarray]
"""A step of a numpy forward pass: (weight ``[..., in, out]``, bias ``[..., out]``), or an activation
or the observations' standardization (:class:`~cartpole.agents.nn.standardize.Standardize`)."""


def run_steps(plan: list[Step], features: np.ndarray) -> np.ndarray:
    """``features`` through ``plan``: ``x W + b`` for a linear step, the function for an activation."""
    for step in plan:
        if isinstance(step, tuple):
            features = np.matmul(features, step[0])
            features += step[1]
        else:
            features = step(features)
    return features


def is_dropout(layer: nn.Module) -> bool:
    """Dropout of any kind (torch's or a hand-written one): the identity when a policy acts."""
    return "dropout" in type(layer).__name__.lower()


class NumpyMLP:
    """Linear layers and activations, in order, run with numpy on float32 copies of the weights.

    Dropout layers are left out (a greedy policy acts in eval mode); any other module is refused.
    """

    def __init__(self, layers: Iterable[nn.Module]):
        self.plan: list[Step] = []
        """Weights ``[in, out]`` (the transpose of torch's) and biases ``[out]``, and the activations."""
        for layer in layers:
            if isinstance(layer, nn.Linear):
                weight = layer.weight.detach().cpu().numpy().T.copy()
                self.plan.append((weight, layer.bias.detach().cpu().numpy().copy()))
            elif type(layer) in NUMPY_ACTIVATIONS:
                self.plan.append(NUMPY_ACTIVATIONS[type(layer)])
            elif isinstance(layer, StandardizeObservations):
                self.plan.append(layer.constants)
            elif not is_dropout(layer):
                raise TypeError(f"no numpy form for {type(layer).__name__}")

    def __call__(self, inputs: np.ndarray) -> np.ndarray:
        return run_steps(self.plan, np.asarray(inputs, dtype=np.float32))


class StackedNumpyMLP:
    """S networks of one shape run as one: inputs ``[S, B, in]`` to outputs ``[S, B, out]``, one
    ``np.matmul`` per layer for all of them. ``np.matmul`` multiplies each network's slice on its own,
    so a network's outputs do not depend on the others beside it (tested)."""

    def __init__(self, plan: list[Step]):
        self.plan = plan
        """Weights ``[S, in, out]`` and biases ``[S, 1, out]``, and the activations."""

    @classmethod
    def stack(cls, mlps: list[NumpyMLP]) -> StackedNumpyMLP | None:
        """The MLPs as one, or None when their layers differ in shape or activation."""
        plans = [mlp.plan for mlp in mlps]
        first = plans[0]
        if any(len(p) != len(first) for p in plans):
            return None
        plan: list[Step] = []
        for index, step in enumerate(first):
            steps = [p[index] for p in plans]
            if isinstance(step, tuple):
                if not all(isinstance(s, tuple) and s[0].shape == step[0].shape for s in steps):
                    return None
                weights = np.stack([s[0] for s in steps])  # type: ignore[index]
                biases = np.stack([s[1] for s in steps])[:, None, :]  # type: ignore[index]
                plan.append((weights, biases))
            elif all(s == step for s in steps):  # the same activation, or equal constants
                plan.append(step)
            else:
                return None
        return cls(plan)

    @property
    def count(self) -> int:
        """How many networks (S)."""
        return next(step[0].shape[0] for step in self.plan if isinstance(step, tuple))

    def subset(self, networks: np.ndarray) -> StackedNumpyMLP:
        """Networks ``networks`` (indices) only, in that order, as a new stack (copies their weights)."""
        plan = [(s[0][networks], s[1][networks]) if isinstance(s, tuple) else s for s in self.plan]
        return StackedNumpyMLP(plan)

    def __call__(self, inputs: np.ndarray) -> np.ndarray:
        return run_steps(self.plan, np.asarray(inputs, dtype=np.float32))


def stacked_block_actor(
    networks: list[StackedNumpyMLP],
    obs_dim: int,
    scores: Callable[[list[StackedNumpyMLP], np.ndarray], np.ndarray],
) -> BlockActor:
    """The greedy actions of stacks of S networks as one :data:`~cartpole.evaluation.BlockActor`: the
    rows of blocks ``blocks`` ``[k * E, obs_dim]`` (network b's E rows in block b) to the argmax of
    ``scores(networks, rows [k, E, obs_dim])``, ``[k * E]``. A subset of the blocks runs through
    stacks of those networks only, kept until the subset changes."""
    kept: dict[bytes, list[StackedNumpyMLP]] = {}

    def subset(blocks: np.ndarray) -> list[StackedNumpyMLP]:
        if len(blocks) == networks[-1].count:
            return networks
        key = np.asarray(blocks, dtype=np.int64).tobytes()
        if key not in kept:
            kept.clear()
            kept[key] = [network.subset(np.asarray(blocks)) for network in networks]
        return kept[key]

    def act(observations: np.ndarray, blocks: np.ndarray) -> np.ndarray:
        x = np.asarray(observations, dtype=np.float32).reshape(len(blocks), -1, obs_dim)
        return scores(subset(blocks), x).argmax(axis=-1).reshape(-1)

    return act


__all__ = ["NUMPY_ACTIVATIONS", "NumpyMLP", "StackedNumpyMLP", "stacked_block_actor"]
