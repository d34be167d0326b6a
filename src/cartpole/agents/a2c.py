"""Advantage Actor-Critic (A2C, synchronous) in PyTorch, readable top to bottom.

What it does, in order:

1. ``A2CConfig``: every knob, with a one-line docstring each (presets in ``presets/a2c.toml``).
2. ``A2CLearner``: one ``learn()`` call = one rollout of ``n_steps`` batched steps from ``num_envs``
   envs (one forward pass for all envs per step), GAE(lambda) advantages (bootstrapping at
   truncation, never at termination; lambda 1 with few steps is A2C's n-step return), then *one*
   gradient step on ``-mean(A log pi) + vf_coef * value loss - ent_coef * entropy`` with RMSprop (as
   the A2C paper and Stable-Baselines3) or Adam.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from cartpole.agents.learner import LearnResult
from cartpole.agents.nn.optimizers import Optimizer, RMSprop
from cartpole.agents.policy_gradient import (
    PolicyGradientConfig,
    PolicyGradientLearner,
    adam,
    policy_loss_terms,
)
from cartpole.agents.rollout import explained_variance, normalize
from cartpole.core.config import require
from cartpole.envs import EnvInfo

OPTIMIZERS = ("rmsprop", "adam")


@dataclass
class A2CConfig(PolicyGradientConfig):
    """Hyperparameters of A2C. Defaults are the ``default`` preset's values for CartPole-v1."""

    n_steps: int = 8
    """Batched steps per rollout; one gradient step per rollout."""
    gae_lambda: float = 1.0
    """GAE lambda (1: the n-step return minus the value, as in the A2C paper)."""
    normalize_advantages: bool = False
    """Standardize the advantages of each rollout."""
    optimizer: str = "rmsprop"
    """rmsprop (torch.optim.RMSprop's update) or adam."""
    rms_alpha: float = 0.99
    """RMSprop's smoothing constant."""
    optimizer_eps: float = 1e-5
    """Epsilon of RMSprop or Adam."""

    def validate(self) -> None:
        super().validate()
        require(self.n_steps >= 1, f"n_steps must be >= 1, got {self.n_steps}")
        require(0.0 <= self.gae_lambda <= 1.0, f"gae_lambda must be in [0, 1], got {self.gae_lambda}")
        require(self.optimizer in OPTIMIZERS, f"optimizer must be one of {', '.join(OPTIMIZERS)}")
        require(0.0 <= self.rms_alpha < 1.0, f"rms_alpha must be in [0, 1), got {self.rms_alpha}")
        require(self.optimizer_eps > 0, f"optimizer_eps must be > 0, got {self.optimizer_eps}")


class A2CLearner(PolicyGradientLearner):
    """A2C as a Learner of the shared loop: one ``learn()`` = one rollout and one gradient step."""

    config: A2CConfig

    def __init__(self, config: A2CConfig, env: EnvInfo, seed: int, device: str = "cpu"):
        config.validate()

        def make_optimizer(parameters: list[torch.Tensor]) -> Optimizer:
            if config.optimizer == "adam":
                return adam(parameters, lr=config.lr, eps=config.optimizer_eps)
            return RMSprop(parameters, lr=config.lr, alpha=config.rms_alpha, eps=config.optimizer_eps)

        super().__init__(config, env, seed, device, config.n_steps, make_optimizer)

    def learn(self) -> LearnResult:
        config = self.config
        learning_rate = self.schedule_learning_rate()
        rows, returns, lengths = self.collector.collect(self.buffer, self.model, self.action_rng)
        batch = self.rollout_batch(rows, config.gae_lambda)
        collected = len(batch)
        self.env_steps += collected
        result = LearnResult(env_steps=collected, episode_returns=returns, episode_lengths=lengths)
        if collected == 0:
            return result

        log_probs, entropy, values = policy_loss_terms(
            self.model, batch.observations, batch.actions, entropy_grad=config.ent_coef > 0
        )
        advantages = normalize(batch.advantages) if config.normalize_advantages else batch.advantages
        policy_loss = -(advantages * log_probs).mean()
        value_loss = 0.5 * (values - batch.returns).square().mean()
        self.clip_and_step(policy_loss - config.ent_coef * entropy + config.vf_coef * value_loss)
        self.updates += 1

        with torch.no_grad():  # how far this step moved the policy on its own batch
            new_log_probs = torch.log_softmax(self.model.logits(batch.observations), dim=-1)
            log_ratio = new_log_probs.gather(1, batch.actions.unsqueeze(1)).squeeze(1) - batch.log_probs
            approx_kl = ((log_ratio.exp() - 1.0) - log_ratio).mean()
        losses = torch.stack([policy_loss.detach(), value_loss.detach(), entropy.detach(), approx_kl])
        policy_loss_value, value_loss_value, entropy_value, approx_kl_value = losses.tolist()
        result.scalars = {
            "train/policy_loss": policy_loss_value,
            "train/value_loss": value_loss_value,
            "train/entropy": entropy_value,
            "train/approx_kl": approx_kl_value,
            "train/explained_variance": explained_variance(batch.values, batch.returns),
            "train/learning_rate": learning_rate,
            "train/updates": float(self.updates),
        }
        result.log_scalars = True
        return result


__all__ = ["A2CConfig", "A2CLearner"]
