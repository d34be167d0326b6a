"""What REINFORCE, A2C and PPO share in their settings and checkpoints: the common settings, the
network a seed starts from, and the greedy policy of a checkpoint.

``PolicyGradientConfig`` holds the settings all three have (network, envs, discount, learning rate
and its schedule, loss coefficients); each agent's config (ppo.py, a2c.py, reinforce.py) adds its own.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, fields
from typing import Any

import torch

from cartpole.agents.actor_critic.network import (
    ACTIVATIONS,
    ActorCritic,
    ActorLogits,
    CategoricalPolicy,
    Standardization,
)
from cartpole.agents.nn.schedules import SCHEDULES
from cartpole.agents.seed_state import unprefixed
from cartpole.core.config import build_config, require
from cartpole.core.errors import ConfigError
from cartpole.core.seeding import derived_seed
from cartpole.envs import EnvInfo, check_simulator
from cartpole.runs import Checkpoint, CheckpointError


@dataclass
class PolicyGradientConfig:
    """Settings every policy-gradient agent has."""

    # network
    hidden_sizes: tuple[int, ...] = (64, 64)
    """Widths of the hidden layers (of each trunk, or of the shared one)."""
    activation: str = "tanh"
    """Hidden-layer activation: tanh, relu or elu."""
    shared_trunk: bool = False
    """One trunk for actor and critic (two heads); false: two separate MLPs."""
    orthogonal_init: bool = True
    """Orthogonal init (gain sqrt(2) hidden, 0.01 policy head, 1 value head); false: torch's default."""
    observation_mean: tuple[float, ...] = ()
    """Subtracted from each observation dimension before the network (with observation_std); fixed,
    not estimated; empty: 0 for every dimension. Flat observations only."""
    observation_std: tuple[float, ...] = ()
    """Each observation dimension is divided by this after observation_mean is subtracted (e.g.
    MountainCar's 0.1,0.005); empty: 1 for every dimension."""
    # collection
    num_envs: int = 8
    """Vector envs stepped together, with one batched forward pass per step."""
    gamma: float = 0.99
    """Discount factor."""
    # optimization
    lr: float = 1e-3
    """Learning rate (the start value of a linear schedule)."""
    lr_schedule: str = "constant"
    """constant, or linear: decays to 0 at schedule_steps env steps."""
    schedule_steps: int = 100_000
    """Env steps over which linear schedules decay to 0 (set it to the budget)."""
    ent_coef: float = 0.0
    """Weight of the entropy bonus in the loss."""
    vf_coef: float = 0.5
    """Weight of the value loss, 0.5 * mean((V - return)^2), in the loss."""
    max_grad_norm: float | None = 0.5
    """Clip the gradient's global norm to this (none: no clipping)."""
    # runtime
    simulator: str = "fast"
    """Training simulator: fast (our batched CartPole; other envs use Gymnasium) or gymnasium."""

    def validate(self) -> None:
        """Reject bad values with one clear line each (every agent's config calls this first)."""
        for field in fields(self):
            value = getattr(self, field.name)
            if isinstance(value, float):
                require(math.isfinite(value), f"{field.name} must be a finite number, got {value}")
        require(len(self.hidden_sizes) >= 1, "hidden_sizes needs at least one layer, e.g. 64,64")
        require(all(h >= 1 for h in self.hidden_sizes), "hidden_sizes must all be >= 1")
        require(self.activation in ACTIVATIONS, f"activation must be one of {', '.join(ACTIVATIONS)}")
        require(self.num_envs >= 1, f"num_envs must be >= 1, got {self.num_envs}")
        require(0.0 <= self.gamma <= 1.0, f"gamma must be in [0, 1], got {self.gamma}")
        require(self.lr > 0, f"lr must be > 0, got {self.lr}")
        require(self.lr_schedule in SCHEDULES, f"lr_schedule must be one of {', '.join(SCHEDULES)}")
        require(self.schedule_steps >= 1, f"schedule_steps must be >= 1, got {self.schedule_steps}")
        require(self.ent_coef >= 0, f"ent_coef must be >= 0, got {self.ent_coef}")
        require(self.vf_coef >= 0, f"vf_coef must be >= 0, got {self.vf_coef}")
        require(
            all(math.isfinite(m) for m in self.observation_mean), "observation_mean must be finite numbers"
        )
        require(
            all(math.isfinite(s) and s > 0 for s in self.observation_std),
            "observation_std must be finite numbers > 0",
        )
        require(self.max_grad_norm is None or self.max_grad_norm > 0, "max_grad_norm must be > 0 or none")
        check_simulator(self.simulator)


def standardization(config: PolicyGradientConfig, obs_shape: tuple[int, ...]) -> Standardization | None:
    """The (mean, std) constants of ``config.observation_mean``/``observation_std`` for observations
    of ``obs_shape``, None when both are empty; ConfigError when they do not fit the observations."""
    mean, std = config.observation_mean, config.observation_std
    if not mean and not std:
        return None
    if len(obs_shape) != 1:
        raise ConfigError(
            f"observation_mean and observation_std apply to flat observations, not images {list(obs_shape)}: "
            "leave them empty"
        )
    (dims,) = obs_shape
    for name, values in (("observation_mean", mean), ("observation_std", std)):
        if values and len(values) != dims:
            raise ConfigError(
                f"{name} needs {dims} numbers (one for each observation dimension), not {len(values)}"
            )
    return (tuple(mean) or (0.0,) * dims, tuple(std) or (1.0,) * dims)


def seeded_actor_critic(config: PolicyGradientConfig, env: EnvInfo, seed: int) -> ActorCritic:
    """The network a learner of ``seed`` starts from (a population's seeds start from the same)."""
    return ActorCritic(
        env.obs_shape,
        env.n_actions,
        config.hidden_sizes,
        config.activation,
        config.shared_trunk,
        config.orthogonal_init,
        generator=torch.Generator().manual_seed(derived_seed(seed, "init")),
        standardize=standardization(config, env.obs_shape),
    )


def observation_shape(learner: dict[str, Any]) -> tuple[int, ...]:
    """The observation shape a checkpoint's ``learner`` data names (checkpoints written before
    image observations name only ``obs_dim``: flat)."""
    if "obs_shape" in learner:
        return tuple(int(n) for n in learner["obs_shape"])
    return (int(learner["obs_dim"]),)


def policy_loader(agent: str, config_cls: type) -> Callable[[Checkpoint], CategoricalPolicy]:
    """``policy_from_checkpoint`` for an agent whose checkpoints hold an ActorCritic as ``model.*``."""
    load_model = model_loader(agent, config_cls)

    def policy_from_checkpoint(checkpoint: Checkpoint) -> CategoricalPolicy:
        return CategoricalPolicy(load_model(checkpoint))

    return policy_from_checkpoint


def logits_loader(agent: str, config_cls: type) -> Callable[[Checkpoint], ActorLogits]:
    """``scores_network`` for such an agent: the action logits its greedy policy takes the argmax of."""
    load_model = model_loader(agent, config_cls)

    def logits_from_checkpoint(checkpoint: Checkpoint) -> ActorLogits:
        return ActorLogits(load_model(checkpoint))

    return logits_from_checkpoint


def model_loader(agent: str, config_cls: type) -> Callable[[Checkpoint], ActorCritic]:
    """The :class:`ActorCritic` (observation standardization included) of a checkpoint of ``agent``
    (``model.*``); CheckpointError when it does not fit."""

    def model_from_checkpoint(checkpoint: Checkpoint) -> ActorCritic:
        try:
            config = build_config(config_cls, checkpoint.meta["config"])
            data = checkpoint.meta["learner"]
            obs_shape = observation_shape(data)
            model = ActorCritic(
                obs_shape,
                int(data["n_actions"]),
                config.hidden_sizes,
                config.activation,
                config.shared_trunk,
                orthogonal_init=False,
                generator=torch.Generator(),
                standardize=standardization(config, obs_shape),
            )
            model.load_state_dict(unprefixed(checkpoint.tensors, "model."))
        except (KeyError, RuntimeError, TypeError, ValueError) as err:
            raise CheckpointError(f"not a usable {agent} checkpoint: {err!s:.120}") from err
        return model

    return model_from_checkpoint
