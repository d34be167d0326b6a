"""Experience replay: a ring buffer of transitions in preallocated arrays, sampled uniformly.

One buffer for every off-policy agent. Rows are written in place (no Python objects per transition),
the oldest rows are overwritten once ``capacity`` is reached, and ``sample`` only ever returns rows
that were written. ``terminated`` is stored apart from truncation: a transition whose episode was cut
by the time limit is stored with ``terminated=False``, so its target bootstraps from the next state.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
import torch


class Batch(NamedTuple):
    """A sampled minibatch, as tensors on the buffer's device."""

    observations: torch.Tensor
    """float32 [B, obs_dim]"""
    actions: torch.Tensor
    """int64 [B]"""
    rewards: torch.Tensor
    """float32 [B] (after any reward shaping)"""
    next_observations: torch.Tensor
    """float32 [B, obs_dim]: the state reached (the real final state at truncation, never a reset state)"""
    terminated: torch.Tensor
    """float32 [B]: 1.0 where the episode ended by termination, so the target must not bootstrap"""


_FIELDS = ("observations", "actions", "rewards", "next_observations", "terminated")


class ReplayBuffer:
    """Fixed-capacity ring buffer of ``(obs, action, reward, next_obs, terminated)`` rows."""

    def __init__(self, capacity: int, obs_dim: int, device: str | torch.device = "cpu"):
        if capacity < 1:
            raise ValueError(f"replay capacity must be >= 1, got {capacity}")
        self.capacity = int(capacity)
        self.obs_dim = int(obs_dim)
        self.device = torch.device(device)
        self.observations = np.zeros((capacity, obs_dim), dtype=np.float32)
        self.actions = np.zeros(capacity, dtype=np.int64)
        self.rewards = np.zeros(capacity, dtype=np.float32)
        self.next_observations = np.zeros((capacity, obs_dim), dtype=np.float32)
        self.terminated = np.zeros(capacity, dtype=np.float32)
        self.pos = 0
        """Row the next transition is written to."""
        self.size = 0
        """Rows written so far, at most ``capacity``."""

    def __len__(self) -> int:
        return self.size

    def add(
        self,
        observations: np.ndarray,
        actions: np.ndarray,
        rewards: np.ndarray,
        next_observations: np.ndarray,
        terminated: np.ndarray,
    ) -> None:
        """Append a batch of ``n`` transitions (n may be 0), overwriting the oldest when full."""
        n = len(actions)
        if n == 0:
            return
        if n > self.capacity:  # only the newest `capacity` rows can survive
            keep = slice(n - self.capacity, n)
            observations, actions, rewards = observations[keep], actions[keep], rewards[keep]
            next_observations, terminated = next_observations[keep], terminated[keep]
            self.pos = (self.pos + n - self.capacity) % self.capacity
            n = self.capacity
        rows = (self.pos + np.arange(n)) % self.capacity
        self.observations[rows] = observations
        self.actions[rows] = actions
        self.rewards[rows] = rewards
        self.next_observations[rows] = next_observations
        self.terminated[rows] = terminated
        self.pos = (self.pos + n) % self.capacity
        self.size = min(self.size + n, self.capacity)

    def sample(self, batch_size: int, rng: np.random.Generator) -> Batch:
        """``batch_size`` rows drawn uniformly (with replacement) from the rows written so far."""
        if self.size == 0:
            raise ValueError("cannot sample from an empty replay buffer")
        rows = rng.integers(0, self.size, size=batch_size)
        device = self.device
        return Batch(
            torch.from_numpy(self.observations[rows]).to(device, non_blocking=True),
            torch.from_numpy(self.actions[rows]).to(device, non_blocking=True),
            torch.from_numpy(self.rewards[rows]).to(device, non_blocking=True),
            torch.from_numpy(self.next_observations[rows]).to(device, non_blocking=True),
            torch.from_numpy(self.terminated[rows]).to(device, non_blocking=True),
        )

    def state_dict(self) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
        """The written rows as tensors, and the write position as plain data (for exact resume)."""
        tensors = {name: torch.from_numpy(getattr(self, name)[: self.size].copy()) for name in _FIELDS}
        return tensors, {"capacity": self.capacity, "pos": self.pos, "size": self.size}

    def load_state_dict(self, tensors: dict[str, torch.Tensor], data: dict[str, Any]) -> None:
        """Restore what ``state_dict`` gave (the capacity must match)."""
        if int(data["capacity"]) != self.capacity:
            raise ValueError(f"replay capacity {data['capacity']} in the checkpoint, {self.capacity} here")
        size = int(data["size"])
        for name in _FIELDS:
            getattr(self, name)[:size] = tensors[name].numpy()
        self.pos, self.size = int(data["pos"]), size
