"""Agent configs and presets: typed dataclasses filled from TOML data files, then validated.

A preset is a table in ``cartpole/agents/presets/<agent>.toml``, or a ``.toml`` file anywhere (for
example the ``best.toml`` a sweep writes) holding one table of settings. Its keys are fields of the agent's
config dataclass or of :class:`TrainSettings`; anything else is an error that names the valid keys.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Any

from cartpole.agents.presets import preset_values
from cartpole.core.config import build_valid_config, require
from cartpole.core.errors import ConfigError
from cartpole.envs import check_kwargs, check_simulator, check_wrappers
from cartpole.training.budget import parse_budget


@dataclass
class TrainSettings:
    """How the shared loop runs an agent: budget, evaluation and checkpoint cadence."""

    budget: str = "100k"
    """Default budget: env steps (50k), episodes (300ep), generations (20gen) or time (90s)."""
    eval_every: int = 5000
    """Env steps between evaluations (0: evaluate after every learning step)."""
    eval_screen_episodes: int = 20
    """Episodes of the quick screen; only a screen at the threshold triggers the full evaluation."""
    eval_episodes: int = 100
    """Episodes of the full evaluation (Gymnasium's rule needs >= 100 to call it solved)."""
    eval_simulator: str = "gymnasium"
    """Simulator of the full evaluations during training (the ones that stop a run at a solve):
    "gymnasium" (the reference) or "fast"."""
    confirm_solves: bool = False
    """Play a full evaluation that passes again, on the next ``eval_episodes`` episode seeds of its
    stream: the evaluation reports the lower of the two, so a solve counts (and ends training) only
    when both pass. A policy that passed once by luck is then rarely called solved, and the final
    verdict, a third evaluation, agrees more often."""
    verdict_simulator: str | None = None
    """Simulator of the final verdict: "gymnasium" or "fast"; none: the ``eval_simulator``. (The
    pixel presets evaluate on our renderer during training and judge on Gymnasium's pictures.)"""
    checkpoint_fraction: float = 0.05
    """Share of the budget between writes of checkpoints/latest.pt (also written at start and end)."""
    checkpoint_seconds: float = 30.0
    """Wall-clock seconds between writes of checkpoints/latest.pt at the most."""
    checkpoint_every: int = 0
    """Env steps between writes of checkpoints/latest.pt at the most (0: no step-based cadence)."""
    stop_when_solved: bool = True
    """End training at the first verified solve."""
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    """Keyword arguments of the env's constructor, as ``gymnasium.make(env_id, **env_kwargs)`` passes
    them (``--env-kwargs KEY=VALUE``), for training, evaluations and the verdict."""
    wrappers: list[dict[str, Any] | str] = field(default_factory=list)
    """Gymnasium wrappers put around every env, in order: each "module:Class" or {name = "module:Class",
    kwargs = {...}}; the verdict's return stays the env's own reward."""

    @property
    def final_simulator(self) -> str:
        """Where the final verdict is played: ``verdict_simulator``, else ``eval_simulator``."""
        return self.eval_simulator if self.verdict_simulator is None else self.verdict_simulator

    def validate(self) -> None:
        parse_budget(self.budget)
        require(self.eval_every >= 0, "eval_every must be >= 0")
        require(self.eval_screen_episodes >= 1, "eval_screen_episodes must be >= 1")
        require(self.eval_episodes >= 1, "eval_episodes must be >= 1")
        check_simulator(self.eval_simulator, "eval_simulator")
        check_simulator(self.final_simulator, "verdict_simulator")
        require(0 < self.checkpoint_fraction <= 1, "checkpoint_fraction must be in (0, 1]")
        require(0 < self.checkpoint_seconds < float("inf"), "checkpoint_seconds must be > 0")
        require(self.checkpoint_every >= 0, "checkpoint_every must be >= 0 (0: off)")
        check_kwargs(self.env_kwargs, "env_kwargs")
        check_wrappers(self.wrappers)


def resolve_config(
    agent: str, config_cls: type, preset: str, overrides: dict[str, Any] | None = None
) -> tuple[Any, TrainSettings]:
    """Agent config and train settings: dataclass defaults < preset < overrides, validated.

    ``preset`` is a preset name of the agent or a path to a ``.toml`` preset file.
    """
    values = preset_values(agent, preset)
    overrides = dict(overrides or {})
    if isinstance(values.get("env_kwargs"), dict) and isinstance(overrides.get("env_kwargs"), dict):
        overrides["env_kwargs"] = values["env_kwargs"] | overrides["env_kwargs"]  # the preset's, updated
    values.update(overrides)
    agent_keys = {f.name for f in fields(config_cls)}
    train_keys = {f.name for f in fields(TrainSettings)}
    unknown = sorted(set(values) - agent_keys - train_keys)
    if unknown:
        raise ConfigError(
            f"unknown setting {unknown[0]!r} for {agent}; valid: {', '.join(sorted(agent_keys | train_keys))}"
        )
    config = build_valid_config(config_cls, {k: v for k, v in values.items() if k in agent_keys})
    settings = build_valid_config(TrainSettings, {k: v for k, v in values.items() if k in train_keys})
    return config, settings
