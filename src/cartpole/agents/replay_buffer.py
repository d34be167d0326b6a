"""Experience replay: a ring buffer of transitions in preallocated tensors, sampled uniformly.

One buffer for every off-policy agent. Rows live in tensors on the learner's device, written in place
(no Python objects per transition); the oldest rows are overwritten once ``capacity`` is reached, and
``sample`` only ever returns rows that were written. All fields of a transition share one row of a
single float32 table, so a sample is one ``torch.randint`` (from the caller's ``torch.Generator``) and
one ``index_select``, whose columns are the batch's fields: no host-to-device copy per gradient step.
``terminated`` is stored apart from truncation: a transition whose episode was cut by the time limit
is stored with ``terminated=False``, so its target bootstraps from the next state.
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
        # One row per transition: obs | next_obs | action | reward | terminated. Actions are stored as
        # float32, exact for any discrete action index below 2**24.
        d = self.obs_dim
        self.table = torch.zeros((capacity, 2 * d + 3), dtype=torch.float32, device=self.device)
        self.observations = self.table[:, :d]
        self.next_observations = self.table[:, d : 2 * d]
        self.actions = self.table[:, 2 * d]
        self.rewards = self.table[:, 2 * d + 1]
        self.terminated = self.table[:, 2 * d + 2]
        # On CPU, rows are written through numpy views of the same memory: a numpy fancy-index write
        # costs a fraction of torch's for the few rows of one env step.
        self._host_views = (
            {name: getattr(self, name).numpy() for name in _FIELDS} if self.device.type == "cpu" else None
        )
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
        values = [observations, actions, rewards, next_observations, terminated]
        if n > self.capacity:  # only the newest `capacity` rows can survive
            values = [v[n - self.capacity :] for v in values]
            self.pos = (self.pos + n - self.capacity) % self.capacity
            n = self.capacity
        rows = (self.pos + np.arange(n)) % self.capacity
        if self._host_views is not None:
            for name, value in zip(_FIELDS, values, strict=True):
                self._host_views[name][rows] = value
        else:
            index = torch.from_numpy(rows).to(self.device)
            for name, value in zip(_FIELDS, values, strict=True):
                field = getattr(self, name)
                field.index_copy_(0, index, torch.as_tensor(np.asarray(value)).to(self.device, field.dtype))
        self.pos = (self.pos + n) % self.capacity
        self.size = min(self.size + n, self.capacity)

    def sample(self, batch_size: int, generator: torch.Generator) -> Batch:
        """``batch_size`` rows drawn uniformly (with replacement) from the rows written so far.

        ``generator`` must live on the buffer's device; its state is the only randomness used.
        """
        if self.size == 0:
            raise ValueError("cannot sample from an empty replay buffer")
        rows = torch.randint(0, self.size, (batch_size,), generator=generator, device=self.device)
        sampled = self.table.index_select(0, rows)
        d = self.obs_dim
        return Batch(
            sampled[:, :d],
            sampled[:, 2 * d].long(),
            sampled[:, 2 * d + 1],
            sampled[:, d : 2 * d],
            sampled[:, 2 * d + 2],
        )

    def state_dict(self) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
        """The written rows as CPU tensors, and the write position as plain data (for exact resume)."""
        tensors = {name: getattr(self, name)[: self.size].to("cpu", copy=True) for name in _FIELDS}
        tensors["actions"] = tensors["actions"].long()  # int64, as the batches give them
        return tensors, {"capacity": self.capacity, "pos": self.pos, "size": self.size}

    def load_state_dict(self, tensors: dict[str, torch.Tensor], data: dict[str, Any]) -> None:
        """Restore what ``state_dict`` gave (the capacity must match)."""
        if int(data["capacity"]) != self.capacity:
            raise ValueError(f"replay capacity {data['capacity']} in the checkpoint, {self.capacity} here")
        size = int(data["size"])
        for name in _FIELDS:
            getattr(self, name)[:size] = tensors[name]  # in place: the numpy views stay valid
        self.pos, self.size = int(data["pos"]), size
