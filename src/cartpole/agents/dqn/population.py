"""What DQN's learning rule (:mod:`cartpole.agents.dqn.dqn`) runs on, batched over seeds:
:class:`QLearningPopulation`, every seed's Q-networks, replay memory, envs, generators and counters,
how the seeds act and how each one is checkpointed.

Every seed is its own training run: its own Q-network (initialized from its ``init`` generator),
target network, optimizer state and replay memory, its own ``num_envs`` envs seeded as its run seeds
them, and its own random streams (exploration from ``derived_seed(seed, "explore")``, replay sampling
from ``"replay"``, dropout masks from ``"dropout"``). What is shared is only the arithmetic, along a
leading seed axis: the networks (:class:`~cartpole.agents.dqn.stacked.StackedQNetwork`), the replay
memories (:class:`~cartpole.agents.dqn.replay.StackedReplay`), the envs
(:class:`~cartpole.agents.episodes.SeedEpisodes`: on CartPole's fast simulator all S x ``num_envs``
step in one call) and the optimizer (:mod:`cartpole.agents.nn.population_optimizers`: every seed's
Adam or RMSprop in one pass). Shapes never depend on the other seeds, and a seed that sits a step
out keeps its generators untouched, so seed N trains bit for bit the same alone and among others
(``tests/test_one_engine.py``; why the arithmetic allows it: :mod:`cartpole.agents.dqn.stacked`).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
import torch

from cartpole.agents.dqn.config import DQNConfig
from cartpole.agents.dqn.n_step import NStepWindows, n_step_window_bytes
from cartpole.agents.dqn.q_network import (
    ACTIVATIONS,
    QNetwork,
    QNetworkPolicy,
    network_input_shape,
    q_network_parameters,
    q_values_from,
)
from cartpole.agents.dqn.replay import StackedReplay, replay_bytes
from cartpole.agents.dqn.stacked import StackedQNetwork, padded
from cartpole.agents.episodes import EnvStep, SeedEpisodes
from cartpole.agents.learner import LearnResult
from cartpole.agents.nn.conv import conv_activations
from cartpole.agents.nn.flat_parameters import on_the_cpu, to_device
from cartpole.agents.nn.numpy_mlp import NUMPY_ACTIVATIONS, StackedGreedyActor, StackedNumpyMLP, Step
from cartpole.agents.nn.population_optimizers import population_optimizer
from cartpole.agents.nn.stacked_linear import TORCH_ACTIVATIONS
from cartpole.agents.population import staying_rows
from cartpole.agents.seed_state import (
    SeedState,
    nan_if_none,
    none_if_nan,
    require_training_state,
    unprefixed,
    with_training_state,
)
from cartpole.core.config import build_config
from cartpole.core.errors import ConfigError
from cartpole.core.seeding import derived_seed
from cartpole.envs import EnvInfo
from cartpole.envs.seed_envs import rows_of_envs
from cartpole.evaluation import BlockActor
from cartpole.runs import Checkpoint, CheckpointError


def seeded_q_network(config: DQNConfig, env: EnvInfo, seed: int) -> QNetwork:
    """Seed ``seed``'s initial Q-network on the CPU, from its own ``init`` generator."""
    with on_the_cpu():
        generator = torch.Generator(device="cpu").manual_seed(derived_seed(seed, "init"))
        return QNetwork(env.obs_shape, env.n_actions, config, generator).eval()


class QLearningPopulation:
    """The Q-learners of seeds ``seeds``, all with ``config``: their stacked networks, optimizer,
    replay memories, envs, generators and counters; their epsilon-greedy acting; each seed's policy
    and checkpoint. DQN's learning rule (:class:`~cartpole.agents.dqn.dqn.PopulationDQN`) adds what
    one ``learn()`` does."""

    def __init__(self, config: DQNConfig, env: EnvInfo, seeds: list[int], device: str = "cpu"):
        config.validate()
        config.check_env(env)
        if not seeds:
            raise ConfigError("a population needs at least one seed")
        self.config, self.env_info = config, env
        self.device = torch.device(device)
        """Where the networks, the replay memories and the updates live. The envs step on the CPU
        (numpy) and every random draw comes from a seed's own CPU generator, so a seed's draws are the
        same on any device."""
        self.seeds = list(seeds)
        """The seed of each row of every batch."""
        self.activation = TORCH_ACTIVATIONS[ACTIVATIONS[config.activation]]
        self.net = StackedQNetwork(
            [seeded_q_network(config, env, s) for s in self.seeds], config.target_network, self.device
        )
        width = self.net.flat.shape[1]
        self.optimizer = population_optimizer(config.optimizer, len(self.seeds), width, self.device)
        self.replay = StackedReplay(
            len(self.seeds), config.buffer_size, env.obs_shape, self.device, config.num_envs, config.n_step
        )
        self.explore_rngs = [np.random.default_rng(derived_seed(s, "explore")) for s in self.seeds]
        self.replay_generators = [self.cpu_generator(derived_seed(s, "replay")) for s in self.seeds]
        self.dropout_generators = [self.cpu_generator(derived_seed(s, "dropout")) for s in self.seeds]
        self.episodes = SeedEpisodes(env, config.simulator, self.seeds, config.num_envs)
        self.windows: NStepWindows | None = None
        """Each env's transitions not yet stored, with n-step returns (None: one-step rows)."""
        if config.n_step > 1:
            envs, dtype = len(self.seeds) * config.num_envs, self.episodes.observations.dtype
            self.windows = NStepWindows(
                envs, config.num_envs, config.n_step, config.gamma, env.obs_shape, dtype
            )
        rows = len(self.seeds)
        self.env_steps = np.zeros(rows, dtype=np.int64)
        self.calls = np.zeros(rows, dtype=np.int64)
        self.gradient_steps = np.zeros(rows, dtype=np.int64)
        self.epsilon_multiplied = np.full(rows, config.epsilon_start, dtype=np.float64)
        self.last_loss = np.full(rows, math.nan)
        self.last_q_mean = np.full(rows, math.nan)
        self.greedy: np.ndarray | None = None
        """The greedy actions [S, num_envs] for ``observations`` under the current weights, computed
        at the end of the last ``learn()`` (read back with its metrics: one device sync a call)."""
        self.acting_rows = padded(config.num_envs)
        self.acting_networks: list[StackedNumpyMLP] | None = None
        """:meth:`numpy_q_values`'s NumPy views of the online weights (which the updates change in
        place), made on first use and again after seeds leave."""

    @staticmethod
    def cpu_generator(seed: int) -> torch.Generator:
        return torch.Generator(device="cpu").manual_seed(seed)

    @property
    def active_seeds(self) -> list[int]:
        return list(self.seeds)

    def remove(self, seeds: list[int]) -> None:
        """Stop training ``seeds``: they leave every batch."""
        rows_np = staying_rows(self.seeds, seeds)
        self.seeds = [self.seeds[i] for i in rows_np]
        envs = rows_of_envs(rows_np, self.config.num_envs)
        rows = torch.from_numpy(rows_np).to(self.device)
        self.net.keep(rows)
        self.acting_networks = None
        self.optimizer.keep(rows)
        self.replay.keep(rows_np)
        self.episodes.keep(rows_np, envs)
        if self.windows is not None:
            self.windows.keep(envs)
        self.explore_rngs = [self.explore_rngs[i] for i in rows_np]
        self.replay_generators = [self.replay_generators[i] for i in rows_np]
        self.dropout_generators = [self.dropout_generators[i] for i in rows_np]
        for name in (
            "env_steps",
            "calls",
            "gradient_steps",
            "epsilon_multiplied",
            "last_loss",
            "last_q_mean",
        ):
            setattr(self, name, getattr(self, name)[rows_np])
        if self.greedy is not None:
            self.greedy = self.greedy[rows_np]

    # -- acting, storing, reporting -----------------------------------------------------------------

    def select_actions(self, epsilons: list[float]) -> np.ndarray:
        """Epsilon-greedy actions of all envs: each seed's exploration draws from its own generator
        (its draws are its own whoever shares the batch), the greedy actions from one forward pass for
        all seeds."""
        n, n_actions = self.config.num_envs, self.env_info.n_actions
        greedy = self.greedy if self.greedy is not None else self.greedy_actions()
        explore = np.empty((len(self.seeds), n), dtype=bool)
        random = np.empty((len(self.seeds), n), dtype=np.int64)
        for row, rng in enumerate(self.explore_rngs):
            explore[row] = rng.random(n) < epsilons[row]
            random[row] = rng.integers(0, n_actions, size=n)
        self.greedy = None
        return np.where(explore, random, greedy).reshape(-1)

    @torch.no_grad()
    def greedy_q_argmax(self) -> torch.Tensor:
        """The online networks' greedy actions [S, num_envs] for ``observations`` (on the device)."""
        seeds, n, obs_shape = len(self.seeds), self.config.num_envs, self.env_info.obs_shape
        dtype = torch.uint8 if self.env_info.is_image else torch.float32  # pixels stay uint8
        x = torch.zeros(seeds, self.acting_rows, *obs_shape, dtype=dtype, device="cpu")
        x[:, :n] = torch.from_numpy(self.episodes.observations).view(seeds, n, *obs_shape)
        q = self.net.forward(self.net.params, to_device(x, self.device), self.activation)
        return q[:, :n].argmax(dim=2)

    def greedy_actions(self) -> np.ndarray:
        """The online networks' greedy actions [S, num_envs] for ``observations``: on the CPU through
        NumPy views of the weights (:meth:`numpy_q_values`); an image network through torch."""
        if self.device.type == "cpu" and not self.env_info.is_image:
            n, obs_dim = self.config.num_envs, self.env_info.obs_dim
            return self.numpy_q_values(self.episodes.observations.reshape(-1, n, obs_dim)).argmax(axis=2)
        return self.greedy_q_argmax().cpu().numpy()

    def numpy_q_values(self, x: np.ndarray) -> np.ndarray:
        """Q-values ``[S, B, n_actions]`` of ``x`` [S, B, obs_dim] as :meth:`StackedQNetwork.forward`
        computes them, in NumPy on views of the online weights (CPU only), in the fixed order of
        :func:`~cartpole.agents.nn.fixed_order.matmul_arrays` (which lays each view's rows out
        once a call), so a seed's actions do not depend on its neighbours."""
        if self.acting_networks is None:
            self.acting_networks = self.numpy_networks(None, copy=False)
        return q_values_from(self.acting_networks, x)

    def numpy_networks(self, rows: list[int] | None, copy: bool) -> list[StackedNumpyMLP]:
        """The online networks of ``rows`` (None: all) as NumPy stacks: the body, the head and (dueling)
        the value head (:func:`~cartpole.agents.dqn.q_network.q_values_from`); views of the weights
        (CPU, ``rows`` None) unless ``copy``."""
        net = self.net
        activation = NUMPY_ACTIVATIONS[ACTIVATIONS[self.config.activation]]
        body: list[Step] = []
        for weight, bias in net.hidden:
            body += [net.numpy_linear(weight, bias, rows, copy), activation]
        heads = ["head", "value"] if net.dueling else ["head"]
        linear = [net.numpy_linear(f"{head}.weight", f"{head}.bias", rows, copy) for head in heads]
        return [StackedNumpyMLP(body)] + [StackedNumpyMLP([step]) for step in linear]

    def store(self, step: EnvStep, actions: np.ndarray, rewards: np.ndarray) -> None:
        """Put the transitions of ``step`` (taken with ``actions``, their ``rewards`` as stored) into
        their seeds' replay memories: as they are, or, with n-step returns, the rows their windows
        complete. An autoreset step is no transition: dropped."""
        seeds, n = len(self.seeds), self.config.num_envs
        valid, terminated = step.valid, step.terminated
        terminal = terminated.astype(np.float32)
        fields = [step.observations, actions, rewards, step.next_observations, terminal]
        if self.windows is None:
            self.replay.add(valid.reshape(seeds, n), fields)
            return
        rows = self.windows.step(
            valid, step.observations, actions, rewards, step.next_observations, terminated, step.truncated
        )
        for emitted, row_fields in rows:
            self.replay.add(emitted.reshape(seeds, n), row_fields)

    def read_back(self, metrics: torch.Tensor | None, training: np.ndarray) -> None:
        """This call's metrics ([S, 2]: loss, Q mean) and, off the CPU, the next call's greedy
        actions, fetched from the device together (one sync a call)."""
        parts, greedy = [], None
        if self.device.type != "cpu":
            greedy = self.greedy_q_argmax()
            parts.append(greedy.view(-1).to(torch.float64))
        if metrics is not None:
            parts.append(metrics.view(-1).to(torch.float64))
        if not parts:
            return
        values = torch.cat(parts).cpu().numpy()
        if greedy is not None:
            self.greedy = values[: greedy.numel()].astype(np.int64).reshape(greedy.shape)
            values = values[greedy.numel() :]
        if metrics is not None:
            losses, q_means = values.reshape(-1, 2).T
            self.last_loss = np.where(training, losses, self.last_loss)
            self.last_q_mean = np.where(training, q_means, self.last_q_mean)

    def results(
        self, collected: np.ndarray, finished: list[tuple[list[float], list[int]]], epsilons: list[float]
    ) -> dict[int, LearnResult]:
        results = {}
        for row, seed in enumerate(self.seeds):
            returns, lengths = finished[row]
            result = LearnResult(
                env_steps=int(collected[row]), episode_returns=returns, episode_lengths=lengths
            )
            steps = int(self.gradient_steps[row])
            result.scalars = {"train/epsilon": epsilons[row], "train/gradient_steps": float(steps)}
            if steps:  # no loss before the first update (and metrics hold no NaN)
                result.scalars |= {
                    "train/loss": float(self.last_loss[row]),
                    "train/q_mean": float(self.last_q_mean[row]),
                }
            results[seed] = result
        return results

    # -- each seed's policy and checkpoint ----------------------------------------------------------

    def seed_policy(self, seed: int) -> QNetworkPolicy:
        """Seed ``seed``'s greedy policy (a frozen copy)."""
        return QNetworkPolicy(self.net.unstack(self.seeds.index(seed)))

    def greedy_actor(self, seeds: list[int]) -> BlockActor:
        """The greedy policies of ``seeds`` as one :data:`~cartpole.evaluation.BlockActor` (block i
        holds seed i's rows): one stacked NumPy forward pass per call, as
        :class:`~cartpole.agents.dqn.q_network.QNetworkPolicy` acts alone (through torch for image
        networks)."""
        if self.env_info.is_image:
            return self.torch_block_actor([self.seeds.index(seed) for seed in seeds])
        networks = self.numpy_networks([self.seeds.index(seed) for seed in seeds], copy=True)
        chain = None if self.net.dueling else networks[0].then(networks[1])  # body, then head
        return StackedGreedyActor(networks, self.env_info.obs_dim, q_values_from, argmax_of=chain)

    def torch_block_actor(self, rows: list[int]) -> BlockActor:
        """The greedy actions of the online networks of ``rows`` as one :data:`BlockActor`, through
        torch: for image networks (no NumPy twin)."""
        return self.net.block_actor(
            rows, self.env_info.obs_shape, lambda params, x: self.net.forward(params, x, self.activation)
        )

    def seed_state_dict(self, seed: int, resume: bool) -> SeedState:
        """Seed ``seed``'s checkpoint: ``q_net.*`` (what :func:`policy_from_checkpoint` reads) and,
        with ``resume``, everything to continue exactly: target, optimizer, replay rows, n-step
        windows, generators, counters and envs."""
        row, env = self.seeds.index(seed), self.env_info
        data: dict[str, Any] = {"obs_dim": env.obs_dim, "n_actions": env.n_actions}
        if env.is_image:
            data["obs_shape"] = list(env.obs_shape)
        policy = (self.net.row_state_dict(row, "q_net."), data)
        if not resume:
            return policy
        target = (
            {} if self.net.target is None else self.net.row_state_dict(row, "target_net.", self.net.target)
        )
        optim_tensors, optim_data = self.optimizer.row_state(row)
        optimizer = {k: v[: self.net.size].clone() for k, v in optim_tensors.items()}  # without the padding
        replay_tensors, replay_data = self.replay.row_state(row)
        replay = {f"replay.{k}": v for k, v in replay_tensors.items()}
        generators = {
            "rng.dropout": self.dropout_generators[row].get_state(),
            "rng.replay": self.replay_generators[row].get_state(),
        }
        counters = {
            "replay": replay_data,
            "rng_numpy": self.explore_rngs[row].bit_generator.state,
            "env_steps": int(self.env_steps[row]),
            "calls": int(self.calls[row]),
            "gradient_steps": int(self.gradient_steps[row]),
            "epsilon_multiplied": float(self.epsilon_multiplied[row]),
            "last_loss": none_if_nan(float(self.last_loss[row])),
            "last_q_mean": none_if_nan(float(self.last_q_mean[row])),
        }
        windows = ({}, {}) if self.windows is None else self.windows.seed_state(row)
        return with_training_state(
            policy,
            (target | optimizer | replay | generators, optim_data | counters),
            self.episodes.seed_state(row),
            windows,
        )

    def load_seed_state_dict(self, seed: int, tensors: dict[str, torch.Tensor], data: dict[str, Any]) -> None:
        """Restore what ``seed_state_dict(seed, resume=True)`` gave."""
        require_training_state(data)
        row = self.seeds.index(seed)
        self.net.load_row(row, unprefixed(tensors, "q_net."))
        if self.net.target is not None:
            self.net.load_row(row, unprefixed(tensors, "target_net."), self.net.target)
        width = self.net.flat.shape[1]
        optim = {
            k: torch.cat([v, v.new_zeros(width - len(v))]) for k, v in unprefixed(tensors, "optim.").items()
        }
        self.optimizer.load_row_state(row, {f"optim.{k}": v for k, v in optim.items()}, data)
        self.replay.load_row_state(row, unprefixed(tensors, "replay."), data["replay"])
        self.dropout_generators[row].set_state(tensors["rng.dropout"])
        self.replay_generators[row].set_state(tensors["rng.replay"])
        self.explore_rngs[row].bit_generator.state = data["rng_numpy"]
        self.env_steps[row], self.calls[row] = int(data["env_steps"]), int(data["calls"])
        self.gradient_steps[row] = int(data["gradient_steps"])
        self.epsilon_multiplied[row] = float(data["epsilon_multiplied"])
        self.last_loss[row] = nan_if_none(data.get("last_loss"))
        self.last_q_mean[row] = nan_if_none(data.get("last_q_mean"))
        self.episodes.load_seed_state(row, tensors, data)
        if self.windows is not None:
            self.windows.load_seed_state(row, tensors, data)
        self.greedy = None  # the row's weights and observations changed


def policy_from_checkpoint(checkpoint: Checkpoint) -> QNetworkPolicy:
    """Rebuild the greedy policy on CPU from a checkpoint's tensors (``q_net.*``)."""
    return QNetworkPolicy(q_network_from_checkpoint(checkpoint))


def q_network_from_checkpoint(checkpoint: Checkpoint) -> QNetwork:
    """The Q-network a checkpoint holds (``q_net.*``), on CPU, in eval mode (no dropout), frozen:
    its greedy policy's Q-values, computed by torch."""
    try:
        known = {f.name for f in dataclasses.fields(DQNConfig)}  # older checkpoints hold retired settings
        config = build_config(DQNConfig, {k: v for k, v in checkpoint.meta["config"].items() if k in known})
        data = checkpoint.meta["learner"]
        obs_shape = [int(n) for n in data.get("obs_shape", [data["obs_dim"]])]
        q_net = QNetwork(obs_shape, int(data["n_actions"]), config)
        q_net.load_state_dict(unprefixed(checkpoint.tensors, "q_net."))
    except (KeyError, RuntimeError, TypeError, AttributeError) as err:
        raise CheckpointError(f"not a usable dqn checkpoint: {err!s:.120}") from err
    return q_net.requires_grad_(False).eval()


def dqn_bytes_per_seed(config: DQNConfig, env: EnvInfo) -> int:
    """What one seed of a DQN population holds, roughly: its replay rows and n-step windows, its
    parameters five times (online, target, gradient, Adam's two moments), a minibatch's activations
    (the online pass with its gradients, the target and online passes over the next states, dropout
    masks) and the per-seed bookkeeping (run folder, callbacks). Image networks' activations include
    the scaled pixels and every convolutional layer's output."""
    config.check_env(env)  # settings that cannot fit the env's images: one line, not an estimate
    parameters = padded(q_network_parameters(config, env)) * 4 * 5
    rows = padded(config.batch_size)
    inputs = 2 * env.obs_dim
    if env.is_image:
        shown = network_input_shape(env.obs_shape, config.frame_difference)
        inputs = env.obs_dim + math.prod(shown) + conv_activations(shown, config.conv_layers)
    activations = rows * (sum(config.hidden_sizes) + env.n_actions + inputs + 8) * 4 * 8
    bookkeeping = 2 * 1024**2
    held = replay_bytes(config, env) + n_step_window_bytes(config, env)
    return held + parameters + activations + bookkeeping


__all__ = [
    "QLearningPopulation",
    "dqn_bytes_per_seed",
    "policy_from_checkpoint",
    "q_network_from_checkpoint",
    "seeded_q_network",
]
