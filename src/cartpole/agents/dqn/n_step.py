"""n-step returns for DQN: each env's last ``n`` transitions, turned into the rows the replay stores.

A stored row ``(s_t, a_t, R, s', terminated)`` then holds ``R = r_t + gamma r_{t+1} + ... +
gamma^(n-1) r_{t+n-1}`` and ``s' = s_{t+n}``, and its target bootstraps with ``gamma^n`` (as Rainbow's
and SB3's n-step replay do): the reward of a step reaches the values n steps back in one update instead
of n. When an episode terminates, its last transitions (fewer than n steps to the end) are stored too,
each with the rewards up to the end and no bootstrap. When the time limit truncates it, those that
would bootstrap from fewer than n steps are dropped, so every row that bootstraps does so with exactly
``gamma^n`` (one row layout, whatever n; at most n - 1 transitions of a truncated episode lost).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from cartpole.agents.dqn.config import DQNConfig
from cartpole.envs import EnvInfo
from cartpole.envs.seed_envs import env_rows


class NStepWindows:
    """For each of ``envs`` envs (``num_envs`` per seed), its running episode's last transitions not
    yet stored (at most ``n - 1`` between steps), oldest first."""

    def __init__(
        self, envs: int, num_envs: int, n: int, gamma: float, obs_shape: tuple[int, ...], dtype: Any
    ):
        self.n, self.gamma, self.num_envs = n, gamma, num_envs
        self.observations = np.zeros((envs, n, *obs_shape), dtype=dtype)
        self.actions = np.zeros((envs, n), dtype=np.int64)
        self.rewards = np.zeros((envs, n), dtype=np.float32)
        self.count = np.zeros(envs, dtype=np.int64)

    def step(
        self,
        valid: np.ndarray,
        observations: np.ndarray,
        actions: np.ndarray,
        rewards: np.ndarray,
        next_observations: np.ndarray,
        terminated: np.ndarray,
        truncated: np.ndarray,
    ) -> list[tuple[np.ndarray, list[np.ndarray]]]:
        """Take one batched step's transitions (where ``valid`` [E]) and return the rows now complete,
        oldest first, in rounds of at most one row per env: (which envs have one [E], the fields the
        replay stores: obs, actions, n-step returns, the observations they bootstrap from,
        terminated)."""
        envs = np.flatnonzero(valid)
        slots = self.count[envs]
        self.observations[envs, slots] = observations[envs]
        self.actions[envs, slots] = actions[envs]
        self.rewards[envs, slots] = rewards[envs]
        self.count[envs] += 1
        full = valid & (self.count == self.n)
        ends = valid & terminated
        # A terminated episode stores all its rows; otherwise a full window stores its oldest (a
        # truncated episode's shorter windows are dropped).
        emitting = np.where(ends, self.count, full.astype(np.int64))
        returns = self.returns_from_each_slot()
        ended = terminated.astype(np.float32)
        rounds = [
            (
                emitting > slot,
                [
                    self.observations[:, slot].copy(),
                    self.actions[:, slot].copy(),
                    returns[:, slot],
                    next_observations,
                    ended,
                ],
            )
            for slot in range(int(emitting.max(initial=0)))
        ]
        done = valid & (terminated | truncated)
        self.count[done] = 0
        shift = full & ~done  # the oldest left: the others move up one slot
        if shift.any():
            for array in (self.observations, self.actions, self.rewards):
                array[shift, :-1] = array[shift, 1:]
            self.count[shift] -= 1
        return rounds

    def returns_from_each_slot(self) -> np.ndarray:
        """[E, n]: the discounted sum of each window's rewards from each slot to its newest."""
        returns = np.zeros(self.rewards.shape, dtype=np.float64)
        following = np.zeros(len(self.count), dtype=np.float64)
        for slot in reversed(range(self.n)):
            following = np.where(slot < self.count, self.rewards[:, slot] + self.gamma * following, 0.0)
            returns[:, slot] = following
        return returns.astype(np.float32)

    def keep(self, envs: np.ndarray) -> None:
        """Keep only the windows of ``envs``."""
        self.observations, self.actions = self.observations[envs], self.actions[envs]
        self.rewards, self.count = self.rewards[envs], self.count[envs]

    def seed_state(self, row: int) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
        """Seed ``row``'s windows, for its checkpoint."""
        envs = env_rows(row, self.num_envs)
        tensors = {
            f"n_step.{name}": torch.from_numpy(getattr(self, name)[envs].copy())
            for name in ("observations", "actions", "rewards")
        }
        return tensors, {"n_step_count": self.count[envs].tolist()}

    def load_seed_state(self, row: int, tensors: dict[str, torch.Tensor], data: dict[str, Any]) -> None:
        """Restore what :meth:`seed_state` gave."""
        envs = env_rows(row, self.num_envs)
        for name in ("observations", "actions", "rewards"):
            getattr(self, name)[envs] = tensors[f"n_step.{name}"].numpy()
        self.count[envs] = data["n_step_count"]


def n_step_window_bytes(config: DQNConfig, env: EnvInfo) -> int:
    """The bytes of one seed's n-step windows (none for one-step rows): each env's last ``n_step``
    observations (uint8 pixels or float32 states), int64 actions and float32 rewards, and how many
    it holds (int64)."""
    if config.n_step == 1:
        return 0
    observation = env.obs_dim * (1 if env.is_image else 4)
    return config.num_envs * (config.n_step * (observation + 8 + 4) + 8)


__all__ = ["NStepWindows", "n_step_window_bytes"]
