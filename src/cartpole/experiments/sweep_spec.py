"""What a sweep is (:class:`SweepSpec`): the same on every worker and machine that joins its study.
Apart from :mod:`cartpole.experiments.sweep`, which runs sweeps, so that ``best.py`` can read it."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cartpole.experiments.space import Param


@dataclass
class SweepSpec:
    """What a sweep is: the same on every worker and machine that joins its study."""

    name: str
    agent: str
    preset: str
    env_id: str
    budget: str | None
    seeds_per_trial: int
    trials: int
    space_text: str
    storage: str | None
    """A database URL, or None for the journal file in ``folder``."""
    folder: str
    sampler_seed: int = 0
    space: dict[str, Any] = field(default_factory=dict)
    seeds: list[int] = field(default_factory=list)
    """The seeds every trial trains (``--seeds``); none recorded (sweeps before it): 0..K-1."""
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    """``--env-kwargs``: every trial's env made with them (over the preset's own ``env_kwargs``)."""
    tensorboard: bool = False
    """``--tensorboard``: this command's trials log TensorBoard events in their run folders (not part of
    the study's identity: it changes no result)."""

    @property
    def trial_seeds(self) -> list[int]:
        """The seeds every trial trains: ``seeds``, else 0..``seeds_per_trial``-1."""
        return list(self.seeds) or list(range(self.seeds_per_trial))

    @property
    def path(self) -> Path:
        return Path(self.folder)

    @property
    def identity(self) -> dict[str, Any]:
        """What a study records about the sweep; a sweep that differs must not join it. (Its seeds
        only where they are not 0..K-1, and its env kwargs only where given, so studies made before
        ``--seeds`` and ``--env-kwargs`` are joined as before.)"""
        named: dict[str, Any] = {}
        if self.trial_seeds != list(range(self.seeds_per_trial)):
            named["seeds"] = self.trial_seeds
        if self.env_kwargs:
            named["env_kwargs"] = self.env_kwargs
        return {
            "agent": self.agent,
            "preset": self.preset,
            "env_id": self.env_id,
            "budget": self.budget,
            "seeds_per_trial": self.seeds_per_trial,
            "space": self.space,
        } | named

    def params(self) -> dict[str, Param]:
        from cartpole.experiments.space import parse_space

        return parse_space(self.agent, self.space_text, "the study's space")

    @property
    def storage_label(self) -> str:
        return self.storage or str(self.path / "journal.log")


__all__ = ["SweepSpec"]
