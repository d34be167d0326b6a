"""Every seed's own vector env, stepped as one: what a population of seeds trains on.

A population of S seeds with ``num_envs`` envs each sees one [S * num_envs, ...] batch, seed s owning
rows ``s * num_envs`` to ``(s + 1) * num_envs - 1``. Each seed's envs are those its own run would
make: seeded by ``reset(seed=seed)``, with Gymnasium's next-step autoreset. Two forms, one interface
(:class:`SeedEnvs`), picked by :func:`make_seed_envs`:

- :class:`FastSeedEnvs`: CartPole on our fast simulator, all S x N envs stepped by one call of its
  kernel (:func:`~cartpole.envs.fast.step_cartpole_columns`); each seed's start states come from its own
  ``np_random(seed)`` in Gymnasium's order, so they are the start states its vector env would draw.
- :class:`PixelSeedEnvs`: our pixel envs (``cartpole/CartPolePixels-v1``): the fast simulator's S x N
  cart-poles as above, each drawn as a stack of gray frames by one renderer call per step
  (:class:`~cartpole.envs.pixels.PixelRenderer`), as :class:`~cartpole.envs.pixels.CartPolePixelsVectorEnv`
  draws them; observations stay uint8 (the network scales them).
- :class:`GymnasiumSeedEnvs`: any other env or simulator (Acrobot, MountainCar, Gymnasium's own
  CartPole for the tutorial presets): one resumable Gymnasium vector env per seed
  (:func:`~cartpole.envs.resumable_envs.make_resumable_vec_env`), stepped in turn.

Both count each env's steps and pending autoresets themselves, so a seed's envs can be saved to a
checkpoint and put back mid-episode (``seed_state`` / ``load_seed_state``).
"""

from __future__ import annotations

import base64
import zlib
from typing import Any, Protocol

import gymnasium as gym
import numpy as np
from gymnasium.utils.seeding import np_random

from cartpole.envs import EnvInfo, resolve_simulator
from cartpole.envs.fast import DEFAULT_RESET_HIGH, DEFAULT_RESET_LOW, step_cartpole_columns
from cartpole.envs.params import with_physics
from cartpole.envs.resumable_envs import make_resumable_vec_env, restore_vector_env_state, vector_env_state

LONGEST_EPISODE_WITHOUT_TIME_LIMIT = 10_000
"""Where an env without a time limit of its own has its episodes cut (REINFORCE waits for them)."""

Step = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]
"""(observations, rewards, terminated, truncated) of all S x N envs."""


class SeedEnvs(Protocol):
    """S seeds' vector envs of ``num_envs`` envs each, as one batch."""

    num_envs: int

    def observations(self) -> np.ndarray:
        """The current observations [S * N, *obs_shape]: float32, or uint8 for images."""
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
    if resolve_simulator(env, simulator) == "fast":
        if env.pixels_of:
            return PixelSeedEnvs(FastSeedEnvs(seeds, num_envs, limit), env.obs_shape)
        if not env.wrappers:
            return FastSeedEnvs(seeds, num_envs, limit, env.kwargs)
    return GymnasiumSeedEnvs(env, seeds, num_envs)


def env_rows(row: int, num_envs: int) -> slice:
    """The rows of seed row ``row``'s envs in the batch."""
    return slice(row * num_envs, (row + 1) * num_envs)


def rows_of_envs(seed_rows: np.ndarray, num_envs: int) -> np.ndarray:
    """The batch rows of the envs of seed rows ``seed_rows``, in that order."""
    return (seed_rows[:, None] * num_envs + np.arange(num_envs)).reshape(-1)


class FastSeedEnvs:
    """S x N CartPoles of the fast simulator, stepped by one kernel call; their states are kept as
    the kernel's ``(4, S * N)`` columns."""

    def __init__(
        self, seeds: list[int], num_envs: int, max_episode_steps: int, kwargs: dict[str, Any] | None = None
    ):
        """``kwargs``: what our CartPole env takes (its physics constants, ``sutton_barto_reward``)."""
        kwargs = dict(kwargs or {})
        self.sutton_barto_reward = bool(kwargs.pop("sutton_barto_reward", False))
        self.params = with_physics(None, kwargs)  # TypeError for anything else, as the env says
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
        terminated = step_cartpole_columns(self.columns, actions.astype(np.int64, copy=False), self.params)
        self.steps += 1
        truncated = self.steps >= self.max_episode_steps
        if self.sutton_barto_reward:  # 0 per step, -1 for the step that fails (Sutton and Barto's)
            rewards = -terminated.astype(np.float32)
        else:
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


class PixelSeedEnvs:
    """The cart-poles of :class:`FastSeedEnvs` seen as stacks of gray frames ``[S * N, stack, height,
    width]`` uint8 (oldest first), as :class:`~cartpole.envs.pixels.CartPolePixelsVectorEnv` sees
    them: a stack is filled with its first frame at the start of an episode (also on the autoreset
    step). Each env's frames depend only on its own states, so seeds stay independent."""

    def __init__(self, states: FastSeedEnvs, obs_shape: tuple[int, ...]):
        from cartpole.envs.pixels import PixelRenderer  # numba kernels: only for pixel envs

        stack, height, width = obs_shape
        self.states, self.num_envs = states, states.num_envs
        self.renderer = PixelRenderer((height, width))
        self.frames = np.empty((states.columns.shape[1], stack, height, width), dtype=np.uint8)
        self.restack(np.arange(len(self.frames)), self.draw())

    def draw(self) -> np.ndarray:
        """A frame [S * N, height, width] of every env's current state."""
        return self.renderer.render(self.states.columns.T)

    def restack(self, envs: np.ndarray, frames: np.ndarray) -> None:
        """Fill the stacks of ``envs`` with their frame of ``frames`` (a new episode's first)."""
        self.frames[envs] = frames[envs, None]

    def observations(self) -> np.ndarray:
        return self.frames.copy()

    def step(self, actions: np.ndarray) -> Step:
        restarted = np.flatnonzero(self.states.pending)  # their step is the autoreset
        _, rewards, terminated, truncated = self.states.step(actions)
        frames = self.draw()
        self.frames[:, :-1] = self.frames[:, 1:]
        self.frames[:, -1] = frames
        self.restack(restarted, frames)
        return self.observations(), rewards, terminated, truncated

    def restart(self, row: int, seed: int) -> None:
        self.states.restart(row, seed)
        envs = np.arange(len(self.frames))[env_rows(row, self.num_envs)]
        self.restack(envs, self.draw())

    def keep(self, seed_rows: np.ndarray) -> None:
        self.frames = np.ascontiguousarray(self.frames[rows_of_envs(seed_rows, self.num_envs)])
        self.states.keep(seed_rows)

    def seed_state(self, row: int) -> dict[str, Any]:
        # The stacks hold the last few states' frames, which the states alone cannot redraw: kept
        # compressed (mostly white, they shrink to a few kB).
        frames = self.frames[env_rows(row, self.num_envs)]
        packed = base64.b64encode(zlib.compress(frames.tobytes())).decode("ascii")
        return self.states.seed_state(row) | {"frames": packed}

    def load_seed_state(self, row: int, data: dict[str, Any]) -> None:
        self.states.load_seed_state(row, data)
        envs = env_rows(row, self.num_envs)
        unpacked = np.frombuffer(zlib.decompress(base64.b64decode(data["frames"])), dtype=np.uint8)
        self.frames[envs] = unpacked.reshape(self.frames[envs].shape)


def as_observations(observations: Any) -> np.ndarray:
    """A vector env's observations as the learners take them: images stay uint8, the rest float32."""
    array = np.asarray(observations)
    return array if array.dtype == np.uint8 else array.astype(np.float32)


class GymnasiumSeedEnvs:
    """One Gymnasium vector env per seed (any env with Box observations), stepped in turn."""

    def __init__(self, env: str | EnvInfo, seeds: list[int], num_envs: int):
        self.num_envs = num_envs
        self.envs: list[gym.vector.VectorEnv] = []
        self.current: list[np.ndarray] = []
        for seed in seeds:
            envs = make_resumable_vec_env(env, num_envs, "gymnasium")
            self.envs.append(envs)
            self.current.append(as_observations(envs.reset(seed=seed)[0]))
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
            self.current[row] = as_observations(observations)
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
        self.current[row] = as_observations(self.envs[row].reset(seed=seed)[0])
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
            saved = np.asarray(data["observations"], dtype=self.current[row].dtype)
            self.current[row] = as_observations(saved)
        else:  # an env whose state is not public (see resumable_envs): fresh episodes
            self.current[row] = as_observations(self.envs[row].reset()[0])
            self.steps[envs] = 0
            self.pending[envs] = False


__all__ = [
    "LONGEST_EPISODE_WITHOUT_TIME_LIMIT",
    "FastSeedEnvs",
    "GymnasiumSeedEnvs",
    "PixelSeedEnvs",
    "SeedEnvs",
    "make_seed_envs",
    "rows_of_envs",
]
