"""Proximal Policy Optimization (PPO, clipped surrogate) in PyTorch, readable top to bottom.

What it does, in order:

1. ``PPOConfig``: every knob, with a one-line docstring each (presets in ``presets/ppo.toml``).
2. The learner, batched over seeds (a single run is a population of one):
   :class:`~cartpole.agents.actor_critic.population.PopulationPPO`. One ``learn()`` call = one
   rollout of ``n_steps`` batched steps from ``num_envs`` envs per seed, GAE advantages
   (bootstrapping at truncation, never at termination), then ``n_epochs`` passes of shuffled
   minibatches with gradient-norm clipping and an optional early stop on a target KL.

The greedy policy (``act`` = argmax of the action probabilities) is
:class:`~cartpole.agents.actor_critic.network.CategoricalPolicy`.
"""

from __future__ import annotations

from dataclasses import dataclass

from cartpole.agents.actor_critic.network import SCHEDULES
from cartpole.agents.actor_critic.policy_gradient import PolicyGradientConfig
from cartpole.core.config import require

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


__all__ = ["PPOConfig"]
