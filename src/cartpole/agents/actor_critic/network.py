"""The actor-critic network of the policy-gradient agents (REINFORCE, A2C, PPO), and their policy.

- ``ActorCritic``: an MLP from observations to action logits (the actor) and a state value (the
  critic), with separate trunks or one shared trunk, and optional orthogonal initialization (the
  scheme CleanRL and Stable-Baselines3 use: gain sqrt(2) on hidden layers, 0.01 on the policy head,
  1 on the value head, zero biases). For image observations ``[channels, height, width]`` each trunk
  starts with a small convolutional network (:data:`CONV_LAYERS`, on pixels scaled to [0, 1] and
  inverted: :func:`scale_pixels`) whose flattened output feeds the MLP. The network's ``nn.Module``
  form: what each seed is initialized as and what a checkpoint holds (``model.*``); a population
  trains the stacked form (:mod:`cartpole.agents.actor_critic.stacked`).
- ``CategoricalPolicy``: the greedy policy of a trained actor, frozen: ``scores`` are the action
  probabilities, ``act`` their argmax. It runs the actor with numpy on copies of its weights
  (:class:`~cartpole.agents.nn.numpy_mlp.NumpyMLP`), or, for a convolutional actor (which has no
  numpy twin), with torch on a frozen copy.
"""

from __future__ import annotations

import copy
import itertools
import math
from collections.abc import Sequence

import numpy as np
import torch
from torch import nn

from cartpole.agents.nn import conv
from cartpole.agents.nn.conv import PIXEL_SCALE, ScalePixels, scale_pixels
from cartpole.agents.nn.numpy_mlp import NumpyMLP, StackedGreedyActor, StackedNumpyMLP
from cartpole.agents.nn.standardize import StandardizeObservations
from cartpole.envs.params import CartPoleParams
from cartpole.evaluation import BlockActor

ACTIVATIONS: dict[str, type[nn.Module]] = {"tanh": nn.Tanh, "relu": nn.ReLU, "elu": nn.ELU}
"""Hidden-layer activations; each has a numpy twin (:mod:`cartpole.agents.nn.numpy_mlp`)."""


def mlp(sizes: list[int], activation: str) -> list[nn.Linear | nn.Module]:
    """Linear layers of widths ``sizes``, each followed by ``activation``."""
    layers: list[nn.Module] = []
    for width_in, width_out in itertools.pairwise(sizes):
        layers += [nn.Linear(width_in, width_out), ACTIVATIONS[activation]()]
    return layers


CONV_LAYERS: tuple[tuple[int, int, int], ...] = ((16, 8, 4), (32, 3, 1))
"""(filters, kernel size, stride) of the convolutional layers of an image trunk, each followed by a
ReLU, no padding. Small on purpose: a 4x30x100 frame stack becomes 16x6x24 then 32x4x22 (2,816
features), about 1.2 M multiply-adds a frame with the first hidden layer, cheap enough to train on
a CPU (``benchmarks/kernels.py --pixels`` times the trunk). The 8x8 windows overlap by half, so the
pole's edges (1.7 pixels wide) and their motion across the stacked frames still show in every
window's gray levels."""


def conv_output_size(obs_shape: Sequence[int]) -> int:
    """Features the :data:`CONV_LAYERS` make of one image ``[channels, height, width]``."""
    return conv.conv_output_size(obs_shape, CONV_LAYERS)


Standardization = tuple[tuple[float, ...], tuple[float, ...]]
"""(mean, std) of each observation dimension, for :class:`StandardizeObservations`."""


def trunk(obs_shape: tuple[int, ...], hidden_sizes: tuple[int, ...], activation: str) -> nn.Sequential:
    """The layers from an observation to the last hidden layer: an MLP for flat observations
    ``(obs_dim,)``; for images ``(channels, height, width)``, scaled pixels through the
    :data:`CONV_LAYERS` (ReLU), flattened, then the MLP."""
    if len(obs_shape) == 1:
        return nn.Sequential(*mlp([obs_shape[0], *hidden_sizes], activation))
    layers: list[nn.Module] = [ScalePixels()]
    channels = obs_shape[0]
    for filters, kernel, stride in CONV_LAYERS:
        layers += [nn.Conv2d(channels, filters, kernel, stride), nn.ReLU()]
        channels = filters
    layers.append(nn.Flatten())
    return nn.Sequential(*layers, *mlp([conv_output_size(obs_shape), *hidden_sizes], activation))


def parameter_count(
    obs_shape: tuple[int, ...], n_actions: int, hidden_sizes: tuple[int, ...], shared: bool
) -> int:
    """Parameters of an :class:`ActorCritic` (without building it: memory estimates use it)."""
    features = obs_shape[0]
    conv_weights = 0
    if len(obs_shape) == 3:
        conv_weights = conv.conv_parameters(obs_shape[0], CONV_LAYERS)
        features = conv_output_size(obs_shape)
    sizes = [features, *hidden_sizes]
    one_trunk = conv_weights + sum(n_in * n_out + n_out for n_in, n_out in itertools.pairwise(sizes))
    heads = sizes[-1] * (n_actions + 1) + n_actions + 1
    return one_trunk * (1 if shared else 2) + heads


class ActorCritic(nn.Module):
    """Action logits and state values from one trunk (shared) or two (separate): an MLP, or for
    images a convolutional network and an MLP (:func:`trunk`).

    ``obs_shape`` is an observation's shape (an int: a flat observation of that size); flat
    observations are standardized first when ``standardize`` gives (mean, std) per dimension. ``forward``
    returns both outputs; ``logits`` and ``values`` compute one of them alone (acting needs only the
    logits, and with separate trunks skips the critic).
    """

    def __init__(
        self,
        obs_shape: int | tuple[int, ...],
        n_actions: int,
        hidden_sizes: tuple[int, ...],
        activation: str = "tanh",
        shared_trunk: bool = False,
        orthogonal_init: bool = True,
        generator: torch.Generator | None = None,
        standardize: Standardization | None = None,
    ):
        super().__init__()
        self.shared_trunk = shared_trunk
        self.obs_shape = (obs_shape,) if isinstance(obs_shape, int) else tuple(obs_shape)
        self.standardize = StandardizeObservations(*standardize) if standardize else None
        """Before both trunks (not in them: the layers' names, and so checkpoints, stay the same)."""
        features = hidden_sizes[-1]
        # nn.Linear and nn.Conv2d initialize themselves from torch's global generator: build under
        # fork_rng, which puts the global state back, then initialize every parameter from
        # ``generator`` (nothing global changes when a learner is built).
        with torch.random.fork_rng(devices=[]):
            self.actor_trunk = trunk(self.obs_shape, hidden_sizes, activation)
            self.critic_trunk = (
                self.actor_trunk if shared_trunk else trunk(self.obs_shape, hidden_sizes, activation)
            )
            self.policy_head = nn.Linear(features, n_actions)
            self.value_head = nn.Linear(features, 1)
        self.initialize(orthogonal_init, generator)

    @property
    def is_image(self) -> bool:
        """True when its trunks start with convolutional layers (image observations)."""
        return len(self.obs_shape) == 3

    def linear_layers(self) -> list[tuple[nn.Linear | nn.Conv2d, float]]:
        """Every layer with weights (linear and convolutional) once, with its orthogonal-init gain."""
        trunks = [self.actor_trunk] if self.shared_trunk else [self.actor_trunk, self.critic_trunk]
        hidden = [layer for trunk in trunks for layer in trunk if isinstance(layer, nn.Linear | nn.Conv2d)]
        return [(layer, math.sqrt(2)) for layer in hidden] + [
            (self.policy_head, 0.01),
            (self.value_head, 1.0),
        ]

    @torch.no_grad()
    def initialize(self, orthogonal: bool, generator: torch.Generator | None) -> None:
        """Orthogonal weights (gain sqrt(2) hidden, 0.01 policy head, 1 value head) and zero biases;
        else the layers' own default initialization. Drawn from ``generator``."""
        for layer, gain in self.linear_layers():
            bias = layer.bias
            assert bias is not None  # every layer here is built with one
            if orthogonal:  # a conv weight is orthogonal as [filters, inputs x kernel area]
                nn.init.orthogonal_(layer.weight, gain, generator=generator)
                nn.init.zeros_(bias)
            else:  # = nn.Linear's and nn.Conv2d's reset_parameters, from our generator
                nn.init.kaiming_uniform_(layer.weight, a=math.sqrt(5), generator=generator)
                bound = 1.0 / math.sqrt(layer.weight[0].numel())  # 1 / sqrt(fan_in)
                nn.init.uniform_(bias, -bound, bound, generator=generator)

    def _run(self, trunk: nn.Sequential, observations: torch.Tensor) -> torch.Tensor:
        # module.forward(x), not module(x): nn.Module.__call__'s hook handling costs more than a small
        # layer's matmul (no hooks are used on these layers).
        features = observations if self.standardize is None else self.standardize.forward(observations)
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

    def input_layers(self) -> list[StandardizeObservations]:
        """What comes before either trunk: the observations' standardization, if any."""
        return [] if self.standardize is None else [self.standardize]

    def actor_layers(self) -> list[nn.Module]:
        """The modules from observation to logits, in order."""
        return [*self.input_layers(), *self.actor_trunk, self.policy_head]


class ActorLogits(nn.Module):
    """The actor of an :class:`ActorCritic` alone, frozen: observations -> action logits (what its
    greedy policy takes the argmax of), standardization or pixel scaling included; for export."""

    def __init__(self, model: ActorCritic):
        super().__init__()
        self.model = model.requires_grad_(False).eval()

    def forward(self, observations: torch.Tensor) -> torch.Tensor:
        return self.model.logits(observations)


# ----------------------------------------------------------------------------------------------
# The greedy policy
# ----------------------------------------------------------------------------------------------


class CategoricalPolicy:
    """The greedy policy of an actor: ``scores`` = action probabilities, ``act`` = their argmax.

    Holds numpy copies of the actor's weights taken when it is built (a convolutional actor: a torch
    copy, :class:`TorchActor`), so it is a frozen snapshot.
    """

    def __init__(self, model: ActorCritic):
        self.logits: NumpyMLP | TorchActor = (
            TorchActor(model) if model.is_image else NumpyMLP(model.actor_layers())
        )
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

    def play_cartpole(
        self, states: np.ndarray, params: CartPoleParams, max_episode_steps: int, block_size: int
    ) -> np.ndarray | None:
        """Whole greedy episodes on our float64 CartPole in one compiled call
        (:class:`~cartpole.evaluation.CartPolePlayer`); None for a convolutional actor."""
        if not isinstance(self.logits, NumpyMLP):
            return None
        return self.logits.play_cartpole(states, params, max_episode_steps, block_size)


class TorchActor:
    """The action logits of a frozen copy of an actor, computed with torch: for convolutional actors,
    which have no numpy twin (a frame stack's convolutions are where torch's kernels pay off)."""

    def __init__(self, model: ActorCritic):
        self.model = copy.deepcopy(model).requires_grad_(False)

    @torch.no_grad()
    def __call__(self, observations: np.ndarray) -> np.ndarray:
        """Logits [N, n_actions] of observations [N, *obs_shape] (uint8 pixels or their float values)."""
        batch = torch.as_tensor(np.asarray(observations)).reshape(-1, *self.model.obs_shape)
        return self.model.logits(batch).numpy()


def block_greedy_actor(logits: StackedNumpyMLP, obs_dim: int) -> BlockActor:
    """The greedy actions of S stacked actors (``logits``) as one :data:`BlockActor`
    (:class:`~cartpole.agents.nn.numpy_mlp.StackedGreedyActor`, which plays whole episodes of our
    CartPole itself)."""
    return StackedGreedyActor([logits], obs_dim, lambda actors, x: actors[0](x), argmax_of=logits)


def stacked_greedy_actor(policies: Sequence[object], obs_dim: int) -> BlockActor | None:
    """:func:`block_greedy_actor` of ``policies`` when they are :class:`CategoricalPolicy` objects of
    one shape (a population's verdicts), else None. Each policy's actions are those it takes alone."""
    if not all(isinstance(p, CategoricalPolicy) and isinstance(p.logits, NumpyMLP) for p in policies):
        return None  # convolutional actors act one by one (each already batches its episodes)
    stacked = StackedNumpyMLP.stack([p.logits for p in policies])  # type: ignore[attr-defined]
    return None if stacked is None else block_greedy_actor(stacked, obs_dim)


__all__ = [
    "ACTIVATIONS",
    "CONV_LAYERS",
    "PIXEL_SCALE",
    "ActorCritic",
    "ActorLogits",
    "CategoricalPolicy",
    "ScalePixels",
    "Standardization",
    "TorchActor",
    "block_greedy_actor",
    "conv_output_size",
    "parameter_count",
    "scale_pixels",
    "stacked_greedy_actor",
]
