"""What a seed's training loop sees: the result of each learning step, and the seed's greedy policy
and state.

A population (:mod:`cartpole.agents.population`) learns for all its seeds at once and returns a
:class:`LearnResult` per seed; each seed's loop (:mod:`cartpole.training.loop`) and its callbacks see
the seed as a :class:`Learner`. Agents know nothing of callbacks, run folders or budgets.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol

from cartpole.evaluation import Policy

if TYPE_CHECKING:  # only in annotations: `cartpole presets` and `runs` start without torch
    import torch


@dataclass
class LearnResult:
    """What one ``learn()`` call did."""

    env_steps: int
    """Env transitions collected (summed over vector envs)."""
    episode_returns: list[float] = field(default_factory=list)
    """Returns of the training episodes that finished during this call."""
    episode_lengths: list[int] = field(default_factory=list)
    """Their lengths, in the same order."""
    scalars: dict[str, float] = field(default_factory=dict)
    """Namespaced training metrics, e.g. ``train/loss``, ``train/epsilon``."""
    summarized_episodes: int = 0
    """Episodes finished but summarized in ``scalars`` instead of listed one by one (a generation)."""
    log_scalars: bool = False
    """Write ``scalars`` as a metrics row for this step (population methods: one row per generation)."""


class Learner(Protocol):
    """One seed of a population, as its loop's callbacks see it: its greedy policy and its checkpoint.
    (Learning is the population's: all its seeds at once.)"""

    def policy(self) -> Policy:
        """The current greedy policy (what evaluation and checkpoints judge)."""
        ...

    def state_dict(self, resume: bool) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
        """Tensors and JSON-able data; with ``resume`` everything needed to continue exactly."""
        ...

    def load_state_dict(self, tensors: dict[str, torch.Tensor], data: dict[str, Any]) -> None:
        """Restore what ``state_dict`` gave."""
        ...
