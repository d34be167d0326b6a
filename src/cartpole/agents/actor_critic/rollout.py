"""What the actor-critics learn from: every seed's envs played together, and GAE on what they did.

- :func:`play`: up to ``steps`` batched steps of all S x N envs (:class:`~cartpole.agents.episodes.
  SeedEpisodes`), each seed's actions sampled from its own generator, the actors acting through
  their NumPy copy; what the envs did is :class:`Transitions`, time-major ``[T, S * N]``. With
  ``whole_episodes`` (REINFORCE) each env plays one episode.
- :func:`log_probs_of`: the log-probabilities of the actions taken, in one torch pass after the
  rollout (PPO's old ones).
- :func:`advantages`: GAE (:func:`generalized_advantages`) over every env at once, with the seeds'
  critics' values, laid out per seed as a :class:`Rollout`, ``[S, T * N]``: what the losses take.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from cartpole.agents.actor_critic.stacked import StackedActorCritic
from cartpole.agents.episodes import Finished, SeedEpisodes
from cartpole.agents.nn.flat_parameters import Params
from cartpole.agents.seed_state import SeedState


@dataclass
class Transitions:
    """What the envs of every active seed did, time-major ``[T, S * N]`` (observations ``T + 1``)."""

    observations: torch.Tensor
    actions: torch.Tensor
    log_probs: torch.Tensor
    rewards: torch.Tensor
    terminated: torch.Tensor
    truncated: torch.Tensor
    valid: torch.Tensor

    def columns(self, envs: torch.Tensor, steps: int) -> Transitions:
        """The envs ``envs`` only, over ``steps`` steps (padded with invalid rows past the end)."""

        def cut(x: torch.Tensor, rows: int) -> torch.Tensor:
            x = x[: min(rows, x.shape[0]), envs]
            if x.shape[0] < rows:
                x = torch.cat([x, x.new_zeros(rows - x.shape[0], *x.shape[1:])])
            return x

        return Transitions(
            observations=cut(self.observations, steps + 1),
            actions=cut(self.actions, steps),
            log_probs=cut(self.log_probs, steps),
            rewards=cut(self.rewards, steps),
            terminated=cut(self.terminated, steps),
            truncated=cut(self.truncated, steps),
            valid=cut(self.valid, steps),
        )


@dataclass
class Rollout:
    """One rollout of every active seed: rows ``[S, T * N]`` (time-major within a seed)."""

    observations: torch.Tensor
    actions: torch.Tensor
    log_probs: torch.Tensor
    values: torch.Tensor
    advantages: torch.Tensor
    returns: torch.Tensor
    valid: torch.Tensor
    counts: torch.Tensor
    """Valid rows per seed [S]."""


def sample_actions(logits: np.ndarray, uniforms: np.ndarray) -> np.ndarray:
    """One action per row of ``logits`` [..., n_actions] by inverse CDF from ``uniforms`` [...]: the
    number of cumulative softmax probabilities (the last left out) below the uniform."""
    shifted = np.exp(logits - logits.max(axis=-1, keepdims=True))
    cdf = shifted.cumsum(axis=-1)
    return (cdf[..., :-1] < uniforms[..., None] * cdf[..., -1:]).sum(axis=-1)


@torch.no_grad()
def play(
    model: StackedActorCritic,
    episodes: SeedEpisodes,
    generators: list[torch.Generator],
    steps: int,
    whole_episodes: bool = False,
    log_probs: bool = True,
) -> tuple[Transitions, Finished]:
    """Up to ``steps`` batched steps of all S x N envs of ``episodes``; what they did, and each seed's
    finished episodes (returns, lengths). Seed i's actions are sampled from ``generators[i]``. With
    ``whole_episodes`` (REINFORCE) each env plays one episode: its rows after it ended are invalid,
    and play stops once every env has ended one. Until then a seed whose envs have all ended steps
    them on, idle (every seed's envs step as one batch); afterwards they are put back where they
    stood when its last episode ended, where the seed alone leaves them. The actors act through a
    frozen NumPy copy (:meth:`StackedActorCritic.rollout_actor`); the log-probabilities of their
    actions (PPO's old ones; zeros without ``log_probs``) come from one torch pass after the
    rollout."""
    seeds, envs = len(generators), episodes.num_envs
    obs_shape = model.template.obs_shape
    actor = model.rollout_actor()
    observations = np.zeros((steps + 1, seeds * envs, *obs_shape), dtype=episodes.observations.dtype)
    actions = np.zeros((steps, seeds * envs), dtype=np.int64)
    rewards = np.zeros((steps, seeds * envs), dtype=np.float32)
    terminated = np.zeros((steps, seeds * envs), dtype=np.float32)
    truncated = np.zeros((steps, seeds * envs), dtype=np.float32)
    valid = np.zeros((steps, seeds * envs), dtype=bool)
    ended_once = np.zeros(seeds * envs, dtype=bool)
    # Each seed's uniforms for the whole rollout, from its own generator: one call per seed.
    uniforms = np.stack(
        [torch.rand(steps, envs, generator=g, device="cpu").numpy() for g in generators], axis=1
    )
    finished: Finished = [([], []) for _ in range(seeds)]
    held: dict[int, SeedState] = {}
    """The envs of the seeds whose episodes have all ended, as they stood then, by seed row."""
    used = steps
    for t in range(steps):
        observations[t] = episodes.observations
        logits = actor(episodes.observations.reshape(seeds, envs, *obs_shape))
        actions[t] = sample_actions(logits, uniforms[t]).reshape(-1)
        step = episodes.step(actions[t], finished, ended_once if whole_episodes else None)
        rewards[t], terminated[t], truncated[t], valid[t] = (
            step.rewards,
            step.terminated,
            step.truncated,
            step.valid,
        )
        if whole_episodes:
            ended_once |= step.ended
            if ended_once.all():
                used = t + 1
                break
            for row in np.flatnonzero(ended_once.reshape(seeds, envs).all(axis=1)).tolist():
                if row not in held:
                    held[row] = episodes.seed_state(row)
    observations[used] = episodes.observations
    for seed_row, (env_tensors, env_data) in held.items():
        episodes.load_seed_state(seed_row, env_tensors, env_data)
    device = model.flat.device

    def tensor(x: np.ndarray) -> torch.Tensor:
        return torch.from_numpy(x).to(device)

    played = tensor(observations[: used + 1])
    taken = tensor(actions[:used])
    transitions = Transitions(
        observations=played,
        actions=taken,
        log_probs=log_probs_of(model, played[:used], taken)
        if log_probs
        else torch.zeros_like(taken, dtype=torch.float32),
        rewards=tensor(rewards[:used]),
        terminated=tensor(terminated[:used]),
        truncated=tensor(truncated[:used]),
        valid=tensor(valid[:used]),
    )
    return transitions, finished


@torch.no_grad()
def log_probs_of(
    model: StackedActorCritic, observations: torch.Tensor, actions: torch.Tensor
) -> torch.Tensor:
    """The log-probabilities [T, S * N] under the current actors of ``actions`` [T, S * N] taken at
    ``observations`` [T, S * N, *obs_shape]: one batched pass over the whole rollout."""
    steps, rows, *obs_shape = observations.shape
    seeds = model.flat.shape[0]
    by_seed = observations.view(steps, seeds, -1, *obs_shape).transpose(0, 1).reshape(seeds, -1, *obs_shape)
    log_probs = torch.log_softmax(model.logits(by_seed), dim=-1)
    chosen = actions.view(steps, seeds, -1).transpose(0, 1).reshape(seeds, -1, 1)
    return log_probs.gather(-1, chosen).view(seeds, steps, -1).transpose(0, 1).reshape(steps, rows)


def generalized_advantages(
    rewards: torch.Tensor,
    values: torch.Tensor,
    terminated: torch.Tensor,
    truncated: torch.Tensor,
    valid: torch.Tensor,
    gamma: float,
    gae_lambda: float,
) -> torch.Tensor:
    """GAE(lambda) advantages, shape [T, N], of a rollout of T steps from N envs.

    ``values`` has T + 1 rows: ``values[t + 1]`` is the value of the observation that step ``t``
    returned (row T: the observation after the rollout). The TD error of a valid step is
    ``r + gamma * (1 - terminated) * V(next) - V(obs)``: a terminated step has no future, a
    truncated one does (its next observation is the real final state, under next-step autoreset).
    The lambda-sum stops where an episode ended (terminated or truncated): the next row is the
    autoreset step, which is not a transition (``valid`` False) and gets advantage 0.
    """
    valid_f = valid.to(rewards.dtype)
    deltas = valid_f * (rewards + gamma * (1.0 - terminated) * values[1:] - values[:-1])
    carry = gamma * gae_lambda * valid_f * (1.0 - terminated) * (1.0 - truncated)
    steps = rewards.shape[0]
    advantages = torch.zeros((steps + 1, *rewards.shape[1:]), dtype=rewards.dtype, device=rewards.device)
    for t in range(steps - 1, -1, -1):
        torch.addcmul(deltas[t], carry[t], advantages[t + 1], out=advantages[t])
    return advantages[:steps]


@torch.no_grad()
def advantages(
    t: Transitions,
    model: StackedActorCritic,
    params: Params | None,
    num_envs: int,
    gamma: float,
    gae_lambda: float,
) -> Rollout:
    """GAE over the envs of every seed of ``t`` at once (``num_envs`` columns a seed), their values
    from the critics of ``params`` (the parameters of those seeds' networks, in ``model``'s layout),
    reshaped to [S, T * N]. ``params`` None: values are 0, so advantages are the discounted
    reward-to-go."""
    steps, envs = t.rewards.shape[0], num_envs
    seeds = t.rewards.shape[1] // envs

    def per_seed(x: torch.Tensor) -> torch.Tensor:  # [T, S * N, ...] -> [S, T * N, ...]
        return (
            x.view(steps, seeds, envs, *x.shape[2:])
            .transpose(0, 1)
            .reshape(seeds, steps * envs, *x.shape[2:])
        )

    obs_shape = model.template.obs_shape
    if params is not None:
        by_seed = (
            t.observations.view(steps + 1, seeds, envs, *obs_shape)
            .transpose(0, 1)
            .reshape(seeds, -1, *obs_shape)
        )
        critic = StackedActorCritic.run(model.critic_plan, params, by_seed).squeeze(-1)
        values = critic.view(seeds, steps + 1, envs).transpose(0, 1).reshape(steps + 1, -1)
    else:
        values = torch.zeros(steps + 1, seeds * envs, device=t.rewards.device)
    gae = generalized_advantages(t.rewards, values, t.terminated, t.truncated, t.valid, gamma, gae_lambda)
    valid_rows = per_seed(t.valid)
    return Rollout(
        observations=per_seed(t.observations[:steps]),
        actions=per_seed(t.actions),
        log_probs=per_seed(t.log_probs),
        values=per_seed(values[:steps]),
        advantages=per_seed(gae),
        returns=per_seed(gae + values[:steps]),
        valid=valid_rows,
        counts=valid_rows.sum(dim=1).to(torch.float32),
    )


__all__ = [
    "Rollout",
    "Transitions",
    "advantages",
    "generalized_advantages",
    "log_probs_of",
    "play",
    "sample_actions",
]
