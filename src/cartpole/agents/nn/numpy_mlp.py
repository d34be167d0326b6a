"""NumPy twins of small torch MLPs, what the agents act through: :class:`NumpyMLP`, a frozen copy of
one network (the greedy policies, CategoricalPolicy and QNetworkPolicy), and :class:`StackedNumpyMLP`,
S networks of one shape run as one (a rollout's actors, DQN's epsilon-greedy step, a population's
evaluations).

Why NumPy: acting runs a few rows at a time (one per step in the web app, one per env in an
evaluation or a batched env step), where torch's per-op overhead costs more than the arithmetic, and
a product of our own on the weights (:mod:`~cartpole.agents.nn.fixed_order`, on NumPy arrays) acts
several times faster than torch's forward pass on the same ones
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
from cartpole.agents.nn.fixed_order import matmul_arrays
from cartpole.agents.nn.fused_mlp import forward_arrays
from cartpole.agents.nn.greedy_play import RELU, TANH, CompiledMLP
from cartpole.agents.nn.standardize import StandardizeObservations
from cartpole.envs.params import CartPoleParams


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


KERNEL_ACTIVATIONS: dict[Callable[[np.ndarray], np.ndarray], int] = {
    _relu: RELU,
    _tanh: TANH,
}
"""The activations the compiled forward pass (:class:`~cartpole.agents.nn.greedy_play.CompiledMLP`)
computes, by the NumPy functions of a plan."""


Step = tuple[np.ndarray, np.ndarray] | Callable[[np.ndarray], np.ndarray]
"""A step of a numpy forward pass: (weight ``[..., in, out]``, bias ``[..., out]``), or an activation
or the observations' standardization (:class:`~cartpole.agents.nn.standardize.Standardize`)."""


def run_steps(plan: list[Step], features: np.ndarray) -> np.ndarray:
    """``features`` through ``plan``: ``x W + b`` for a linear step (in the fixed order of
    :func:`~cartpole.agents.nn.fixed_order.matmul_arrays`, so that a network's outputs are the same
    bits alone and stacked with any others), the function for an activation."""
    for step in plan:
        features = matmul_arrays(features, *step) if isinstance(step, tuple) else step(features)
    return features


def fused_tanh_layers(plan: list[Step]) -> tuple[tuple[np.ndarray, ...], tuple[np.ndarray, ...]] | None:
    """A stacked plan's weights ``[S, in, out]`` and biases ``[S, 1, out]`` when it is a tanh MLP of a
    hidden layer or more with C-contiguous float32 parameters; None otherwise."""
    linear, between = plan[0::2], plan[1::2]
    if len(plan) < 3 or len(plan) % 2 == 0 or any(step is not _tanh for step in between):
        return None
    steps = [step for step in linear if isinstance(step, tuple)]
    if len(steps) != len(linear):
        return None
    arrays = [array for step in steps for array in step]
    if not all(a.dtype == np.float32 and a.ndim == 3 and a.flags.c_contiguous for a in arrays):
        return None
    return tuple(w for w, _ in steps), tuple(b for _, b in steps)


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
        self.compiled = CompiledMLP.of(self.plan, KERNEL_ACTIVATIONS)
        """The plan's compiled form, which computes the outputs when there is one (linear layers with
        ReLU or tanh), so that the same arithmetic acts here and in whole compiled episodes."""

    def __call__(self, inputs: np.ndarray) -> np.ndarray:
        if self.compiled is not None:
            return self.compiled(np.asarray(inputs, dtype=np.float32))
        return run_steps(self.plan, np.asarray(inputs, dtype=np.float32))

    def play_cartpole(
        self, states: np.ndarray, params: CartPoleParams, max_episode_steps: int, block_size: int
    ) -> np.ndarray | None:
        """Whole greedy episodes (the argmax of the outputs) on our float64 CartPole, in one compiled
        call (:meth:`~cartpole.agents.nn.greedy_play.CompiledMLP.play_cartpole`)."""
        if self.compiled is None:
            return None
        return self.compiled.play_cartpole(states, params, max_episode_steps, len(states))


class StackedNumpyMLP:
    """S networks of one shape run as one: inputs ``[S, B, in]`` to outputs ``[S, B, out]``, one
    fixed-order product per layer for all of them (:func:`run_steps`), so a network's outputs do not
    depend on the others beside it (tested)."""

    def __init__(self, plan: list[Step]):
        self.plan = plan
        """Weights ``[S, in, out]`` and biases ``[S, 1, out]``, and the activations."""
        self.fused = fused_tanh_layers(plan)
        """The weights and biases of a tanh MLP of a hidden layer or more, which runs in one compiled
        call (:func:`~cartpole.agents.nn.fused_mlp.forward_arrays`, the same bits); else None."""

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
        features = np.asarray(inputs, dtype=np.float32)
        if self.fused is not None and features.ndim == 3 and features.shape[0] == self.count:
            return forward_arrays(features, *self.fused)
        return run_steps(self.plan, features)

    def then(self, other: StackedNumpyMLP) -> StackedNumpyMLP:
        """This stack followed by ``other`` (network b's outputs into network b), as one."""
        return StackedNumpyMLP(self.plan + other.plan)


class StackedGreedyActor:
    """The greedy actions of stacks of S networks as one :data:`~cartpole.evaluation.BlockActor`: the
    rows of blocks ``blocks`` ``[k * E, obs_dim]`` (network b's E rows in block b) to the argmax of
    ``scores(networks, rows [k, E, obs_dim])``, ``[k * E]``. A subset of the blocks runs through
    stacks of those networks only, kept until the subset changes.

    When the scores are one stack's outputs (``argmax_of``) and it has a compiled form
    (:class:`~cartpole.agents.nn.greedy_play.CompiledMLP`), that computes them, and plays whole
    episodes of our CartPole itself (a :class:`~cartpole.evaluation.CartPolePlayer`): the same
    arithmetic as each network's greedy policy alone (:class:`NumpyMLP`)."""

    def __init__(
        self,
        networks: list[StackedNumpyMLP],
        obs_dim: int,
        scores: Callable[[list[StackedNumpyMLP], np.ndarray], np.ndarray],
        argmax_of: StackedNumpyMLP | None = None,
    ):
        self.networks, self.obs_dim, self.scores = networks, obs_dim, scores
        self.compiled = None if argmax_of is None else CompiledMLP.of(argmax_of.plan, KERNEL_ACTIVATIONS)
        self.kept: dict[bytes, list[StackedNumpyMLP]] = {}
        self.kept_compiled: dict[bytes, CompiledMLP] = {}

    def subset(self, blocks: np.ndarray) -> list[StackedNumpyMLP]:
        """The stacks of networks ``blocks`` only (all of them: the stacks themselves)."""
        if len(blocks) == self.networks[-1].count:
            return self.networks
        key = np.asarray(blocks, dtype=np.int64).tobytes()
        if key not in self.kept:
            self.kept.clear()
            self.kept[key] = [network.subset(np.asarray(blocks)) for network in self.networks]
        return self.kept[key]

    def compiled_subset(self, compiled: CompiledMLP, blocks: np.ndarray) -> CompiledMLP:
        """The compiled networks ``blocks`` of ``compiled`` only (all of them: ``compiled`` itself)."""
        if len(blocks) == compiled.count:
            return compiled
        key = np.asarray(blocks, dtype=np.int64).tobytes()
        if key not in self.kept_compiled:
            self.kept_compiled = {key: compiled.subset(np.asarray(blocks))}
        return self.kept_compiled[key]

    def __call__(self, observations: np.ndarray, blocks: np.ndarray) -> np.ndarray:
        x = np.asarray(observations, dtype=np.float32).reshape(len(blocks), -1, self.obs_dim)
        if self.compiled is not None:
            scores = self.compiled_subset(self.compiled, blocks)(x)
        else:
            scores = self.scores(self.subset(blocks), x)
        return scores.argmax(axis=-1).reshape(-1)

    def play_cartpole(
        self, states: np.ndarray, params: CartPoleParams, max_episode_steps: int, block_size: int
    ) -> np.ndarray | None:
        """Whole greedy episodes on our float64 CartPole, network b playing block b, in one compiled
        call (:meth:`~cartpole.agents.nn.greedy_play.CompiledMLP.play_cartpole`)."""
        if self.compiled is None:
            return None
        return self.compiled.play_cartpole(states, params, max_episode_steps, block_size)


__all__ = ["KERNEL_ACTIVATIONS", "NUMPY_ACTIVATIONS", "NumpyMLP", "StackedGreedyActor", "StackedNumpyMLP"]
