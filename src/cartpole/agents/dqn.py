"""Deep Q-Network (DQN) in PyTorch, readable top to bottom.

What it does, in order:

1. ``DQNConfig``: every knob, with a one-line docstring each (presets in ``presets/dqn.toml``).
2. ``td_targets``: the one place the Bellman target is computed (double DQN, and no bootstrap at
   termination; truncation by the time limit does bootstrap).
3. ``DQNLearner``: collects one batched step from ``num_envs`` vector envs per ``learn()`` call with a
   single forward pass, stores it in the shared :class:`~cartpole.agents.replay_buffer.ReplayBuffer`,
   and runs ``gradient_steps`` updates every ``train_freq`` calls. The shared training loop does the
   rest (evaluation, best checkpoint, stop when solved, budget).
4. Checkpoints: what a resume restores, and the greedy policy rebuilt from a checkpoint.

The parts it uses live apart: the network and its greedy policy in :mod:`cartpole.agents.q_network`,
Adam in :mod:`cartpole.agents.nn.optimizers`, the replay buffer in :mod:`cartpole.agents.replay_buffer`, and
the vector envs a checkpoint can put back mid-episode in :mod:`cartpole.envs.resumable_envs`.

The learner owns every random stream it uses (network initialization, dropout masks, exploration,
replay sampling), each seeded from the run's seed: building or training one changes nothing global
(not torch's or numpy's global generators, not torch's thread count: that is the caller's choice).

The three exploration schedules are the ones the tutorials used: linear (ours), exponential per env
step (the PyTorch tutorial), and multiplicative per gradient step (the Keras tutorial).
"""

from __future__ import annotations

import copy
import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from cartpole.agents.learner import LearnResult
from cartpole.agents.memory import dqn_memory_problem
from cartpole.agents.nn.optimizers import FusedAdam
from cartpole.agents.q_network import ACTIVATIONS, QNetwork, QNetworkPolicy
from cartpole.agents.replay_buffer import ReplayBuffer
from cartpole.core.config import build_config, require
from cartpole.core.seeding import derived_seed
from cartpole.envs import EnvInfo, check_simulator
from cartpole.envs.resumable_envs import make_resumable_vec_env, restore_vector_env_state, vector_env_state
from cartpole.runs import Checkpoint, CheckpointError

SCHEDULES = ("linear", "exponential", "multiplicative")
LOSSES = ("huber", "mse")


# ----------------------------------------------------------------------------------------------
# 1. Configuration
# ----------------------------------------------------------------------------------------------


@dataclass
class DQNConfig:
    """Hyperparameters of DQN. Defaults are the ``default`` preset's values for CartPole-v1."""

    # network
    hidden_sizes: tuple[int, ...] = (64, 64)
    """Widths of the hidden layers of the Q-network MLP."""
    activation: str = "relu"
    """Hidden-layer activation: relu, tanh, elu or gelu."""
    dropout: float = 0.0
    """Dropout after each hidden layer while training (0 = none); acting and targets run without it."""
    dueling: bool = False
    """Dueling head: Q = V + A - mean(A)."""
    # learning
    lr: float = 1e-3
    """Adam learning rate."""
    gamma: float = 0.99
    """Discount factor."""
    loss: str = "huber"
    """TD loss: huber (smooth L1) or mse."""
    max_grad_norm: float | None = None
    """Clip the gradient's global norm to this (none: no clipping)."""
    double_dqn: bool = True
    """Double DQN: the online net picks the next action, the target net values it."""
    target_network: bool = True
    """Use a separate target network (false: targets from the online net, as both tutorials do)."""
    target_update_interval: int = 1
    """Gradient steps between target-network updates (SB3 counts env steps instead)."""
    tau: float = 0.02
    """Target update: Polyak weight of the online net (1.0 = hard copy)."""
    # replay and updates
    buffer_size: int = 50_000
    """Replay memory capacity (transitions)."""
    batch_size: int = 256
    """Minibatch size of a gradient step (smaller while the memory holds fewer rows)."""
    learning_starts: int = 1000
    """Env steps collected before the first gradient step."""
    num_envs: int = 8
    """Vector envs stepped together; one learn() call collects one transition from each."""
    train_freq: int = 1
    """learn() calls (batched env steps) between training rounds."""
    gradient_steps: int = 2
    """Gradient steps per training round."""
    # exploration
    epsilon_schedule: str = "linear"
    """linear (over epsilon_decay_steps), exponential (time constant epsilon_decay_steps, per env
    step) or multiplicative (x epsilon_decay_rate per gradient step)."""
    epsilon_start: float = 1.0
    """Initial probability of a random action."""
    epsilon_end: float = 0.01
    """Final (minimum) probability of a random action."""
    epsilon_decay_steps: int = 6000
    """Env steps of the linear decay, or the time constant of the exponential one."""
    epsilon_decay_rate: float = 0.999
    """Factor applied per gradient step by the multiplicative schedule."""
    # reward shaping (off by default; the tutorials used them)
    termination_reward: float | None = None
    """Replace the reward of a terminating transition by this value (Keras tutorial: -10)."""
    short_episode_reward: float | None = None
    """Replace the reward of the last transition of an episode shorter than short_episode_length."""
    short_episode_length: int = 0
    """Length below which an ending episode gets short_episode_reward (PyTorch tutorial: 195)."""
    # runtime
    simulator: str = "fast"
    """Training simulator: fast (our batched CartPole; other envs use Gymnasium) or gymnasium."""

    def validate(self) -> None:
        """Reject bad values with one clear line each."""
        require(len(self.hidden_sizes) >= 1, "hidden_sizes needs at least one layer, e.g. 128,128")
        require(all(h >= 1 for h in self.hidden_sizes), "hidden_sizes must all be >= 1")
        require(self.activation in ACTIVATIONS, f"activation must be one of {', '.join(ACTIVATIONS)}")
        require(0.0 <= self.dropout < 1.0, "dropout must be in [0, 1)")
        require(self.lr > 0, f"lr must be > 0, got {self.lr}")
        require(0.0 <= self.gamma <= 1.0, f"gamma must be in [0, 1], got {self.gamma}")
        require(self.loss in LOSSES, f"loss must be one of {', '.join(LOSSES)}, got {self.loss!r}")
        require(self.max_grad_norm is None or self.max_grad_norm > 0, "max_grad_norm must be > 0 or none")
        require(self.target_update_interval >= 1, "target_update_interval must be >= 1")
        require(0.0 < self.tau <= 1.0, f"tau must be in (0, 1], got {self.tau}")
        require(self.buffer_size >= 1, f"buffer_size must be >= 1, got {self.buffer_size}")
        require(self.batch_size >= 1, f"batch_size must be >= 1, got {self.batch_size}")
        require(self.learning_starts >= 0, "learning_starts must be >= 0")
        require(self.num_envs >= 1, f"num_envs must be >= 1, got {self.num_envs}")
        require(self.train_freq >= 1, f"train_freq must be >= 1, got {self.train_freq}")
        require(self.gradient_steps >= 0, f"gradient_steps must be >= 0, got {self.gradient_steps}")
        require(self.epsilon_schedule in SCHEDULES, f"epsilon_schedule must be one of {', '.join(SCHEDULES)}")
        require(
            0.0 <= self.epsilon_end <= self.epsilon_start <= 1.0,
            "need 0 <= epsilon_end <= epsilon_start <= 1",
        )
        require(self.epsilon_decay_steps >= 1, "epsilon_decay_steps must be >= 1")
        require(0.0 < self.epsilon_decay_rate <= 1.0, "epsilon_decay_rate must be in (0, 1]")
        require(self.short_episode_length >= 0, "short_episode_length must be >= 0")
        check_simulator(self.simulator)
        problem = dqn_memory_problem(self.buffer_size, self.hidden_sizes, self.batch_size)
        require(problem is None, problem or "")


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


# ----------------------------------------------------------------------------------------------
# 3. The learner
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


class DQNLearner:
    """DQN as a Learner of the shared loop: one ``learn()`` = one batched env step + due updates."""

    def __init__(self, config: DQNConfig, env: EnvInfo, seed: int, device: str = "cpu"):
        config.validate()
        self.config, self.env_info, self.seed = config, env, seed
        self.device = torch.device(device)
        # The learner's own random streams, one per use, so that none depends on another's draws.
        init_generator = torch.Generator().manual_seed(derived_seed(seed, "init"))
        self.dropout_generator = torch.Generator(self.device).manual_seed(derived_seed(seed, "dropout"))
        self.replay_generator = torch.Generator(self.device).manual_seed(derived_seed(seed, "replay"))
        self.rng = np.random.default_rng(derived_seed(seed, "explore"))
        """Exploration: which envs act at random, and their random actions."""

        self.q_net = QNetwork(env.obs_dim, env.n_actions, config, init_generator).to(self.device).eval()
        self.q_net.use_dropout_generator(self.dropout_generator)
        self.target_net = copy.deepcopy(self.q_net) if config.target_network else None
        self.parameters = list(self.q_net.parameters())
        self.target_parameters = list(self.target_net.parameters()) if self.target_net is not None else []
        # Adam as torch.optim.Adam(fused=True) computes it, without torch.optim's one-off import of
        # torch._dynamo and its per-step wrapper (see agents/optimizers.py).
        self.optimizer = FusedAdam(self.parameters, lr=config.lr)
        self.buffer = ReplayBuffer(config.buffer_size, env.obs_dim, self.device)

        self.envs = make_resumable_vec_env(env.env_id, config.num_envs, check_simulator(config.simulator))
        self.observations, _ = self.envs.reset(seed=seed)
        n = config.num_envs
        self.autoreset = np.zeros(n, dtype=bool)
        """Envs whose last step ended an episode: their next step is a reset, not a transition."""
        self.episode_returns = np.zeros(n, dtype=np.float64)
        self.episode_lengths = np.zeros(n, dtype=np.int64)
        self.env_steps = 0
        self.calls = 0
        self.gradient_steps = 0
        self.epsilon_multiplied = config.epsilon_start
        self.last_loss = float("nan")
        self.last_q_mean = float("nan")
        self.uses_dropout = config.dropout > 0

    # -- acting ----------------------------------------------------------------------------

    @property
    def epsilon(self) -> float:
        return epsilon_at(self.config, self.env_steps, self.epsilon_multiplied)

    def select_actions(self, observations: np.ndarray, epsilon: float) -> np.ndarray:
        """Epsilon-greedy actions for all envs with a single forward pass (skipped if all explore)."""
        n = len(observations)
        explore = self.rng.random(n) < epsilon
        actions = self.rng.integers(0, self.env_info.n_actions, size=n)
        if not explore.all():
            actions = np.where(explore, actions, self.q_net.q_values(observations).argmax(axis=1))
        return actions

    # -- one learn() call --------------------------------------------------------------------

    def learn(self) -> LearnResult:
        config = self.config
        epsilon = self.epsilon
        observations = self.observations
        actions = self.select_actions(observations, epsilon)
        next_observations, rewards, terminated, truncated, _ = self.envs.step(actions)

        # Gymnasium's next-step autoreset: an env that ended an episode at the last call has just
        # been reset (its action was ignored). That row is not a transition; drop it.
        valid = ~self.autoreset
        self.episode_returns += np.where(valid, rewards, 0.0)
        self.episode_lengths += valid
        done = (terminated | truncated) & valid
        stored_rewards = self.shape_rewards(rewards, terminated & valid, done)
        # Only `terminated` is stored as the no-bootstrap flag. At truncation (the time limit) the
        # step returns the real final observation (the reset comes on the next call), so the target
        # bootstraps from that state's value: the pole was still up.
        self.buffer.add(
            observations[valid],
            actions[valid],
            stored_rewards[valid],
            next_observations[valid],
            terminated[valid].astype(np.float32),
        )
        collected = int(valid.sum())
        self.env_steps += collected
        result = LearnResult(env_steps=collected)
        for i in np.flatnonzero(done):  # raw env returns, before any reward shaping
            result.episode_returns.append(float(self.episode_returns[i]))
            result.episode_lengths.append(int(self.episode_lengths[i]))
            self.episode_returns[i] = 0.0
            self.episode_lengths[i] = 0
        self.autoreset = done
        self.observations = next_observations

        self.calls += 1
        if self.calls % config.train_freq == 0 and self.env_steps >= config.learning_starts:
            loss = q = None
            for _ in range(config.gradient_steps):
                loss, q = self.gradient_step()
            if loss is not None and q is not None:  # one device sync per training round, not per step
                self.last_loss, self.last_q_mean = float(loss), float(q.mean())
        result.scalars = {"train/epsilon": epsilon, "train/gradient_steps": float(self.gradient_steps)}
        if self.gradient_steps:  # no loss before the first update (and metrics hold no NaN)
            result.scalars |= {"train/loss": self.last_loss, "train/q_mean": self.last_q_mean}
        return result

    def shape_rewards(self, rewards: np.ndarray, terminated: np.ndarray, done: np.ndarray) -> np.ndarray:
        return shaped_rewards(self.config, rewards, terminated, done, self.episode_lengths)

    # -- one gradient step -----------------------------------------------------------------------

    def gradient_step(self) -> tuple[torch.Tensor, torch.Tensor]:
        """One update of the online net; returns its loss and Q-values (tensors: no sync here)."""
        config = self.config
        batch = self.buffer.sample(min(config.batch_size, len(self.buffer)), self.replay_generator)
        if self.uses_dropout:  # dropout only while fitting; acting and the targets run without it
            q_all = self.q_net.train()(batch.observations)
            self.q_net.eval()
        else:  # (switching modes walks every module: skipped when it changes nothing)
            q_all = self.q_net(batch.observations)
        with torch.no_grad():
            # Without a target network the online net (without dropout) values s', as the tutorials do.
            target_net = self.target_net if self.target_net is not None else self.q_net
            next_q_target = target_net(batch.next_observations)
            next_q_online = None
            if config.double_dqn:
                same = self.target_net is None
                next_q_online = next_q_target if same else self.q_net(batch.next_observations)
            targets = td_targets(batch.rewards, batch.terminated, next_q_target, next_q_online, config.gamma)
        q = q_all.gather(1, batch.actions.unsqueeze(1)).squeeze(1)
        loss = F.smooth_l1_loss(q, targets) if config.loss == "huber" else F.mse_loss(q, targets)
        self.optimizer.zero_grad()
        loss.backward()
        if config.max_grad_norm is not None:
            nn.utils.clip_grad_norm_(self.parameters, config.max_grad_norm)
        self.optimizer.step()
        self.gradient_steps += 1
        if self.target_net is not None and self.gradient_steps % config.target_update_interval == 0:
            self.update_target()
        if config.epsilon_schedule == "multiplicative" and self.epsilon_multiplied > config.epsilon_end:
            self.epsilon_multiplied = max(
                config.epsilon_end, self.epsilon_multiplied * config.epsilon_decay_rate
            )
        return loss.detach(), q.detach()

    @torch.no_grad()
    def update_target(self) -> None:
        """Polyak update: target <- target + tau * (online - target); a copy when tau is 1."""
        for target, online in zip(self.target_parameters, self.parameters, strict=True):
            if self.config.tau >= 1.0:
                target.copy_(online)
            else:
                target.lerp_(online, self.config.tau)

    # -- policy and checkpoints ---------------------------------------------------------------

    def policy(self) -> QNetworkPolicy:
        """A frozen copy of the current greedy policy."""
        return QNetworkPolicy(self.q_net)

    def state_dict(self, resume: bool) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
        """The weights (always); with ``resume`` everything a resume needs to continue exactly: target
        net, Adam, replay rows, the learner's random streams, its counters and the envs' episodes in
        progress (see :mod:`cartpole.envs.resumable_envs` for exactly what of the envs is kept)."""
        tensors = prefixed("q_net.", self.q_net.state_dict())
        data: dict[str, Any] = {"obs_dim": self.env_info.obs_dim, "n_actions": self.env_info.n_actions}
        if not resume:
            return tensors, data
        if self.target_net is not None:
            tensors |= prefixed("target_net.", self.target_net.state_dict())
        optim_tensors, optim_data = self.optimizer.state_dict()
        replay_tensors, replay_data = self.buffer.state_dict()
        tensors |= prefixed("optim.", optim_tensors) | prefixed("replay.", replay_tensors)
        tensors["rng.dropout"] = self.dropout_generator.get_state()
        tensors["rng.replay"] = self.replay_generator.get_state()
        tensors["envs.observations"] = torch.from_numpy(np.asarray(self.observations, dtype=np.float32))
        data |= {
            "optim": optim_data,
            "replay": replay_data,
            "rng_numpy": self.rng.bit_generator.state,
            "env_steps": self.env_steps,
            "calls": self.calls,
            "gradient_steps": self.gradient_steps,
            "epsilon_multiplied": self.epsilon_multiplied,
            "autoreset": self.autoreset.tolist(),
            "episode_returns": self.episode_returns.tolist(),
            "episode_lengths": self.episode_lengths.tolist(),
            "env_state": vector_env_state(self.envs),
        }
        return tensors, data

    def load_state_dict(self, tensors: dict[str, torch.Tensor], data: dict[str, Any]) -> None:
        """Restore what ``state_dict`` gave; touches only this learner (and its envs)."""
        self.q_net.load_state_dict(unprefixed("q_net.", tensors))
        if "env_steps" not in data:  # a policy-only checkpoint: weights only
            if self.target_net is not None:
                self.target_net.load_state_dict(self.q_net.state_dict())
            return
        if self.target_net is not None:
            self.target_net.load_state_dict(unprefixed("target_net.", tensors))
        self.optimizer.load_state_dict(unprefixed("optim.", tensors))
        self.buffer.load_state_dict(unprefixed("replay.", tensors), data["replay"])
        if "rng.dropout" in tensors:  # absent from checkpoints written before the learner owned it
            self.dropout_generator.set_state(tensors["rng.dropout"])
        if "rng.replay" in tensors:
            self.replay_generator.set_state(tensors["rng.replay"])
        self.rng.bit_generator.state = data["rng_numpy"]
        self.env_steps, self.calls = int(data["env_steps"]), int(data["calls"])
        self.gradient_steps = int(data["gradient_steps"])
        self.epsilon_multiplied = float(data["epsilon_multiplied"])
        self.autoreset = np.asarray(data["autoreset"], dtype=bool)
        self.episode_returns = np.asarray(data["episode_returns"], dtype=np.float64)
        self.episode_lengths = np.asarray(data["episode_lengths"], dtype=np.int64)
        saved_envs = data.get("env_state")
        if restore_vector_env_state(self.envs, saved_envs, self.episode_lengths, self.autoreset):
            self.observations = tensors["envs.observations"].numpy().copy()
        else:
            # The envs' state could not be saved (see resumable_envs): start fresh episodes from a
            # seed derived from the run's seed and progress (deterministic), dropping those in progress.
            seed = int(np.random.SeedSequence([self.seed, self.env_steps]).generate_state(1)[0])
            self.observations, _ = self.envs.reset(seed=seed)
            self.autoreset[:] = False
            self.episode_returns[:] = 0.0
            self.episode_lengths[:] = 0


def prefixed(prefix: str, tensors: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    return {prefix + k: v for k, v in tensors.items()}


def unprefixed(prefix: str, tensors: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    return {k.removeprefix(prefix): v for k, v in tensors.items() if k.startswith(prefix)}


# ----------------------------------------------------------------------------------------------
# 4. The greedy policy from a checkpoint
# ----------------------------------------------------------------------------------------------


def policy_from_checkpoint(checkpoint: Checkpoint) -> QNetworkPolicy:
    """Rebuild the greedy policy on CPU from a checkpoint's tensors."""
    try:
        known = {f.name for f in dataclasses.fields(DQNConfig)}  # older checkpoints hold retired settings
        config = build_config(DQNConfig, {k: v for k, v in checkpoint.meta["config"].items() if k in known})
        data = checkpoint.meta["learner"]
        q_net = QNetwork(int(data["obs_dim"]), int(data["n_actions"]), config)
        q_net.load_state_dict(unprefixed("q_net.", checkpoint.tensors))
    except (KeyError, RuntimeError, TypeError, AttributeError) as err:
        raise CheckpointError(f"not a usable dqn checkpoint: {err!s:.120}") from err
    return QNetworkPolicy(q_net)


__all__ = [
    "DQNConfig",
    "DQNLearner",
    "QNetwork",
    "QNetworkPolicy",
    "epsilon_at",
    "policy_from_checkpoint",
    "td_targets",
]
