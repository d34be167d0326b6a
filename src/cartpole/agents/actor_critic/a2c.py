"""Advantage Actor-Critic (A2C, synchronous) in PyTorch, readable top to bottom.

What it does, in order:

1. ``A2CConfig``: every knob, with a one-line docstring each (presets in ``presets/a2c.toml``).
2. The learner, batched over seeds (a single run is a population of one):
   :class:`~cartpole.agents.actor_critic.population.PopulationA2C`. One ``learn()`` call = one
   rollout of ``n_steps`` batched steps from ``num_envs`` envs per seed, GAE(lambda) advantages
   (bootstrapping at truncation, never at termination; lambda 1 with few steps is A2C's n-step
   return), then *one* gradient step on ``-mean(A log pi) + vf_coef * value loss - ent_coef *
   entropy`` with RMSprop (as the A2C paper and Stable-Baselines3) or Adam.
"""

from __future__ import annotations

from dataclasses import dataclass

from cartpole.agents.actor_critic.policy_gradient import PolicyGradientConfig
from cartpole.core.config import require

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


__all__ = ["OPTIMIZERS", "A2CConfig"]
