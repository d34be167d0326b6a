"""What PPO, A2C and REINFORCE share, batched over seeds: :class:`PopulationActorCritic`, the base
each learning rule (ppo.py, a2c.py, reinforce.py) subclasses with its own ``learn()``.

Every seed is its own training run: its own network (initialized from its ``init`` generator), its
own ``num_envs`` envs seeded as its run seeds them, its own action sampling and minibatch shuffling
(its ``actions`` generator) and its own optimizer state. What the seeds share is the arithmetic, on a
leading seed axis:

- the networks: :class:`~cartpole.agents.actor_critic.stacked.StackedActorCritic`;
- the envs and their episodes: :class:`~cartpole.agents.episodes.SeedEpisodes`, played and turned
  into advantages by :mod:`cartpole.agents.actor_critic.rollout`;
- the optimizer: one Adam or RMSprop step for every seed's row
  (:mod:`cartpole.agents.nn.population_optimizers`), each seed with its own learning rate (schedules
  follow the seed's own env steps) and step count, and free to sit a step out;
- each seed's greedy policy and checkpoint (:mod:`cartpole.agents.seed_state`), in the format
  ``load_policy``, ``cartpole eval`` and the web app read.

``remove`` drops seeds that have stopped (solved or out of budget), so they cost nothing more.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
import torch

from cartpole.agents.actor_critic.network import (
    CategoricalPolicy,
    block_greedy_actor,
    conv_output_size,
    parameter_count,
    stacked_greedy_actor,
)
from cartpole.agents.actor_critic.policy_gradient import (
    PolicyGradientConfig,
    logits_loader,
    policy_loader,
    seeded_actor_critic,
)
from cartpole.agents.actor_critic.rollout import Rollout, advantages, play
from cartpole.agents.actor_critic.stacked import StackedActorCritic
from cartpole.agents.episodes import Finished, SeedEpisodes
from cartpole.agents.learner import LearnResult
from cartpole.agents.nn.flat_parameters import on_the_cpu
from cartpole.agents.nn.masked import masked_variance
from cartpole.agents.nn.population_optimizers import population_optimizer
from cartpole.agents.nn.schedules import schedule_value
from cartpole.agents.population import Population, staying_rows
from cartpole.agents.registry import AgentSpec
from cartpole.agents.seed_state import SeedState, require_training_state, unprefixed, with_training_state
from cartpole.core.seeding import derived_seed
from cartpole.envs import EnvInfo
from cartpole.envs.seed_envs import rows_of_envs
from cartpole.evaluation import BlockActor


class PopulationActorCritic:
    """The actor-critics of seeds ``seeds``, all with ``config``: their stacked networks, envs,
    generators and optimizer, the rollout with GAE, the optimizer step, and each seed's policy and
    checkpoint. A subclass says what one ``learn()`` does."""

    def __init__(
        self,
        config: PolicyGradientConfig,
        env: EnvInfo,
        seeds: list[int],
        device: str,
        optimizer: str = "adam",
        eps: float = 1e-8,
        rms_alpha: float = 0.99,
    ):
        config.validate()
        self.config, self.env_info = config, env
        self.device = torch.device(device)
        """Where the networks, rollouts and updates live. The envs step on the CPU (numpy) and the
        seeds' random numbers come from their CPU generators, so a seed's draws are the same on any
        device; only the floats of the network arithmetic differ between devices."""
        self.seeds = list(seeds)
        """The seed of each row of every batch."""
        with on_the_cpu():  # each from its seed's CPU generator, then moved
            models = [seeded_actor_critic(config, env, seed) for seed in self.seeds]
        self.model = StackedActorCritic(models, self.device)
        self.optimizer = population_optimizer(
            optimizer, len(self.seeds), self.model.size, self.device, eps, rms_alpha
        )
        self.generators = [torch.Generator().manual_seed(derived_seed(s, "actions")) for s in self.seeds]
        self.episodes = SeedEpisodes(env, config.simulator, self.seeds, config.num_envs)
        self.env_steps = np.zeros(len(self.seeds), dtype=np.int64)
        self.updates = np.zeros(len(self.seeds), dtype=np.int64)

    @property
    def active_seeds(self) -> list[int]:
        return list(self.seeds)

    def remove(self, seeds: list[int]) -> None:
        """Stop training ``seeds`` (solved or out of budget): they leave every batch."""
        rows_np = staying_rows(self.seeds, seeds)
        self.seeds = [self.seeds[i] for i in rows_np]
        rows = torch.from_numpy(rows_np).to(self.device)
        self.model.keep(rows)
        self.optimizer.keep(rows)
        self.episodes.keep(rows_np, rows_of_envs(rows_np, self.config.num_envs))
        self.generators = [self.generators[i] for i in rows_np]
        self.env_steps, self.updates = self.env_steps[rows_np], self.updates[rows_np]

    # -- what every update uses ---------------------------------------------------------------------

    def learning_rates(self) -> list[float]:
        """Each seed's learning rate now (schedules follow the seed's own env steps)."""
        config = self.config
        return [
            schedule_value(config.lr, config.lr_schedule, int(s), config.schedule_steps)
            for s in self.env_steps
        ]

    def collect(self, n_steps: int, gae_lambda: float, log_probs: bool = True) -> tuple[Rollout, Finished]:
        """``n_steps`` batched steps of all S x N envs; the rollout with GAE(``gae_lambda``)
        advantages (and, with ``log_probs``, the actions' log-probabilities), and each seed's finished
        episodes."""
        transitions, finished = play(self.model, self.episodes, self.generators, n_steps, log_probs=log_probs)
        config = self.config
        rollout = advantages(
            transitions, self.model, self.model.params, config.num_envs, config.gamma, gae_lambda
        )
        return rollout, finished

    def count_steps(self, counts: list[int], finished: Finished) -> dict[int, LearnResult]:
        """Add each seed's new transitions (``counts``) to its env steps; its result (steps and
        finished episodes)."""
        results = {}
        for row, seed in enumerate(self.seeds):
            returns, lengths = finished[row]
            self.env_steps[row] += counts[row]
            results[seed] = LearnResult(counts[row], episode_returns=returns, episode_lengths=lengths)
        return results

    def backward_and_step(self, losses: torch.Tensor, lr: torch.Tensor, active: torch.Tensor) -> None:
        """Gradients of every active seed's loss (``losses`` [S]), clipped per seed, one optimizer step."""
        self.model.grad.zero_()
        self.model.backward((losses * active.float()).sum())
        self.step(lr, active)

    def heads_backward_and_step(
        self, logits_grad: torch.Tensor, values_grad: torch.Tensor, lr: torch.Tensor, active: torch.Tensor
    ) -> None:
        """:meth:`backward_and_step` from the gradients of every seed's loss with respect to its
        logits and values (:meth:`StackedActorCritic.backward_from_heads`), those of inactive seeds
        left out."""
        weights = active.to(logits_grad.dtype).unsqueeze(1)
        self.model.grad.zero_()
        self.model.backward_from_heads(logits_grad * weights.unsqueeze(2), values_grad * weights)
        self.step(lr, active)

    def step(self, lr: torch.Tensor, active: torch.Tensor) -> None:
        """Clip each seed's gradient norm to ``max_grad_norm`` (as clip_grad_norm_ does), then the
        optimizer's step of the ``active`` seeds."""
        if self.config.max_grad_norm is not None:
            self.model.clip_grad_norms(self.config.max_grad_norm)
        self.optimizer.step(self.model.flat, self.model.grad, lr, active)

    def explained_variances(self, rollout: Rollout) -> torch.Tensor:
        """Per seed, how much of the returns' variance the values explain (NaN with no variance)."""
        valid = rollout.valid.float()
        variance = masked_variance(rollout.returns, valid, rollout.counts)
        residual = masked_variance(rollout.returns - rollout.values, valid, rollout.counts)
        return torch.where(variance > 0, 1.0 - residual / variance, torch.full_like(variance, math.nan))

    def attach_metrics(
        self, results: dict[int, LearnResult], counts: torch.Tensor, metrics: list[dict[str, float]]
    ) -> None:
        """Give each seed that updated (``counts`` [S] of new transitions) its metrics row."""
        for row, (seed, count) in enumerate(zip(self.seeds, counts.tolist(), strict=True)):
            if count == 0:
                continue
            results[seed].scalars = metrics[row]
            results[seed].log_scalars = True

    # -- each seed's policy and checkpoint ----------------------------------------------------------

    def greedy_actor(self, seeds: list[int]) -> BlockActor:
        """The greedy policies of ``seeds`` as one :data:`~cartpole.evaluation.BlockActor` (block i
        holds seed i's rows), one stacked NumPy forward pass per call (torch for convolutional actors)."""
        rows = [self.seeds.index(s) for s in seeds]
        if self.model.template.is_image:
            return self.model.torch_block_actor(rows)
        return block_greedy_actor(self.model.numpy_actor(rows), self.env_info.obs_dim)

    def seed_policy(self, seed: int) -> CategoricalPolicy:
        """Seed ``seed``'s greedy policy (a frozen copy)."""
        return CategoricalPolicy(self.model.unstack(self.seeds.index(seed)))

    def seed_state_dict(self, seed: int, resume: bool) -> SeedState:
        """Seed ``seed``'s checkpoint: ``model.*``, its :class:`ActorCritic`'s state dict
        (``load_policy`` reads it), and with ``resume`` its optimizer, generator, envs and counters."""
        row = self.seeds.index(seed)
        env = self.env_info
        data = {"obs_dim": env.obs_dim, "obs_shape": list(env.obs_shape), "n_actions": env.n_actions}
        policy = (self.model.row_state_dict(row, "model."), data)
        if not resume:
            return policy
        counters = {"env_steps": int(self.env_steps[row]), "updates": int(self.updates[row])}
        generator = ({"rng.torch": self.generators[row].get_state()}, counters)
        return with_training_state(
            policy, self.optimizer.row_state(row), self.episodes.seed_state(row), generator
        )

    def load_seed_state_dict(self, seed: int, tensors: dict[str, torch.Tensor], data: dict[str, Any]) -> None:
        """Restore what ``seed_state_dict(seed, resume=True)`` gave."""
        require_training_state(data)
        row = self.seeds.index(seed)
        model = self.model.template
        model.load_state_dict(unprefixed(tensors, "model."))
        self.model.load_row(row, dict(model.named_parameters()))
        self.optimizer.load_row_state(row, tensors, data)
        self.generators[row].set_state(tensors["rng.torch"])
        self.episodes.load_seed_state(row, tensors, data)
        self.env_steps[row], self.updates[row] = int(data["env_steps"]), int(data["updates"])


BOOKKEEPING_BYTES = 2 * 1024**2
"""What a seed costs besides its arrays: its run folder's writers, callbacks and status thread."""


def actor_critic_bytes_per_seed(
    config: PolicyGradientConfig, env: EnvInfo, rollout_steps: int, batch_rows: int
) -> int:
    """What one seed of an actor-critic population holds, roughly: parameters with their gradient
    and optimizer state, a rollout of ``rollout_steps`` steps of every env, the activations of a
    batch of ``batch_rows`` rows, and the bookkeeping. Image observations: the rollout keeps their
    uint8 pixels (1 byte each, not 4), and every trunk's activations include the scaled pixels and
    the convolutional layers' outputs, for the batch and for the whole rollout's no-grad passes
    (the old log-probabilities and the values)."""
    parameters = parameter_count(env.obs_shape, env.n_actions, config.hidden_sizes, config.shared_trunk)
    rows, widths, observation_bytes = batch_rows, sum(config.hidden_sizes), env.obs_dim * 4
    if env.is_image:
        rows = max(batch_rows, (rollout_steps + 1) * config.num_envs)
        widths += env.obs_dim + conv_output_size(env.obs_shape) * 4  # scaled pixels, conv outputs
        observation_bytes = env.obs_dim
    rollout = rollout_steps * config.num_envs * (observation_bytes + 8 * 4) * 3
    activations = rows * widths * 4 * 12
    return parameters * 4 * 6 + rollout + activations + BOOKKEEPING_BYTES


def actor_critic_spec(
    name: str,
    summary: str,
    config_cls: type[PolicyGradientConfig],
    bytes_per_seed: Callable[[Any, EnvInfo], int],
    make_population: Callable[[Any, EnvInfo, list[int], str], Population],
) -> AgentSpec:
    """An actor-critic agent: its checkpoints hold an :class:`ActorCritic`, its scores are action
    probabilities, and it learns from pixels too."""
    return AgentSpec(
        name=name,
        summary=summary,
        config_cls=config_cls,
        policy_from_checkpoint=policy_loader(name, config_cls),
        bytes_per_seed=bytes_per_seed,
        make_population=make_population,
        iteration="update",
        score_label="action probabilities",
        stacked_actor=stacked_greedy_actor,
        image_observations=True,
        scores_network=logits_loader(name, config_cls),
    )


__all__ = ["PopulationActorCritic", "actor_critic_bytes_per_seed", "actor_critic_spec"]
