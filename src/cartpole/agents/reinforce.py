"""REINFORCE (Monte-Carlo policy gradient) in PyTorch, readable top to bottom.

What it does, in order:

1. ``ReinforceConfig``: every knob, with a one-line docstring each (presets in ``presets/reinforce.toml``).
2. ``ReinforceLearner``: one ``learn()`` call = one whole episode in each of ``num_envs`` envs, all
   started fresh and stepped together (one forward pass per step), then one gradient step on
   ``-mean(G_t log pi(a_t | s_t))``, where ``G_t`` is the discounted reward-to-go. Options: a learned
   baseline (``G_t - V(s_t)``; an episode cut by the time limit then bootstraps from the value of its
   final state, one that terminated never does) and standardizing the weights over the batch.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from cartpole.agents.learner import LearnResult
from cartpole.agents.policy_gradient import (
    PolicyGradientConfig,
    PolicyGradientLearner,
    adam,
    policy_loss_terms,
)
from cartpole.agents.rollout import explained_variance, normalize
from cartpole.envs import EnvInfo
from cartpole.envs.seed_envs import LONGEST_EPISODE_WITHOUT_TIME_LIMIT

"""Rows per env of the episode buffer for an env that registers no time limit (longer episodes are cut)."""


@dataclass
class ReinforceConfig(PolicyGradientConfig):
    """Hyperparameters of REINFORCE. Defaults are the ``default`` preset's values for CartPole-v1."""

    baseline: bool = True
    """Subtract a learned state value from the return (the critic is trained with vf_coef)."""
    normalize_returns: bool = True
    """Standardize the policy-gradient weights (returns, or returns minus baseline) over each batch."""


class ReinforceLearner(PolicyGradientLearner):
    """REINFORCE as a Learner of the shared loop: one ``learn()`` = num_envs episodes + one step."""

    config: ReinforceConfig

    def __init__(self, config: ReinforceConfig, env: EnvInfo, seed: int, device: str = "cpu"):
        config.validate()
        rows = env.max_episode_steps or LONGEST_EPISODE_WITHOUT_TIME_LIMIT
        super().__init__(config, env, seed, device, rows, lambda p: adam(p, lr=config.lr))

    def learn(self) -> LearnResult:
        config = self.config
        learning_rate = self.schedule_learning_rate()
        # Every batch starts fresh episodes (seeded from the learner's own generator), so the
        # returns are those of whole episodes.
        self.collector.restart(int(self.rng.integers(2**32)))
        rows, returns, lengths = self.collector.collect(
            self.buffer, self.model, self.action_rng, stop_when_all_ended=True
        )
        # gae_lambda = 1 with values 0 is the plain discounted reward-to-go; with the baseline's
        # values it is the reward-to-go minus V(s_t) (plus the bootstrap at truncation).
        batch = self.rollout_batch(rows, gae_lambda=1.0, use_values=config.baseline)
        collected = len(batch)
        self.env_steps += collected
        result = LearnResult(env_steps=collected, episode_returns=returns, episode_lengths=lengths)
        if collected == 0:
            return result

        log_probs, entropy, values = policy_loss_terms(
            self.model, batch.observations, batch.actions, entropy_grad=config.ent_coef > 0
        )
        weights = normalize(batch.advantages) if config.normalize_returns else batch.advantages
        policy_loss = -(weights * log_probs).mean()
        loss = policy_loss - config.ent_coef * entropy
        value_loss = 0.5 * (values - batch.returns).square().mean()
        if config.baseline:
            loss = loss + config.vf_coef * value_loss
        self.clip_and_step(loss)
        self.updates += 1

        losses = torch.stack([policy_loss.detach(), value_loss.detach(), entropy.detach()]).tolist()
        result.scalars = {
            "train/policy_loss": losses[0],
            "train/entropy": losses[2],
            "train/learning_rate": learning_rate,
            "train/updates": float(self.updates),
        }
        if config.baseline:
            result.scalars |= {
                "train/value_loss": losses[1],
                "train/explained_variance": explained_variance(batch.values, batch.returns),
            }
        result.log_scalars = True
        return result


__all__ = ["ReinforceConfig", "ReinforceLearner"]
