"""Every run is a population: S seeds of one agent trained side by side, a single run being S = 1.

:class:`Population` is what the training session drives (:mod:`cartpole.training.engine`). One
learner holds every seed on a leading seed axis (networks, optimizers, replay or rollouts, envs,
generators), one update for all, on any env. Each seed's envs are its own
(:mod:`cartpole.envs.seed_envs`): on CartPole's fast simulator all seeds' envs step in one call,
elsewhere (Acrobot, MountainCar, Gymnasium's own CartPole for the tutorial presets) each seed's
Gymnasium vector env steps in turn. Each seed's arithmetic does not depend on which seeds share it,
so seed N alone (``--seed N``) and seed N among others train bit for bit the same
(``tests/test_one_engine.py``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from cartpole.agents.learner import LearnResult
from cartpole.core.errors import ConfigError
from cartpole.envs.seed_envs import rows_of_envs
from cartpole.evaluation import BlockActor, Policy

if TYPE_CHECKING:
    import torch


class Population(Protocol):
    """Many seeds of one agent trained side by side: what the training session needs of them."""

    @property
    def active_seeds(self) -> list[int]: ...

    def learn(self) -> dict[int, LearnResult]:
        """One step (a rollout and update, a batched env step, or a generation) of every active
        seed, by seed."""
        ...

    def remove(self, seeds: list[int]) -> None:
        """Stop training ``seeds``: they leave every batch."""
        ...

    def greedy_actor(self, seeds: list[int]) -> BlockActor:
        """The greedy policies of ``seeds`` as one :data:`~cartpole.evaluation.BlockActor`: block i
        holds seed i's rows."""
        ...

    def seed_policy(self, seed: int) -> Policy: ...

    def seed_state_dict(self, seed: int, resume: bool) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
        """Seed ``seed``'s checkpoint: its greedy policy's tensors and, with ``resume``, everything to
        continue exactly."""
        ...

    def load_seed_state_dict(
        self, seed: int, tensors: dict[str, torch.Tensor], data: dict[str, Any]
    ) -> None: ...


class SeedRows:
    """Which row of a batched population holds which seed: one row of every seed-axis tensor, and
    ``num_envs`` consecutive rows of every per-env array."""

    seeds: list[int]

    def row(self, seed: int) -> int:
        return self.seeds.index(seed)

    @property
    def active_seeds(self) -> list[int]:
        return list(self.seeds)

    def leave(self, seeds: list[int], num_envs: int) -> tuple[np.ndarray, np.ndarray]:
        """``seeds`` leave: the seeds that stay become ``self.seeds``; returns their rows, and the rows
        of their envs, for the caller to keep of every batch."""
        gone = set(seeds)
        rows = np.asarray([i for i, s in enumerate(self.seeds) if s not in gone], dtype=np.int64)
        if not len(rows):
            raise ConfigError("cannot remove every seed of a population")
        self.seeds = [self.seeds[i] for i in rows]
        return rows, rows_of_envs(rows, num_envs)


__all__ = ["Population", "SeedRows"]
