"""What REINFORCE, A2C and PPO share: the common settings, and the learner's plumbing.

``PolicyGradientConfig`` holds the settings all three have (network, envs, discount, learning rate
and its schedule, loss coefficients); each agent's config adds its own. ``PolicyGradientLearner``
builds the actor-critic, the collector and the generators, and does the checkpoint and exact-resume
work, so that each agent's module is only its collection and its update (``learn``).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, fields
from typing import Any

import numpy as np
import torch

from cartpole.agents.actor_critic import (
    ACTIVATIONS,
    SCHEDULES,
    ActorCritic,
    CategoricalPolicy,
    schedule_value,
)
from cartpole.agents.nn.optimizers import FusedAdam, Optimizer
from cartpole.agents.rollout import RolloutBuffer, RolloutCollector, generalized_advantages
from cartpole.core.config import build_config, require
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
        require(self.max_grad_norm is None or self.max_grad_norm > 0, "max_grad_norm must be > 0 or none")
        check_simulator(self.simulator)


@dataclass
class Batch:
    """The valid transitions of a rollout, flattened, with their advantages."""

    observations: torch.Tensor
    actions: torch.Tensor
    log_probs: torch.Tensor
    values: torch.Tensor
    advantages: torch.Tensor
    returns: torch.Tensor

    def __len__(self) -> int:
        return len(self.actions)

    def __getitem__(self, index: torch.Tensor) -> Batch:
        return Batch(*(getattr(self, f.name)[index] for f in fields(self)))


def policy_loss_terms(
    model: ActorCritic, observations: torch.Tensor, actions: torch.Tensor, entropy_grad: bool = True
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(log-probabilities of ``actions``, mean entropy, values) under the current network.

    Without ``entropy_grad`` the entropy is only a metric (an entropy coefficient of 0): computed
    outside autograd, it adds nothing to the backward pass.
    """
    logits, values = model(observations)
    log_probs_all = torch.log_softmax(logits, dim=-1)
    log_probs = log_probs_all.gather(1, actions.unsqueeze(1)).squeeze(1)
    with torch.set_grad_enabled(entropy_grad and torch.is_grad_enabled()):
        entropy = -(log_probs_all.exp() * log_probs_all).sum(dim=-1).mean()
    return log_probs, entropy, values


def seeded_actor_critic(config: PolicyGradientConfig, env: EnvInfo, seed: int) -> ActorCritic:
    """The network a learner of ``seed`` starts from (a population's seeds start from the same)."""
    return ActorCritic(
        env.obs_dim,
        env.n_actions,
        config.hidden_sizes,
        config.activation,
        config.shared_trunk,
        config.orthogonal_init,
        generator=torch.Generator().manual_seed(derived_seed(seed, "init")),
    )


class PolicyGradientLearner:
    """The shared part of the learners: network, collector, generators, checkpoints."""

    def __init__(
        self,
        config: PolicyGradientConfig,
        env: EnvInfo,
        seed: int,
        device: str,
        rollout_steps: int,
        make_optimizer: Callable[[list[torch.Tensor]], Optimizer],
    ):
        config.validate()
        self.config, self.env_info, self.seed = config, env, seed
        self.device = torch.device(device)
        self.model = seeded_actor_critic(config, env, seed).to(self.device)
        self.parameters: list[torch.Tensor] = list(self.model.parameters())
        self.optimizer = make_optimizer(self.parameters)
        self.generator = torch.Generator(self.device).manual_seed(derived_seed(seed, "minibatches"))
        """Shuffles minibatches; each random stream is seeded apart from the others."""
        self.action_rng = np.random.default_rng(derived_seed(seed, "actions"))
        """Samples the actions of collection."""
        self.rng = np.random.default_rng(derived_seed(seed, "episodes"))
        """Seeds fresh episodes where an agent restarts them (REINFORCE)."""
        self.collector = RolloutCollector(env, config.num_envs, config.simulator, seed)
        self.buffer = RolloutBuffer(rollout_steps, config.num_envs, env.obs_dim, self.device)
        self.env_steps = 0
        self.updates = 0

    # -- advantages -------------------------------------------------------------------------------

    @torch.no_grad()
    def rollout_batch(self, rows: int, gae_lambda: float, use_values: bool = True) -> Batch:
        """The first ``rows`` steps of the buffer as a batch of valid transitions with GAE advantages
        (``use_values`` False: values are 0, so advantages are discounted reward-to-go)."""
        buffer, device = self.buffer, self.device
        observations = buffer.observations[: rows + 1].to(device)
        actions = buffer.actions[:rows].to(device)
        logits, values = self.model(observations.flatten(0, 1))
        log_probs = torch.log_softmax(logits.view(rows + 1, -1, logits.shape[-1])[:-1], dim=-1)
        log_probs = log_probs.gather(2, actions.unsqueeze(2)).squeeze(2)
        values = (
            values.view(rows + 1, -1) if use_values else torch.zeros(observations.shape[:2], device=device)
        )
        rewards, terminated = buffer.rewards[:rows].to(device), buffer.terminated[:rows].to(device)
        truncated, valid = buffer.truncated[:rows].to(device), buffer.valid[:rows].to(device)
        gamma = self.config.gamma
        advantages = generalized_advantages(rewards, values, terminated, truncated, valid, gamma, gae_lambda)
        returns = advantages + values[:-1]
        keep = valid.flatten()
        return Batch(
            observations=observations[:-1].flatten(0, 1)[keep],
            actions=actions.flatten()[keep],
            log_probs=log_probs.flatten()[keep],
            values=values[:-1].flatten()[keep],
            advantages=advantages.flatten()[keep],
            returns=returns.flatten()[keep],
        )

    @property
    def learning_rate(self) -> float:
        return self.optimizer.lr

    def schedule_learning_rate(self) -> float:
        """Set the optimizer's learning rate from the schedule at the current env step; return it."""
        config = self.config
        self.optimizer.lr = schedule_value(
            config.lr, config.lr_schedule, self.env_steps, config.schedule_steps
        )
        return self.optimizer.lr

    def clip_and_step(self, loss: torch.Tensor) -> None:
        """Backpropagate ``loss``, clip the gradient norm if configured, and step the optimizer."""
        self.optimizer.zero_grad()
        loss.backward()
        if self.config.max_grad_norm is not None:
            torch.nn.utils.clip_grad_norm_(self.parameters, self.config.max_grad_norm)
        self.optimizer.step()

    # -- policy and checkpoints -------------------------------------------------------------------

    def policy(self) -> CategoricalPolicy:
        """A frozen copy of the current greedy policy."""
        return CategoricalPolicy(self.model)

    def state_dict(self, resume: bool) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
        tensors = {f"model.{k}": v for k, v in self.model.state_dict().items()}
        data: dict[str, Any] = {"obs_dim": self.env_info.obs_dim, "n_actions": self.env_info.n_actions}
        if not resume:
            return tensors, data
        optim_tensors, optim_data = self.optimizer.state_dict()
        tensors |= {f"optim.{k}": v for k, v in optim_tensors.items()}
        tensors["rng.torch"] = self.generator.get_state()
        data["rng_actions"] = self.action_rng.bit_generator.state
        collector_tensors, collector_data = self.collector.state_dict()
        tensors |= {f"collector.{k}": v for k, v in collector_tensors.items()}
        data |= {
            "optim": optim_data,
            "collector": collector_data,
            "rng_numpy": self.rng.bit_generator.state,
            "env_steps": self.env_steps,
            "updates": self.updates,
        }
        return tensors, data

    def load_state_dict(self, tensors: dict[str, torch.Tensor], data: dict[str, Any]) -> None:
        self.model.load_state_dict(with_prefix(tensors, "model."))
        if "env_steps" not in data:  # a policy-only checkpoint: weights only
            return
        self.optimizer.load_state_dict(with_prefix(tensors, "optim."))
        self.generator.set_state(tensors["rng.torch"])
        self.rng.bit_generator.state = data["rng_numpy"]
        self.action_rng.bit_generator.state = data["rng_actions"]
        self.env_steps, self.updates = int(data["env_steps"]), int(data["updates"])
        self.collector.load_state_dict(with_prefix(tensors, "collector."), data["collector"], self.env_steps)


def adam(parameters: list[torch.Tensor], lr: float, eps: float = 1e-8) -> FusedAdam:
    """Adam with torch's fused kernel (one kernel per step: several times faster than the per-tensor
    loop for nets this small on CPU), without constructing a ``torch.optim`` optimizer (see
    agents/optimizers.py)."""
    return FusedAdam(parameters, lr=lr, eps=eps)


def with_prefix(tensors: dict[str, torch.Tensor], prefix: str) -> dict[str, torch.Tensor]:
    return {k.removeprefix(prefix): v for k, v in tensors.items() if k.startswith(prefix)}


def policy_loader(agent: str, config_cls: type) -> Callable[[Checkpoint], CategoricalPolicy]:
    """``policy_from_checkpoint`` for an agent whose checkpoints hold an ActorCritic as ``model.*``."""

    def policy_from_checkpoint(checkpoint: Checkpoint) -> CategoricalPolicy:
        try:
            config = build_config(config_cls, checkpoint.meta["config"])
            data = checkpoint.meta["learner"]
            model = ActorCritic(
                int(data["obs_dim"]),
                int(data["n_actions"]),
                config.hidden_sizes,
                config.activation,
                config.shared_trunk,
                orthogonal_init=False,
                generator=torch.Generator(),
            )
            model.load_state_dict(with_prefix(checkpoint.tensors, "model."))
        except (KeyError, RuntimeError, TypeError, ValueError) as err:
            raise CheckpointError(f"not a usable {agent} checkpoint: {err!s:.120}") from err
        return CategoricalPolicy(model)

    return policy_from_checkpoint
