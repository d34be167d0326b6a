"""Advantage Actor-Critic (A2C, synchronous) for a batch of seeds, read top to bottom.

1. :class:`A2CConfig`: every setting, with a one-line docstring each (presets in ``presets/a2c.toml``).
2. One ``learn()`` (:meth:`PopulationA2C.learn`): a rollout of ``n_steps`` batched steps from
   ``num_envs`` envs per seed, GAE(lambda) advantages (bootstrapping at truncation, never at
   termination; lambda 1 with few steps is A2C's n-step return:
   :mod:`cartpole.agents.actor_critic.rollout`), then *one* gradient step per seed on
   ``-mean(A log pi) + vf_coef * value loss - ent_coef * entropy`` over its own rows of the
   ``[S, B]`` batch, with RMSprop (as the A2C paper and Stable-Baselines3) or Adam.
3. The agent's spec, as the registry finds it.

A single run is a population of one. What every actor-critic shares (the stacked networks, the envs,
the optimizer, checkpoints) is :class:`~cartpole.agents.actor_critic.population.PopulationActorCritic`.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from cartpole.agents.actor_critic.policy_gradient import PolicyGradientConfig
from cartpole.agents.actor_critic.population import (
    PopulationActorCritic,
    actor_critic_bytes_per_seed,
    actor_critic_spec,
)
from cartpole.agents.learner import LearnResult
from cartpole.agents.nn.masked import log_probs_and_entropy, masked_mean, masked_normalize
from cartpole.core.config import require
from cartpole.envs import EnvInfo

# ----------------------------------------------------------------------------------------------
# 1. Configuration
# ----------------------------------------------------------------------------------------------

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


# ----------------------------------------------------------------------------------------------
# 2. One learn(): a rollout, the loss and one step
# ----------------------------------------------------------------------------------------------


class PopulationA2C(PopulationActorCritic):
    """A2C for seeds ``seeds``, all with ``config``: one ``learn()`` = a rollout and one gradient step
    on all of it for each seed."""

    config: A2CConfig

    def __init__(self, config: A2CConfig, env: EnvInfo, seeds: list[int], device: str = "cpu"):
        super().__init__(config, env, seeds, device, config.optimizer, config.optimizer_eps, config.rms_alpha)

    def learn(self) -> dict[int, LearnResult]:
        """A rollout and one gradient step on all of it, for every active seed; each seed's result by
        seed."""
        config = self.config
        lr = self.learning_rates()
        # no log-probabilities: the loss's own forward pass gives them
        rollout, finished = self.collect(config.n_steps, config.gae_lambda, log_probs=False)
        results = self.count_steps(rollout.counts.to(torch.int64).tolist(), finished)
        valid, count = rollout.valid.float(), rollout.counts
        logits, values = self.model.forward_for_update(rollout.observations)
        log_probs, entropy = log_probs_and_entropy(logits, rollout.actions, valid, count, config.ent_coef)
        advantages = rollout.advantages
        if config.normalize_advantages:
            advantages = masked_normalize(advantages, valid, count)
        policy_loss = masked_mean(-(advantages * log_probs), valid, count)
        value_loss = 0.5 * masked_mean((values - rollout.returns).square(), valid, count)
        loss = policy_loss - config.ent_coef * entropy + config.vf_coef * value_loss
        active = count > 0
        self.backward_and_step(loss, torch.tensor(lr, device=self.device), active)
        self.model.forget_scaled()
        self.updates += active.cpu().numpy()
        with torch.no_grad():  # how far the step moved each policy on its own batch
            new_log_probs = torch.log_softmax(self.model.logits(rollout.observations), dim=-1)
            log_ratio = (
                new_log_probs.gather(-1, rollout.actions.unsqueeze(-1)).squeeze(-1) - log_probs.detach()
            )
            approx_kl = masked_mean((log_ratio.exp() - 1.0) - log_ratio, valid, count)
            rows = torch.stack([policy_loss, value_loss, entropy, approx_kl], dim=1).tolist()
        explained = self.explained_variances(rollout).tolist()
        names = ("policy_loss", "value_loss", "entropy", "approx_kl")
        metrics = [
            {f"train/{name}": v for name, v in zip(names, row, strict=True)}
            | {
                "train/explained_variance": explained[i],
                "train/learning_rate": lr[i],
                "train/updates": float(self.updates[i]),
            }
            for i, row in enumerate(rows)
        ]
        self.attach_metrics(results, rollout.counts, metrics)
        return results


# ----------------------------------------------------------------------------------------------
# 3. The spec
# ----------------------------------------------------------------------------------------------


def a2c_bytes_per_seed(config: A2CConfig, env: EnvInfo) -> int:
    return actor_critic_bytes_per_seed(config, env, config.n_steps, config.n_steps * config.num_envs)


AGENT = actor_critic_spec(
    "a2c",
    "Advantage Actor-Critic (PyTorch): n-step rollouts from vector envs, GAE, RMSprop or Adam",
    A2CConfig,
    a2c_bytes_per_seed,
    PopulationA2C,
)


__all__ = ["AGENT", "OPTIMIZERS", "A2CConfig", "PopulationA2C", "a2c_bytes_per_seed"]
