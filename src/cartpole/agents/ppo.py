"""Proximal Policy Optimization (PPO, clipped surrogate) in PyTorch, readable top to bottom.

What it does, in order:

1. ``PPOConfig``: every knob, with a one-line docstring each (presets in ``presets/ppo.toml``).
2. ``clipped_surrogate_loss`` and ``value_loss``: the two losses, each in one place.
3. ``PPOLearner``: one ``learn()`` call = one rollout of ``n_steps`` batched steps from ``num_envs``
   envs (one forward pass for all envs per step, see :mod:`cartpole.agents.rollout`), GAE advantages
   (bootstrapping at truncation, never at termination), then ``n_epochs`` passes of shuffled
   minibatches with gradient-norm clipping and an optional early stop on a target KL. The shared
   training loop does the rest (evaluation, best checkpoint, stop when solved, budget).

The greedy policy (``act`` = argmax of the action probabilities) is
:class:`~cartpole.agents.actor_critic.CategoricalPolicy`.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from cartpole.agents.actor_critic import SCHEDULES, schedule_value
from cartpole.agents.learner import LearnResult
from cartpole.agents.nn.optimizers import Optimizer
from cartpole.agents.policy_gradient import (
    Batch,
    PolicyGradientConfig,
    PolicyGradientLearner,
    adam,
    policy_loss_terms,
)
from cartpole.agents.rollout import explained_variance, normalize
from cartpole.core.config import require
from cartpole.envs import EnvInfo

# ----------------------------------------------------------------------------------------------
# 1. Configuration
# ----------------------------------------------------------------------------------------------


@dataclass
class PPOConfig(PolicyGradientConfig):
    """Hyperparameters of PPO. `cartpole train ppo` uses the ``default`` preset (presets/ppo.toml), not
    these field defaults."""

    n_steps: int = 32
    """Batched steps per rollout (a rollout holds n_steps x num_envs rows)."""
    gae_lambda: float = 0.8
    """GAE lambda: 0 = one-step TD advantages, 1 = Monte-Carlo returns minus the value."""
    n_epochs: int = 10
    """Passes over each rollout."""
    minibatch_size: int = 64
    """Rows per gradient step (the last minibatch of a pass may be smaller)."""
    clip_range: float = 0.2
    """Clip the probability ratio to [1 - clip_range, 1 + clip_range] (start value if scheduled)."""
    clip_schedule: str = "constant"
    """constant, or linear: the clip range decays to 0 at schedule_steps env steps."""
    clip_range_vf: float | None = None
    """Clip the value prediction to old value +- this (none: no value clipping)."""
    target_kl: float | None = None
    """Stop the update's remaining epochs once a minibatch's approximate KL exceeds this (none: never)."""
    normalize_advantages: bool = True
    """Standardize the advantages within each minibatch."""
    adam_eps: float = 1e-5
    """Adam's epsilon."""

    def validate(self) -> None:
        super().validate()
        require(self.n_steps >= 1, f"n_steps must be >= 1, got {self.n_steps}")
        require(0.0 <= self.gae_lambda <= 1.0, f"gae_lambda must be in [0, 1], got {self.gae_lambda}")
        require(self.n_epochs >= 1, f"n_epochs must be >= 1, got {self.n_epochs}")
        require(self.minibatch_size >= 1, f"minibatch_size must be >= 1, got {self.minibatch_size}")
        require(self.clip_range > 0, f"clip_range must be > 0, got {self.clip_range}")
        require(self.clip_schedule in SCHEDULES, f"clip_schedule must be one of {', '.join(SCHEDULES)}")
        require(self.clip_range_vf is None or self.clip_range_vf > 0, "clip_range_vf must be > 0 or none")
        require(self.target_kl is None or self.target_kl > 0, "target_kl must be > 0 or none")
        require(self.adam_eps > 0, f"adam_eps must be > 0, got {self.adam_eps}")


# ----------------------------------------------------------------------------------------------
# 2. The losses
# ----------------------------------------------------------------------------------------------


def clipped_surrogate_loss(
    log_probs: torch.Tensor, old_log_probs: torch.Tensor, advantages: torch.Tensor, clip_range: float
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """PPO's policy loss ``mean(max(-A r, -A clip(r, 1 - eps, 1 + eps)))`` with ``r = pi / pi_old``.

    Also returns the approximate KL(old || new), ``mean((r - 1) - log r)`` (non-negative, low
    variance), and the fraction of rows whose ratio was clipped (both detached).
    """
    log_ratio = log_probs - old_log_probs
    ratio = log_ratio.exp()
    unclipped = -advantages * ratio
    clipped = -advantages * ratio.clamp(1.0 - clip_range, 1.0 + clip_range)
    loss = torch.max(unclipped, clipped).mean()
    with torch.no_grad():
        approx_kl = ((ratio - 1.0) - log_ratio).mean()
        clip_fraction = ((ratio - 1.0).abs() > clip_range).float().mean()
    return loss, approx_kl, clip_fraction


def value_loss(
    values: torch.Tensor, old_values: torch.Tensor, returns: torch.Tensor, clip_range_vf: float | None
) -> torch.Tensor:
    """``0.5 * mean((V - R)^2)``; with ``clip_range_vf`` the pessimistic max of that and the loss of
    the value clipped to ``old_value +- clip_range_vf`` (as CleanRL and SB3 clip it)."""
    squared = (values - returns).square()
    if clip_range_vf is not None:
        clipped = old_values + (values - old_values).clamp(-clip_range_vf, clip_range_vf)
        squared = torch.max(squared, (clipped - returns).square())
    return 0.5 * squared.mean()


# ----------------------------------------------------------------------------------------------
# 3. The learner
# ----------------------------------------------------------------------------------------------


class PPOLearner(PolicyGradientLearner):
    """PPO as a Learner of the shared loop: one ``learn()`` = one rollout and its update."""

    config: PPOConfig

    def __init__(self, config: PPOConfig, env: EnvInfo, seed: int, device: str = "cpu"):
        config.validate()

        def make_optimizer(parameters: list[torch.Tensor]) -> Optimizer:
            return adam(parameters, lr=config.lr, eps=config.adam_eps)

        super().__init__(config, env, seed, device, config.n_steps, make_optimizer)

    def learn(self) -> LearnResult:
        config = self.config
        learning_rate = self.schedule_learning_rate()
        clip_range = schedule_value(
            config.clip_range, config.clip_schedule, self.env_steps, config.schedule_steps
        )
        rows, returns, lengths = self.collector.collect(self.buffer, self.model, self.action_rng)
        batch = self.rollout_batch(rows, config.gae_lambda)
        collected = len(batch)
        self.env_steps += collected
        result = LearnResult(env_steps=collected, episode_returns=returns, episode_lengths=lengths)
        if collected == 0:
            return result
        result.scalars = self.update(batch, max(clip_range, 1e-8))
        result.scalars |= {"train/learning_rate": learning_rate, "train/clip_range": clip_range}
        result.log_scalars = True
        return result

    def minibatches(self, batch: Batch) -> list[Batch]:
        """One pass over ``batch`` in shuffled minibatches (the whole batch when it fits in one)."""
        size = self.config.minibatch_size
        if size >= len(batch):  # one full-batch step: the order of rows does not matter
            return [batch]
        order = torch.randperm(len(batch), generator=self.generator, device=self.device)
        return [batch[order[start : start + size]] for start in range(0, len(batch), size)]

    def update(self, batch: Batch, clip_range: float) -> dict[str, float]:
        """``n_epochs`` passes of shuffled minibatches over ``batch``; the update's mean metrics."""
        config = self.config
        metrics: list[torch.Tensor] = []
        stopped_early = False
        for _ in range(config.n_epochs):
            for minibatch in self.minibatches(batch):
                log_probs, entropy, values = policy_loss_terms(
                    self.model, minibatch.observations, minibatch.actions, entropy_grad=config.ent_coef > 0
                )
                advantages = minibatch.advantages
                if config.normalize_advantages:
                    advantages = normalize(advantages)
                policy_loss, approx_kl, clip_fraction = clipped_surrogate_loss(
                    log_probs, minibatch.log_probs, advantages, clip_range
                )
                if config.target_kl is not None and float(approx_kl) > config.target_kl:
                    stopped_early = True
                    break
                v_loss = value_loss(values, minibatch.values, minibatch.returns, config.clip_range_vf)
                loss = policy_loss + config.vf_coef * v_loss
                if config.ent_coef > 0:
                    loss = loss - config.ent_coef * entropy
                self.clip_and_step(loss)
                metrics.append(
                    torch.stack(
                        [policy_loss.detach(), v_loss.detach(), entropy.detach(), approx_kl, clip_fraction]
                    )
                )
            if stopped_early:
                break
        self.updates += 1
        names = ("policy_loss", "value_loss", "entropy", "approx_kl", "clip_fraction")
        scalars = {"train/updates": float(self.updates), "train/stopped_early": float(stopped_early)}
        if metrics:  # one sync for all of them
            means = torch.stack(metrics).mean(dim=0).tolist()
            scalars |= {f"train/{name}": value for name, value in zip(names, means, strict=True)}
        scalars["train/explained_variance"] = explained_variance(batch.values, batch.returns)
        return scalars


__all__ = ["PPOConfig", "PPOLearner", "clipped_surrogate_loss", "value_loss"]
