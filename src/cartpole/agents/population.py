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


def staying_rows(seeds: list[int], leaving: list[int]) -> np.ndarray:
    """The rows of ``seeds`` (a population's, row by row) that stay when ``leaving`` leave, rising;
    ConfigError when none would."""
    gone = set(leaving)
    rows = np.asarray([i for i, s in enumerate(seeds) if s not in gone], dtype=np.int64)
    if not len(rows):
        raise ConfigError("cannot remove every seed of a population")
    return rows


__all__ = ["Population", "staying_rows"]
