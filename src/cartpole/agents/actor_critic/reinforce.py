"""REINFORCE (Monte-Carlo policy gradient) for a batch of seeds, read top to bottom.

1. :class:`ReinforceConfig`: every setting, with a one-line docstring each (presets in
   ``presets/reinforce.toml``).
2. One ``learn()`` (:meth:`PopulationReinforce.learn`): one whole episode in each of ``num_envs``
   envs per seed, all started fresh and stepped together (one forward pass per step), then one
   gradient step per seed on ``-mean(G_t log pi(a_t | s_t))``, where ``G_t`` is the discounted
   reward-to-go. Options: a learned baseline (``G_t - V(s_t)``; an episode cut by the time limit then
   bootstraps from the value of its final state, one that terminated never does) and standardizing
   the weights over the batch.
3. Per-length groups (:meth:`PopulationReinforce.update_lengths`): episodes have different lengths,
   and play lasts until the longest episode of *any* seed ends. So that a seed's arithmetic does not
   depend on its neighbours, its loss (:meth:`PopulationReinforce.backward_group`) runs on its own
   rows cut to a length that depends only on them (its longest episode, rounded up:
   :func:`rounded_up`); seeds of the same length take one batched forward and backward pass.
4. The agent's spec, as the registry finds it.

A single run is a population of one. What every actor-critic shares (the stacked networks, the envs,
the optimizer, checkpoints) is :class:`~cartpole.agents.actor_critic.population.PopulationActorCritic`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from cartpole.agents.actor_critic.policy_gradient import PolicyGradientConfig
from cartpole.agents.actor_critic.population import (
    PopulationActorCritic,
    actor_critic_bytes_per_seed,
    actor_critic_spec,
)
from cartpole.agents.actor_critic.rollout import Transitions, advantages, play
from cartpole.agents.learner import LearnResult
from cartpole.agents.nn.masked import log_probs_and_entropy, masked_mean, masked_normalize
from cartpole.agents.seed_state import SeedState
from cartpole.core.seeding import derived_seed
from cartpole.envs import EnvInfo
from cartpole.envs.seed_envs import LONGEST_EPISODE_WITHOUT_TIME_LIMIT

# ----------------------------------------------------------------------------------------------
# 1. Configuration
# ----------------------------------------------------------------------------------------------


@dataclass
class ReinforceConfig(PolicyGradientConfig):
    """Hyperparameters of REINFORCE. `cartpole train reinforce` uses the ``default`` preset
    (presets/reinforce.toml), not these field defaults."""

    baseline: bool = True
    """Subtract a learned state value from the return (the critic is trained with vf_coef)."""
    normalize_returns: bool = True
    """Standardize the policy-gradient weights (returns, or returns minus baseline) over each batch."""


# ----------------------------------------------------------------------------------------------
# 2. and 3. One learn(), by groups of seeds of one update length
# ----------------------------------------------------------------------------------------------


def rounded_up(n: int) -> int:
    """``n`` (>= 1) rounded up to a multiple of a quarter of the power of two at or below it: at most
    a quarter more, and four lengths per doubling."""
    quarter = max(1, (1 << (n.bit_length() - 1)) // 4)
    return -(-n // quarter) * quarter


class PopulationReinforce(PopulationActorCritic):
    """REINFORCE for seeds ``seeds``, all with ``config``: one ``learn()`` = one whole episode in each
    of every seed's envs, all started fresh, then one gradient step each, the seeds grouped by
    update length (see the module docstring)."""

    config: ReinforceConfig

    def __init__(self, config: ReinforceConfig, env: EnvInfo, seeds: list[int], device: str = "cpu"):
        super().__init__(config, env, seeds, device)
        self.episode_rngs = [np.random.default_rng(derived_seed(s, "episodes")) for s in self.seeds]
        """Each seed's generator of the seeds of its batches' fresh episodes."""
        self.longest = env.max_episode_steps or LONGEST_EPISODE_WITHOUT_TIME_LIMIT

    def backward_group(
        self, transitions: Transitions, rows: list[int], length: int, metrics: list[dict[str, float]]
    ) -> None:
        """The loss of the seeds at ``rows`` (all with update length ``length``), backpropagated into
        their rows of the gradients; their metrics into ``metrics``."""
        config, envs = self.config, self.config.num_envs
        index = torch.tensor(rows, dtype=torch.int64, device=self.device)
        columns = (index.unsqueeze(1) * envs + torch.arange(envs, device=self.device)).reshape(-1)
        detached = {name: p.detach()[index] for name, p in self.model.params.items()}
        critics = detached if config.baseline else None  # without a baseline: the reward-to-go
        rollout = advantages(
            transitions.columns(columns, length), self.model, critics, envs, config.gamma, 1.0
        )
        valid, count = rollout.valid.float(), rollout.counts
        logits, values = self.model.forward_for_update(rollout.observations, index)
        log_probs, entropy = log_probs_and_entropy(logits, rollout.actions, valid, count, config.ent_coef)
        weights = (
            masked_normalize(rollout.advantages, valid, count)
            if config.normalize_returns
            else rollout.advantages
        )
        policy_loss = masked_mean(-(weights * log_probs), valid, count)
        value_loss = 0.5 * masked_mean((values - rollout.returns).square(), valid, count)
        loss = policy_loss - config.ent_coef * entropy
        if config.baseline:
            loss = loss + config.vf_coef * value_loss
        self.model.backward(loss.sum())
        self.model.forget_scaled()
        explained = self.explained_variances(rollout).tolist()
        values_of = torch.stack([policy_loss, value_loss, entropy], dim=1).tolist()
        for i, row in enumerate(rows):
            policy, value, entropy_value = values_of[i]
            metrics[row] = {"train/policy_loss": policy, "train/entropy": entropy_value}
            if config.baseline:
                metrics[row] |= {"train/value_loss": value, "train/explained_variance": explained[i]}

    def update_lengths(self, transitions: Transitions) -> list[int]:
        """Each seed's update length, covering its longest episode (:func:`rounded_up`, at least 8):
        padding costs at most a quarter more rows, and seeds of similar lengths share a pass."""
        steps, envs = transitions.valid.shape[0], self.config.num_envs
        played = transitions.valid.view(steps, len(self.seeds), envs).any(dim=2)  # [T, S]
        longest = [
            int(played[:, row].nonzero().max()) + 1 if bool(played[:, row].any()) else 1
            for row in range(len(self.seeds))
        ]
        return [min(self.longest, max(8, rounded_up(n))) for n in longest]

    def learn(self) -> dict[int, LearnResult]:
        lr = self.learning_rates()
        self.restart()
        transitions, finished = play(
            self.model, self.episodes, self.generators, self.longest, whole_episodes=True, log_probs=False
        )
        counts = transitions.valid.view(transitions.valid.shape[0], len(self.seeds), -1).sum(dim=(0, 2))
        results = self.count_steps(counts.tolist(), finished)
        lengths = self.update_lengths(transitions)
        self.model.grad.zero_()
        metrics: list[dict[str, float]] = [{} for _ in self.seeds]
        for length in sorted(set(lengths)):
            rows = [row for row, n in enumerate(lengths) if n == length]
            self.backward_group(transitions, rows, length, metrics)
        active = counts > 0
        self.step(torch.tensor(lr, device=self.device), active)
        self.updates += active.cpu().numpy()
        for row, scalars in enumerate(metrics):
            scalars |= {"train/learning_rate": lr[row], "train/updates": float(self.updates[row])}
        self.attach_metrics(results, counts, metrics)
        return results

    def restart(self) -> None:
        """Fresh episodes in every env, from each seed's own episode generator."""
        self.episodes.restart([int(rng.integers(2**32)) for rng in self.episode_rngs])

    def remove(self, seeds: list[int]) -> None:
        gone = set(seeds)
        rngs = zip(self.seeds, self.episode_rngs, strict=True)
        self.episode_rngs = [rng for seed, rng in rngs if seed not in gone]
        super().remove(seeds)

    def seed_state_dict(self, seed: int, resume: bool) -> SeedState:
        tensors, data = super().seed_state_dict(seed, resume)
        if resume:
            data["rng_numpy"] = self.episode_rngs[self.seeds.index(seed)].bit_generator.state
        return tensors, data

    def load_seed_state_dict(self, seed: int, tensors: dict[str, torch.Tensor], data: dict[str, Any]) -> None:
        super().load_seed_state_dict(seed, tensors, data)
        self.episode_rngs[self.seeds.index(seed)].bit_generator.state = data["rng_numpy"]


# ----------------------------------------------------------------------------------------------
# 4. The spec
# ----------------------------------------------------------------------------------------------


def reinforce_bytes_per_seed(config: ReinforceConfig, env: EnvInfo) -> int:
    longest = env.max_episode_steps or LONGEST_EPISODE_WITHOUT_TIME_LIMIT
    return actor_critic_bytes_per_seed(config, env, longest, longest * config.num_envs)


AGENT = actor_critic_spec(
    "reinforce",
    "REINFORCE (PyTorch): Monte-Carlo policy gradient on whole episodes, optional learned baseline",
    ReinforceConfig,
    reinforce_bytes_per_seed,
    PopulationReinforce,
)


__all__ = ["AGENT", "PopulationReinforce", "ReinforceConfig", "reinforce_bytes_per_seed", "rounded_up"]
