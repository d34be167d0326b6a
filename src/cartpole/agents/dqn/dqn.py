"""Deep Q-Network (DQN) for a batch of seeds, read top to bottom.

1. :class:`~cartpole.agents.dqn.config.DQNConfig` (config.py, beside this file): every setting, with a
   one-line docstring each (presets in ``presets/dqn.toml``).
2. The Bellman target (:func:`td_targets`, computed for every seed's minibatch by
   :meth:`PopulationDQN.targets`): double DQN, no bootstrap at termination, truncation by the time
   limit does bootstrap; with ``n_step`` > 1 a replay row holds n steps' discounted rewards and
   bootstraps with ``gamma^n`` (:mod:`cartpole.agents.dqn.n_step`).
3. The loss (:meth:`PopulationDQN.losses`: Huber or MSE, each seed's mean over its own rows) and one
   gradient step (:meth:`PopulationDQN.gradient_step`: for a plain ReLU MLP the gradient with respect
   to the Q-values, :func:`td_gradient`, then the network's by hand; clipping; the
   optimizer step).
4. A training round (:meth:`PopulationDQN.train`): ``gradient_steps`` gradient steps on minibatches
   drawn from each seed's replay memory at the seed's learning rate (constant, or decayed linearly
   with its env steps: :meth:`PopulationDQN.learning_rates`), each followed by the due
   target-network updates (Polyak or hard copies: :meth:`PopulationDQN.update_targets`) and the
   multiplicative epsilon decay (:meth:`PopulationDQN.after_step`).
5. One ``learn()`` (:meth:`PopulationDQN.learn`): one batched env step of every seed, epsilon-greedy
   (:func:`epsilon_at`), its transitions stored (with the tutorials' reward shaping where configured:
   :func:`shaped_rewards`), then a training round for the seeds whose round is due.
6. The agent's spec, as the registry finds it.

Every tensor carries a leading seed axis ``[S, ...]``; a single run is a population of one. What the
rule runs on (the stacked networks, replay memories, envs, generators, acting, checkpoints) is
:class:`~cartpole.agents.dqn.population.QLearningPopulation`.
"""

from __future__ import annotations

import functools
import math
from types import ModuleType
from typing import NamedTuple

import numpy as np
import torch
import torch.nn.functional as F

from cartpole.agents.dqn.config import DQNConfig
from cartpole.agents.dqn.population import (
    QLearningPopulation,
    dqn_bytes_per_seed,
    policy_from_checkpoint,
    q_network_from_checkpoint,
)
from cartpole.agents.dqn.replay import Minibatch
from cartpole.agents.dqn.stacked import padded
from cartpole.agents.episodes import Finished
from cartpole.agents.learner import LearnResult
from cartpole.agents.nn.fixed_order import seed_sums
from cartpole.agents.nn.flat_parameters import to_device
from cartpole.agents.nn.schedules import schedule_value
from cartpole.agents.registry import AgentSpec
from cartpole.envs import EnvInfo

# ----------------------------------------------------------------------------------------------
# 2. The Bellman target
# ----------------------------------------------------------------------------------------------


def td_targets(
    rewards: torch.Tensor,
    terminated: torch.Tensor,
    next_q_target: torch.Tensor,
    next_q_online: torch.Tensor | None,
    gamma: float,
) -> torch.Tensor:
    """``r + gamma * (1 - terminated) * Q_target(s', a*)``.

    ``a*`` is argmax of the online net's values (double DQN) when ``next_q_online`` is given, else of
    the target net's own. Only *termination* stops the bootstrap: a transition cut by the time limit
    (truncated, e.g. step 500 of CartPole-v1) was stored with ``terminated=0``, because the pole was
    still up and the state still had value. Treating truncation as termination teaches the agent that
    step 500 is a cliff, which is the classic reason a DQN "solves" CartPole and then collapses.
    """
    chooser = next_q_target if next_q_online is None else next_q_online
    next_actions = chooser.argmax(dim=1, keepdim=True)
    next_values = next_q_target.gather(1, next_actions).squeeze(1)
    return rewards + gamma * (1.0 - terminated) * next_values


def bellman_targets(
    rewards: torch.Tensor,
    terminated: torch.Tensor,
    next_q_target: torch.Tensor,
    next_q_chooser: torch.Tensor,
    gamma: float,
) -> torch.Tensor:
    """:func:`td_targets` of every seed's rows: rewards and terminated flags [S, B], the next states'
    target values and the chooser's (whose argmax picks the action) [S, B, n_actions]; [S, B]."""
    seeds, rows, n_actions = next_q_target.shape
    targets = td_targets(
        rewards.reshape(-1),
        terminated.reshape(-1),
        next_q_target.reshape(-1, n_actions),
        next_q_chooser.reshape(-1, n_actions),
        gamma,
    )
    return targets.view(seeds, rows)


def td_gradient(
    q_all: torch.Tensor,
    minibatch: Minibatch,
    next_q_target: torch.Tensor,
    next_q_chooser: torch.Tensor,
    row_weights: torch.Tensor,
    gamma: float,
    loss: str,
    kernel: bool | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """The gradient [S, B, n_actions] with respect to the Q-values ``q_all`` of the summed weighted
    loss (each row's loss times its ``row_weights`` [S, B]: see :class:`Round`), and the Bellman
    targets [S, B] (:func:`bellman_targets`) it was taken against. Only the taken actions' values
    have a gradient: Huber's derivative is the error clipped to [-1, 1], MSE's twice the error.

    ``kernel`` None: on the CPU one numba pass over the rows (:mod:`cartpole.agents.dqn._td_kernels`:
    the same bits as torch's operations on float32 tensors, in a fraction of their dispatch), torch
    elsewhere; False: torch always. The tensors carry no autograd graph (the gradient is by hand)."""
    if kernel is not False and q_all.device.type == "cpu":
        gradient, targets = torch.empty_like(q_all), torch.empty_like(minibatch.rewards)
        arrays = [t.numpy() for t in (q_all, minibatch.actions, minibatch.rewards, minibatch.terminated)]
        arrays += [next_q_target.numpy(), next_q_chooser.numpy(), row_weights.numpy()]
        _kernels().td_gradient_rows(*arrays, gamma, loss == "huber", gradient.numpy(), targets.numpy())
        return gradient, targets
    targets = bellman_targets(minibatch.rewards, minibatch.terminated, next_q_target, next_q_chooser, gamma)
    error = q_all.gather(2, minibatch.actions).squeeze(2) - targets
    slope = error.clamp(-1.0, 1.0) if loss == "huber" else 2.0 * error
    gradient = torch.zeros_like(q_all).scatter_(2, minibatch.actions, (slope * row_weights).unsqueeze(2))
    return gradient, targets


@functools.cache
def _kernels() -> ModuleType:
    """The numba kernel, compiled on first use (importing this module does not import numba)."""
    from cartpole.agents.dqn import _td_kernels

    return _td_kernels


# ----------------------------------------------------------------------------------------------
# Exploration and reward shaping
# ----------------------------------------------------------------------------------------------


def shaped_rewards(
    config: DQNConfig,
    rewards: np.ndarray,
    terminated: np.ndarray,
    done: np.ndarray,
    episode_lengths: np.ndarray,
) -> np.ndarray:
    """The tutorials' reward shaping, where configured (the raw rewards otherwise): ``termination_reward``
    for a terminating transition, ``short_episode_reward`` for the last one of an episode shorter than
    ``short_episode_length`` (``episode_lengths``: each env's episode so far)."""
    if config.termination_reward is None and config.short_episode_reward is None:
        return rewards
    shaped = rewards.astype(np.float32, copy=True)
    if config.termination_reward is not None:
        shaped[terminated] = config.termination_reward
    if config.short_episode_reward is not None:
        shaped[done & (episode_lengths < config.short_episode_length)] = config.short_episode_reward
    return shaped


def epsilon_at(config: DQNConfig, env_steps: int, multiplied: float) -> float:
    """Exploration rate after ``env_steps`` (``multiplied`` is the multiplicative schedule's value)."""
    start, end = config.epsilon_start, config.epsilon_end
    if config.epsilon_schedule == "linear":
        return end + (start - end) * max(0.0, 1.0 - env_steps / config.epsilon_decay_steps)
    if config.epsilon_schedule == "exponential":
        return end + (start - end) * math.exp(-env_steps / config.epsilon_decay_steps)
    return multiplied


# ----------------------------------------------------------------------------------------------
# 3. to 5. The loss, a gradient step, a training round and one learn()
# ----------------------------------------------------------------------------------------------


class Round(NamedTuple):
    """What every gradient step of one training round shares, on the device: the minibatch row mask
    [S, B], each seed's row count [S], who trains [S], the learning rates [S], and each row's weight
    in its seed's mean loss [S, B] (``active / count`` on its rows, 0 on padding)."""

    mask: torch.Tensor
    row_counts: torch.Tensor
    active: torch.Tensor
    lr: torch.Tensor
    row_weights: torch.Tensor


class PopulationDQN(QLearningPopulation):
    """DQN for seeds ``seeds``, all with ``config``: one ``learn()`` = one batched env step of every
    seed and its due gradient steps."""

    def __init__(self, config: DQNConfig, env: EnvInfo, seeds: list[int], device: str = "cpu"):
        super().__init__(config, env, seeds, device)
        self.batch_rows = padded(config.batch_size)
        self.rounds: dict[bytes, Round] = {}
        """The last training round's tensors (see :meth:`round_tensors`), by who trained and their rows."""

    @torch.no_grad()
    def next_q_values(self, next_observations: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The values of every seed's next states [S, B, n_actions]: the target networks' (which value
        the chosen action) and the chooser's (whose argmax chooses it: the online networks' for double
        DQN, else the same tensor). Without a target network the online nets (without dropout) do both."""
        config, net = self.config, self.net
        if config.double_dqn and net.target is not None:  # both networks in one pass
            twice = torch.cat([next_observations, next_observations])  # cheaper than repeat()
            q = net.forward(net.pair_params, twice, self.activation, buffers="next")
            next_q_target, next_q_online = q.chunk(2)
            return next_q_target, next_q_online
        next_q_target = net.forward(net.target_params, next_observations, self.activation, buffers="next")
        return next_q_target, next_q_target

    @torch.no_grad()
    def targets(
        self, next_observations: torch.Tensor, rewards: torch.Tensor, terminated: torch.Tensor
    ) -> torch.Tensor:
        """The Bellman targets [S, B] of every seed's minibatch (:func:`td_targets`, per row), with
        ``gamma^n_step``."""
        next_q_target, next_q_chooser = self.next_q_values(next_observations)
        return bellman_targets(rewards, terminated, next_q_target, next_q_chooser, self.discount)

    def losses(
        self, q: torch.Tensor, targets: torch.Tensor, mask: torch.Tensor, count: torch.Tensor
    ) -> torch.Tensor:
        """Each seed's mean TD loss [S] over its own rows (where ``mask`` is 1) of ``q`` against
        ``targets`` [S, B]."""
        if self.config.loss == "huber":
            elementwise = F.smooth_l1_loss(q, targets, reduction="none")
        else:
            elementwise = F.mse_loss(q, targets, reduction="none")
        return seed_sums(elementwise * mask) / count

    @property
    def discount(self) -> float:
        """What a replay row's bootstrap is discounted by: ``gamma^n_step``."""
        return self.config.gamma**self.config.n_step

    def gradient_step(
        self,
        minibatch: Minibatch,
        keeps: list[torch.Tensor] | None,
        shared: Round,
        metrics: bool = True,
    ) -> torch.Tensor | None:
        """One update of the online networks of the active seeds on ``minibatch`` (its rows where the
        round's mask is 0 are padding); with ``metrics``, each seed's loss and Q mean [S, 2]
        (detached; a round reports its last step's, and a gradient by hand needs no loss)."""
        config, net = self.config, self.net
        if net.plain_relu and keeps is None:
            measured = self.gradient_by_hand(minibatch, shared, metrics)
        else:
            measured = self.gradient_by_autograd(minibatch, keeps, shared)
        if config.max_grad_value is not None:  # every value on its own, as clip_grad_value_
            net.grad.clamp_(-config.max_grad_value, config.max_grad_value)
        if config.max_grad_norm is not None:
            net.clip_grad_norms(config.max_grad_norm)
        self.optimizer.step(net.flat, net.grad, shared.lr, shared.active)
        if not metrics or measured is None:
            return None
        q, losses = measured
        with torch.no_grad():
            q_means = seed_sums(q.detach() * shared.mask) / shared.row_counts
            return torch.stack([losses.detach(), q_means], dim=1)

    @torch.no_grad()
    def gradient_by_hand(
        self, minibatch: Minibatch, shared: Round, metrics: bool
    ) -> tuple[torch.Tensor, torch.Tensor] | None:
        """Write the online networks' gradients of a plain ReLU MLP (no dropout) on ``minibatch`` into
        ``net.grad``: the Q-values' (:func:`td_gradient`), then the network's by hand. With
        ``metrics``, the taken actions' Q-values [S, B] and each seed's loss [S] (no gradient needs
        them)."""
        net, loss = self.net, self.config.loss
        inputs: list[torch.Tensor] = []
        observations = minibatch.observations
        q_all = net.forward(net.params, observations, self.activation, inputs=inputs, buffers="online")
        next_q_target, next_q_chooser = self.next_q_values(minibatch.next_observations)
        grad, targets = td_gradient(
            q_all, minibatch, next_q_target, next_q_chooser, shared.row_weights, self.discount, loss
        )
        net.backward_by_hand(inputs, grad)
        if not metrics:
            return None
        q = q_all.gather(2, minibatch.actions).squeeze(2)
        return q, self.losses(q, targets, shared.mask, shared.row_counts)

    def gradient_by_autograd(
        self, minibatch: Minibatch, keeps: list[torch.Tensor] | None, shared: Round
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Write the online networks' gradients on ``minibatch`` into ``net.grad`` by autograd (dropout
        masks ``keeps``; any activation, dueling heads, convolutions): the taken actions' Q-values [S, B]
        and each seed's loss [S]."""
        net = self.net
        with torch.enable_grad():
            q_all = net.forward(net.params, minibatch.observations, self.activation, keeps)
            targets = self.targets(minibatch.next_observations, minibatch.rewards, minibatch.terminated)
            q = q_all.gather(2, minibatch.actions).squeeze(2)
            losses = self.losses(q, targets, shared.mask, shared.row_counts)
            net.grad.zero_()
            net.backward((losses * shared.active.to(losses.dtype)).sum())
        return q, losses

    def dropout_keeps(self, training: np.ndarray, counts: np.ndarray) -> list[torch.Tensor]:
        """Each hidden layer's dropout keep-mask [S, batch rows, width] for one gradient step: each
        training seed's from its own dropout generator, layer by layer as ``GeneratorDropout`` draws."""
        p, rows = self.net.dropout, self.batch_rows
        widths = self.config.hidden_sizes
        uniforms = [torch.zeros(len(self.seeds), rows, w, device="cpu") for w in widths]
        for row in np.flatnonzero(training):
            count, generator = int(counts[row]), self.dropout_generators[row]
            for layer, width in zip(uniforms, widths, strict=True):
                layer[row, :count] = torch.rand(count, width, generator=generator, device="cpu")
        return [to_device(u >= p, self.device) for u in uniforms]

    def train(self, training: np.ndarray) -> torch.Tensor:
        """``gradient_steps`` batched updates in which the seeds where ``training`` [S] is True take
        part (the others sit out); the last step's loss and Q mean per seed [S, 2] (on the device)."""
        config, device = self.config, self.device
        counts = np.where(training, np.minimum(config.batch_size, self.replay.size), 0)
        shared = self.round_tensors(training, counts)
        metrics = torch.zeros(len(self.seeds), 2, device=device)
        slots = self.replay.sample_slots(
            training, counts, config.gradient_steps, self.batch_rows, self.replay_generators
        )
        for step, minibatch in enumerate(self.replay.minibatches(slots)):
            keeps = self.dropout_keeps(training, counts) if self.net.dropout > 0 else None
            last = step == config.gradient_steps - 1
            measured = self.gradient_step(minibatch, keeps, shared, metrics=last)
            metrics = metrics if measured is None else measured
            self.after_step(training)
        return metrics

    def round_tensors(self, training: np.ndarray, counts: np.ndarray) -> Round:
        """A training round's shared tensors (:class:`Round`): those of the rows are made again only when
        who trains or how many rows they have changes; a scheduled learning rate, every round."""
        key = training.tobytes() + counts.tobytes()
        if key not in self.rounds:
            device = self.device
            rows = (np.arange(self.batch_rows) < counts[:, None]).astype(np.float32)
            mask = to_device(torch.from_numpy(rows), device)
            count = to_device(torch.from_numpy(np.maximum(counts, 1).astype(np.float32)), device)
            active = to_device(torch.from_numpy(training.copy()), device)
            row_weights = (active.to(mask.dtype) / count).unsqueeze(1) * mask
            self.rounds = {key: Round(mask, count, active, self.learning_rates(), row_weights)}
        shared = self.rounds[key]
        return shared if self.config.lr_schedule == "constant" else shared._replace(lr=self.learning_rates())

    def learning_rates(self) -> torch.Tensor:
        """Each seed's learning rate now [S] (the schedule follows the seed's own env steps)."""
        config = self.config
        rates = [
            schedule_value(config.lr, config.lr_schedule, int(s), config.schedule_steps)
            for s in self.env_steps
        ]
        return to_device(torch.tensor(rates, dtype=torch.float64, device="cpu"), self.device)

    @torch.no_grad()
    def update_targets(self, rows: np.ndarray) -> None:
        """Polyak update of the target networks of the seeds at ``rows``: target <- target + tau *
        (online - target); a copy when tau is 1."""
        net, tau = self.net, self.config.tau
        if net.target is None or not rows.any():
            return
        if rows.all():
            if tau >= 1.0:
                net.target.copy_(net.flat)
            else:
                net.target.lerp_(net.flat, tau)
            return
        index = to_device(torch.from_numpy(np.flatnonzero(rows)), net.flat.device)
        online = net.flat.index_select(0, index)
        moved = online if tau >= 1.0 else net.target.index_select(0, index).lerp_(online, tau)
        net.target.index_copy_(0, index, moved)

    def after_step(self, training: np.ndarray) -> None:
        """Count the gradient step of the ``training`` seeds; their due target updates and their
        multiplicative epsilon decay."""
        config = self.config
        self.gradient_steps += training
        due = training & (self.gradient_steps % config.target_update_interval == 0)
        self.update_targets(due)
        if config.epsilon_schedule == "multiplicative":
            m = self.epsilon_multiplied
            decays = training & (m > config.epsilon_end)
            self.epsilon_multiplied = np.where(
                decays, np.maximum(config.epsilon_end, m * config.epsilon_decay_rate), m
            )

    def learn(self) -> dict[int, LearnResult]:
        """One batched env step of every seed, then the gradient steps of the seeds whose training
        round is due; each active seed's result by seed."""
        config = self.config
        seeds, n = len(self.seeds), config.num_envs
        epsilons = [
            epsilon_at(config, int(steps), float(multiplied))
            for steps, multiplied in zip(self.env_steps, self.epsilon_multiplied, strict=True)
        ]
        actions = self.select_actions(epsilons)
        finished: Finished = [([], []) for _ in self.seeds]
        step = self.episodes.step(actions, finished)
        valid = step.valid
        rewards = shaped_rewards(config, step.rewards, step.terminated & valid, step.ended, step.lengths)
        self.store(step, actions, rewards)
        collected = valid.reshape(seeds, n).sum(axis=1)
        self.env_steps += collected

        self.calls += 1
        training = (self.calls % config.train_freq == 0) & (self.env_steps >= config.learning_starts)
        training &= (config.gradient_steps > 0) & (self.replay.size > 0)  # n-step rows come n steps late
        metrics = self.train(training) if training.any() else None
        self.read_back(metrics, training)
        return self.results(collected, finished, epsilons)


# ----------------------------------------------------------------------------------------------
# 6. The spec
# ----------------------------------------------------------------------------------------------


AGENT = AgentSpec(
    name="dqn",
    summary="Deep Q-Network (PyTorch): double DQN, replay, target network, vectorized collection",
    config_cls=DQNConfig,
    policy_from_checkpoint=policy_from_checkpoint,
    bytes_per_seed=dqn_bytes_per_seed,
    make_population=PopulationDQN,
    iteration="step",
    score_label="Q-values",
    image_observations=True,
    scores_network=q_network_from_checkpoint,
)


__all__ = ["AGENT", "PopulationDQN", "epsilon_at", "shaped_rewards", "td_targets"]
