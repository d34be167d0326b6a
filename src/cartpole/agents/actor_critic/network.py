"""The actor-critic network of the policy-gradient agents (REINFORCE, A2C, PPO), and their policy.

- ``ActorCritic``: an MLP from observations to action logits (the actor) and a state value (the
  critic), with separate trunks or one shared trunk, and optional orthogonal initialization (the
  scheme CleanRL and Stable-Baselines3 use: gain sqrt(2) on hidden layers, 0.01 on the policy head,
  1 on the value head, zero biases).
- ``CategoricalPolicy``: the greedy policy of a trained actor, frozen: ``scores`` are the action
  probabilities, ``act`` their argmax. It runs the actor with numpy on copies of its weights
  (:class:`~cartpole.agents.nn.numpy_mlp.NumpyMLP`).
- ``schedule_value``: the constant and linear schedules of learning rate and clip range.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence

import numpy as np
import torch
from torch import nn

from cartpole.agents.nn.numpy_mlp import NumpyMLP, StackedNumpyMLP
from cartpole.evaluation import BlockActor

ACTIVATIONS: dict[str, type[nn.Module]] = {"tanh": nn.Tanh, "relu": nn.ReLU, "elu": nn.ELU}
"""Hidden-layer activations; each has a numpy twin (:mod:`cartpole.agents.nn.numpy_mlp`)."""
SCHEDULES = ("constant", "linear")


def schedule_value(start: float, schedule: str, env_steps: int, schedule_steps: int) -> float:
    """``start`` (constant), or ``start`` decayed linearly to 0 at ``schedule_steps`` env steps (linear)."""
    if schedule == "constant":
        return start
    return start * max(0.0, 1.0 - env_steps / schedule_steps)


def mlp(sizes: list[int], activation: str) -> list[nn.Linear | nn.Module]:
    """Linear layers of widths ``sizes``, each followed by ``activation``."""
    layers: list[nn.Module] = []
    for width_in, width_out in itertools.pairwise(sizes):
        layers += [nn.Linear(width_in, width_out), ACTIVATIONS[activation]()]
    return layers


class ActorCritic(nn.Module):
    """Action logits and state values from one MLP (shared trunk) or two (separate trunks).

    ``forward`` returns both; ``logits`` and ``values`` compute one of them alone (acting needs only the
    logits, and with separate trunks skips the critic).
    """

    def __init__(
        self,
        obs_dim: int,
        n_actions: int,
        hidden_sizes: tuple[int, ...],
        activation: str = "tanh",
        shared_trunk: bool = False,
        orthogonal_init: bool = True,
        generator: torch.Generator | None = None,
    ):
        super().__init__()
        self.shared_trunk = shared_trunk
        sizes = [obs_dim, *hidden_sizes]
        # nn.Linear initializes itself from torch's global generator: build under fork_rng, which puts
        # the global state back, then initialize every parameter from ``generator`` (nothing global
        # changes when a learner is built).
        with torch.random.fork_rng(devices=[]):
            self.actor_trunk = nn.Sequential(*mlp(sizes, activation))
            self.critic_trunk = self.actor_trunk if shared_trunk else nn.Sequential(*mlp(sizes, activation))
            self.policy_head = nn.Linear(sizes[-1], n_actions)
            self.value_head = nn.Linear(sizes[-1], 1)
        self.initialize(orthogonal_init, generator)

    def linear_layers(self) -> list[tuple[nn.Linear, float]]:
        """Every linear layer once, with its orthogonal-init gain."""
        trunks = [self.actor_trunk] if self.shared_trunk else [self.actor_trunk, self.critic_trunk]
        hidden = [layer for trunk in trunks for layer in trunk if isinstance(layer, nn.Linear)]
        return [(layer, math.sqrt(2)) for layer in hidden] + [
            (self.policy_head, 0.01),
            (self.value_head, 1.0),
        ]

    @torch.no_grad()
    def initialize(self, orthogonal: bool, generator: torch.Generator | None) -> None:
        """Orthogonal weights (gain sqrt(2) hidden, 0.01 policy head, 1 value head) and zero biases;
        else nn.Linear's own default initialization. Drawn from ``generator``."""
        for layer, gain in self.linear_layers():
            if orthogonal:
                nn.init.orthogonal_(layer.weight, gain, generator=generator)
                nn.init.zeros_(layer.bias)
            else:  # = nn.Linear.reset_parameters, from our generator
                nn.init.kaiming_uniform_(layer.weight, a=math.sqrt(5), generator=generator)
                bound = 1.0 / math.sqrt(layer.in_features)
                nn.init.uniform_(layer.bias, -bound, bound, generator=generator)

    @staticmethod
    def _run(trunk: nn.Sequential, observations: torch.Tensor) -> torch.Tensor:
        # module.forward(x), not module(x): nn.Module.__call__'s hook handling costs more than a small
        # layer's matmul (no hooks are used on these layers).
        features = observations
        for layer in trunk:
            features = layer.forward(features)
        return features

    def forward(self, observations: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(logits [N, n_actions], values [N])."""
        actor_features = self._run(self.actor_trunk, observations)
        critic_features = actor_features if self.shared_trunk else self._run(self.critic_trunk, observations)
        logits = self.policy_head.forward(actor_features)
        return logits, self.value_head.forward(critic_features).squeeze(-1)

    def logits(self, observations: torch.Tensor) -> torch.Tensor:
        return self.policy_head.forward(self._run(self.actor_trunk, observations))

    def values(self, observations: torch.Tensor) -> torch.Tensor:
        return self.value_head.forward(self._run(self.critic_trunk, observations)).squeeze(-1)

    def actor_layers(self) -> list[nn.Module]:
        """The modules from observation to logits, in order."""
        return [*self.actor_trunk, self.policy_head]


# ----------------------------------------------------------------------------------------------
# The greedy policy
# ----------------------------------------------------------------------------------------------


class CategoricalPolicy:
    """The greedy policy of an actor: ``scores`` = action probabilities, ``act`` = their argmax.

    Holds numpy copies of the actor's weights taken when it is built, so it is a frozen snapshot.
    """

    def __init__(self, model: ActorCritic):
        self.logits = NumpyMLP(model.actor_layers())
        """Action logits [N, n_actions] of observations."""

    def scores(self, observations: np.ndarray) -> np.ndarray:
        """Action probabilities, shape [N, n_actions]."""
        logits = self.logits(observations).astype(np.float64)
        logits -= logits.max(axis=1, keepdims=True)
        probabilities = np.exp(logits)
        probabilities /= probabilities.sum(axis=1, keepdims=True)
        return probabilities

    def act(self, observations: np.ndarray) -> np.ndarray:
        return self.logits(observations).argmax(axis=1)


def block_greedy_actor(logits: StackedNumpyMLP, obs_dim: int) -> BlockActor:
    """The greedy actions of S stacked actors (``logits``) as one :data:`BlockActor`: the rows of
    blocks ``blocks`` ``[k * E, obs_dim]``, actor b's E rows in block b, to actions ``[k * E]``. A
    subset of the blocks runs through a stack of those actors only, kept until the subset changes."""
    kept: dict[bytes, StackedNumpyMLP] = {}

    def actors(blocks: np.ndarray) -> StackedNumpyMLP:
        if len(blocks) == logits.count:
            return logits
        key = np.asarray(blocks, dtype=np.int64).tobytes()
        if key not in kept:
            kept.clear()
            kept[key] = logits.subset(blocks)
        return kept[key]

    def act(observations: np.ndarray, blocks: np.ndarray) -> np.ndarray:
        x = np.asarray(observations, dtype=np.float32).reshape(len(blocks), -1, obs_dim)
        return actors(blocks)(x).argmax(axis=-1).reshape(-1)

    return act


def stacked_greedy_actor(policies: Sequence[object], obs_dim: int) -> BlockActor | None:
    """:func:`block_greedy_actor` of ``policies`` when they are :class:`CategoricalPolicy` objects of
    one shape (a population's verdicts), else None. Each policy's actions are those it takes alone."""
    if not all(isinstance(p, CategoricalPolicy) for p in policies):
        return None
    stacked = StackedNumpyMLP.stack([p.logits for p in policies])  # type: ignore[attr-defined]
    return None if stacked is None else block_greedy_actor(stacked, obs_dim)


__all__ = [
    "ACTIVATIONS",
    "SCHEDULES",
    "ActorCritic",
    "CategoricalPolicy",
    "block_greedy_actor",
    "schedule_value",
    "stacked_greedy_actor",
]
