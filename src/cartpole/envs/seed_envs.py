"""Every seed's own vector env, stepped as one: what a population of seeds trains on.

A population of S seeds with ``num_envs`` envs each sees one [S * num_envs, ...] batch, seed s owning
rows ``s * num_envs`` to ``(s + 1) * num_envs - 1``. Each seed's envs are those its own run would
make: seeded by ``reset(seed=seed)``, with Gymnasium's next-step autoreset. Two forms, one interface
(:class:`SeedEnvs`), picked by :func:`make_seed_envs`:

- :class:`FastSeedEnvs`: CartPole on our fast simulator, all S x N envs stepped by one call of its
  kernel (:func:`~cartpole.envs.fast.step_cartpole_columns`); each seed's start states come from its own
  ``np_random(seed)`` in Gymnasium's order, so they are the start states its vector env would draw.
- :class:`GymnasiumSeedEnvs`: any other env or simulator (Acrobot, MountainCar, Gymnasium's own
  CartPole for the tutorial presets): one resumable Gymnasium vector env per seed
  (:func:`~cartpole.envs.resumable_envs.make_resumable_vec_env`), stepped in turn.

Both count each env's steps and pending autoresets themselves, so a seed's envs can be saved to a
checkpoint and put back mid-episode (``seed_state`` / ``load_seed_state``).
"""

from __future__ import annotations

from typing import Any, Protocol

import gymnasium as gym
import numpy as np
from gymnasium.utils.seeding import np_random

from cartpole.envs import EnvInfo, resolve_simulator
from cartpole.envs.fast import DEFAULT_RESET_HIGH, DEFAULT_RESET_LOW, step_cartpole_columns
from cartpole.envs.resumable_envs import make_resumable_vec_env, restore_vector_env_state, vector_env_state

LONGEST_EPISODE_WITHOUT_TIME_LIMIT = 10_000
"""Where an env without a time limit of its own has its episodes cut (REINFORCE waits for them)."""

Step = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]
"""(observations, rewards, terminated, truncated) of all S x N envs."""


class SeedEnvs(Protocol):
    """S seeds' vector envs of ``num_envs`` envs each, as one batch."""

    num_envs: int

    def observations(self) -> np.ndarray:
        """The current observations [S * N, obs_dim] (float32)."""
        ...

    def step(self, actions: np.ndarray) -> Step:
        """Step every env with ``actions`` [S * N]; an env whose last step ended its episode is
        reset instead (reward 0, neither terminated nor truncated)."""
        ...

    def restart(self, row: int, seed: int) -> None:
        """Fresh episodes for the envs of row ``row``, as ``reset(seed=seed)`` starts them."""
        ...

    def keep(self, seed_rows: np.ndarray) -> None:
        """Keep only the seeds at ``seed_rows``, in that order."""
        ...

    def seed_state(self, row: int) -> dict[str, Any]:
        """Row ``row``'s envs as plain data, for a checkpoint."""
        ...

    def load_seed_state(self, row: int, data: dict[str, Any]) -> None:
        """Put row ``row``'s envs back where ``seed_state`` found them."""
        ...


def make_seed_envs(env: EnvInfo, simulator: str, seeds: list[int], num_envs: int) -> SeedEnvs:
    """``num_envs`` envs of ``env`` for each seed of ``seeds``, on ``simulator`` where it runs that env."""
    limit = env.max_episode_steps or LONGEST_EPISODE_WITHOUT_TIME_LIMIT
    if resolve_simulator(env.env_id, simulator) == "fast":
        return FastSeedEnvs(seeds, num_envs, limit)
    return GymnasiumSeedEnvs(env.env_id, seeds, num_envs)


def env_rows(row: int, num_envs: int) -> slice:
    """The rows of seed row ``row``'s envs in the batch."""
    return slice(row * num_envs, (row + 1) * num_envs)


def rows_of_envs(seed_rows: np.ndarray, num_envs: int) -> np.ndarray:
    """The batch rows of the envs of seed rows ``seed_rows``, in that order."""
    return (seed_rows[:, None] * num_envs + np.arange(num_envs)).reshape(-1)


class FastSeedEnvs:
    """S x N CartPoles of the fast simulator, stepped by one kernel call; their states are kept as
    the kernel's ``(4, S * N)`` columns."""

    def __init__(self, seeds: list[int], num_envs: int, max_episode_steps: int):
        self.num_envs, self.max_episode_steps = num_envs, max_episode_steps
        self.rngs = [np_random(seed)[0] for seed in seeds]
        draws = [rng.uniform(DEFAULT_RESET_LOW, DEFAULT_RESET_HIGH, size=(4, num_envs)) for rng in self.rngs]
        self.columns = np.concatenate(draws, axis=1).astype(np.float32)  # [4, S * N]
        n = self.columns.shape[1]
        self.steps = np.zeros(n, dtype=np.int64)
        self.pending = np.zeros(n, dtype=bool)
        """Envs whose episode ended on the last step: the next step resets them."""

    def observations(self) -> np.ndarray:
        return self.columns.T.copy()  # a new array: the columns step in place

    def step(self, actions: np.ndarray) -> Step:
        terminated = step_cartpole_columns(self.columns, actions.astype(np.int64, copy=False))
        self.steps += 1
        truncated = self.steps >= self.max_episode_steps
        rewards = np.ones(len(self.steps), dtype=np.float32)
        if self.pending.any():
            resets = np.flatnonzero(self.pending)
            owners = resets // self.num_envs
            for owner in np.unique(owners):
                mine = resets[owners == owner]
                draws = self.rngs[owner].uniform(DEFAULT_RESET_LOW, DEFAULT_RESET_HIGH, size=(4, len(mine)))
                self.columns[:, mine] = draws.astype(np.float32)
            self.steps[resets] = 0
            rewards[resets] = 0.0
            terminated[resets] = False
            truncated[resets] = False
        self.pending = terminated | truncated
        return self.observations(), rewards, terminated, truncated

    def restart(self, row: int, seed: int) -> None:
        envs = env_rows(row, self.num_envs)
        self.rngs[row] = np_random(seed)[0]
        draws = self.rngs[row].uniform(DEFAULT_RESET_LOW, DEFAULT_RESET_HIGH, size=(4, self.num_envs))
        self.columns[:, envs] = draws.astype(np.float32)
        self.steps[envs] = 0
        self.pending[envs] = False

    def keep(self, seed_rows: np.ndarray) -> None:
        envs = rows_of_envs(seed_rows, self.num_envs)
        self.rngs = [self.rngs[i] for i in seed_rows]
        self.columns = np.ascontiguousarray(self.columns[:, envs])
        self.steps, self.pending = self.steps[envs], self.pending[envs]

    def seed_state(self, row: int) -> dict[str, Any]:
        envs = env_rows(row, self.num_envs)
        return {
            "state": self.columns[:, envs].T.tolist(),
            "steps": self.steps[envs].tolist(),
            "pending": self.pending[envs].tolist(),
            "np_random": self.rngs[row].bit_generator.state,
        }

    def load_seed_state(self, row: int, data: dict[str, Any]) -> None:
        envs = env_rows(row, self.num_envs)
        self.columns[:, envs] = np.asarray(data["state"], dtype=np.float32).T
        self.steps[envs] = data["steps"]
        self.pending[envs] = data["pending"]
        self.rngs[row].bit_generator.state = data["np_random"]


class GymnasiumSeedEnvs:
    """One Gymnasium vector env per seed (any env with Box observations), stepped in turn."""

    def __init__(self, env_id: str, seeds: list[int], num_envs: int):
        self.num_envs = num_envs
        self.envs: list[gym.vector.VectorEnv] = []
        self.current: list[np.ndarray] = []
        for seed in seeds:
            envs = make_resumable_vec_env(env_id, num_envs, "gymnasium")
            self.envs.append(envs)
            self.current.append(np.asarray(envs.reset(seed=seed)[0], dtype=np.float32))
        n = len(seeds) * num_envs
        self.steps = np.zeros(n, dtype=np.int64)
        self.pending = np.zeros(n, dtype=bool)

    def observations(self) -> np.ndarray:
        return np.concatenate(self.current)

    def step(self, actions: np.ndarray) -> Step:
        rewards, terminated, truncated = [], [], []
        for row, envs in enumerate(self.envs):
            mine = actions[env_rows(row, self.num_envs)]
            observations, reward, term, trunc, _ = envs.step(mine)
            self.current[row] = np.asarray(observations, dtype=np.float32)
            rewards.append(reward)
            terminated.append(term)
            truncated.append(trunc)
        self.steps = np.where(self.pending, 0, self.steps + 1)
        ended_terminated, ended_truncated = np.concatenate(terminated), np.concatenate(truncated)
        self.pending = ended_terminated | ended_truncated
        return (
            self.observations(),
            np.concatenate(rewards).astype(np.float32),
            ended_terminated,
            ended_truncated,
        )

    def restart(self, row: int, seed: int) -> None:
        self.current[row] = np.asarray(self.envs[row].reset(seed=seed)[0], dtype=np.float32)
        envs = env_rows(row, self.num_envs)
        self.steps[envs] = 0
        self.pending[envs] = False

    def keep(self, seed_rows: np.ndarray) -> None:
        envs = rows_of_envs(seed_rows, self.num_envs)
        kept = set(seed_rows.tolist())
        for row, vector_env in enumerate(self.envs):
            if row not in kept:
                vector_env.close()
        self.envs = [self.envs[i] for i in seed_rows]
        self.current = [self.current[i] for i in seed_rows]
        self.steps, self.pending = self.steps[envs], self.pending[envs]

    def seed_state(self, row: int) -> dict[str, Any]:
        envs = env_rows(row, self.num_envs)
        return {
            "vector_env": vector_env_state(self.envs[row]),
            "observations": self.current[row].tolist(),
            "steps": self.steps[envs].tolist(),
            "pending": self.pending[envs].tolist(),
        }

    def load_seed_state(self, row: int, data: dict[str, Any]) -> None:
        envs = env_rows(row, self.num_envs)
        self.steps[envs] = data["steps"]
        self.pending[envs] = data["pending"]
        if restore_vector_env_state(self.envs[row], data["vector_env"], self.steps[envs], self.pending[envs]):
            self.current[row] = np.asarray(data["observations"], dtype=np.float32)
        else:  # an env whose state is not public (see resumable_envs): fresh episodes
            self.current[row] = np.asarray(self.envs[row].reset()[0], dtype=np.float32)
            self.steps[envs] = 0
            self.pending[envs] = False


__all__ = [
    "LONGEST_EPISODE_WITHOUT_TIME_LIMIT",
    "FastSeedEnvs",
    "GymnasiumSeedEnvs",
    "SeedEnvs",
    "make_seed_envs",
    "rows_of_envs",
]
