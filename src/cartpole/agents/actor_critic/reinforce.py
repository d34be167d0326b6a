"""REINFORCE (Monte-Carlo policy gradient) in PyTorch, readable top to bottom.

What it does, in order:

1. ``ReinforceConfig``: every knob, with a one-line docstring each (presets in ``presets/reinforce.toml``).
2. The learner, batched over seeds (a single run is a population of one):
   :class:`~cartpole.agents.actor_critic.population.PopulationReinforce`. One ``learn()`` call =
   one whole episode in each of ``num_envs`` envs per seed, all started fresh and stepped together
   (one forward pass per step), then one gradient step on ``-mean(G_t log pi(a_t | s_t))``, where
   ``G_t`` is the discounted reward-to-go. Options: a learned baseline (``G_t - V(s_t)``; an episode
   cut by the time limit then bootstraps from the value of its final state, one that terminated
   never does) and standardizing the weights over the batch.
"""

from __future__ import annotations

from dataclasses import dataclass

from cartpole.agents.actor_critic.policy_gradient import PolicyGradientConfig


@dataclass
class ReinforceConfig(PolicyGradientConfig):
    """Hyperparameters of REINFORCE. `cartpole train reinforce` uses the ``default`` preset
    (presets/reinforce.toml), not these field defaults."""

    baseline: bool = True
    """Subtract a learned state value from the return (the critic is trained with vf_coef)."""
    normalize_returns: bool = True
    """Standardize the policy-gradient weights (returns, or returns minus baseline) over each batch."""


__all__ = ["ReinforceConfig"]
