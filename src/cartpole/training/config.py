"""Agent configs and presets: typed dataclasses filled from TOML data files, then validated.

A preset is a table in ``cartpole/agents/presets/<agent>.toml``. Its keys are fields of the agent's
config dataclass or of :class:`TrainSettings`; anything else is an error that names the valid keys.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
import types
import typing
from dataclasses import dataclass, fields
from importlib import resources
from typing import Any

from cartpole.training.budget import BudgetError, parse_budget


class ConfigError(ValueError):
    """A preset, an override or a config value is wrong."""


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
    """Simulator of the full evaluation: "gymnasium" (the reference) or "fast"."""
    checkpoint_every: int = 50_000
    """Env steps between writes of checkpoints/latest.pt (it is also written at the end)."""
    stop_when_solved: bool = True
    """End training at the first verified solve."""

    def validate(self) -> None:
        try:
            parse_budget(self.budget)
        except BudgetError as err:
            raise ConfigError(f"budget: {err}") from None
        require(self.eval_every >= 0, "eval_every must be >= 0")
        require(self.eval_screen_episodes >= 1, "eval_screen_episodes must be >= 1")
        require(self.eval_episodes >= 1, "eval_episodes must be >= 1")
        require(self.eval_simulator in ("gymnasium", "fast"), "eval_simulator: gymnasium or fast")
        require(self.checkpoint_every >= 1, "checkpoint_every must be >= 1")


def require(condition: bool, message: str) -> None:
    """Raise ConfigError(message) unless ``condition``: the one-line check configs use."""
    if not condition:
        raise ConfigError(message)


def preset_table(agent: str) -> dict[str, dict[str, Any]]:
    """All presets of ``agent`` as read from its TOML file."""
    text = resources.files("cartpole.agents").joinpath("presets", f"{agent}.toml").read_text()
    return tomllib.loads(text)


def preset_names(agent: str) -> list[str]:
    return list(preset_table(agent))


def _coerce(value: Any, annotation: Any, key: str) -> Any:
    """Check ``value`` against a field's type, converting strings from the command line."""
    hint = typing.get_type_hints(type("_", (), {"__annotations__": {"x": annotation}}))["x"]
    options = typing.get_args(hint) if isinstance(hint, types.UnionType) else (hint,)
    if value is None or (isinstance(value, str) and value.lower() == "none"):
        if type(None) in options:
            return None
        raise ConfigError(f"{key} cannot be none")
    for option in options:
        origin = typing.get_origin(option) or option
        try:
            if origin is bool:
                if isinstance(value, bool):
                    return value
                if isinstance(value, str) and value.lower() in ("true", "false", "1", "0"):
                    return value.lower() in ("true", "1")
            elif origin in (int, float):
                return _number(value, origin)
            elif origin is str:
                return str(value)
            elif origin in (list, tuple):
                items = value if isinstance(value, list | tuple) else str(value).split(",")
                (item_type,) = typing.get_args(option)[:1] or (str,)
                return origin(_coerce(v, item_type, key) for v in items if v != "")
        except (TypeError, ValueError, OverflowError):
            continue
    name = hint.__name__ if isinstance(hint, type) else str(hint)
    kinds = {typing.get_origin(o) or o for o in options}
    rule = (
        " (a whole number is needed)"
        if int in kinds
        else " (a finite number is needed)"
        if float in kinds
        else ""
    )
    raise ConfigError(f"{key}={value!r} is not a valid {name}{rule}")


def _number(value: Any, kind: type) -> int | float:
    """``value`` (a number, or text from the command line) as a finite int or float; ValueError if
    it is not one (``2.5`` for an int, ``inf``, ``nan``, ``true``)."""
    if isinstance(value, bool) or not isinstance(value, int | float | str):
        raise TypeError(f"not a number: {value!r}")
    if isinstance(value, str):
        text = value.strip()
        try:
            value = int(text)
        except ValueError:
            value = float(text)
    if isinstance(value, float) and not math.isfinite(value):
        raise ValueError(f"not finite: {value}")
    if kind is int:
        if isinstance(value, float) and not value.is_integer():
            raise ValueError(f"not whole: {value}")
        return int(value)
    return float(value)


def build_config(cls: type, values: dict[str, Any]) -> Any:
    """An instance of dataclass ``cls`` from ``values``; ConfigError for an unknown key or bad value."""
    kinds = {f.name: f.type for f in fields(cls)}
    unknown = sorted(set(values) - set(kinds))
    if unknown:
        raise ConfigError(f"unknown setting {unknown[0]!r}; valid: {', '.join(sorted(kinds))}")
    kwargs = {k: _coerce(v, kinds[k], k) for k, v in values.items()}
    return cls(**kwargs)


def build_valid_config(cls: type, values: dict[str, Any]) -> Any:
    """``build_config``, then the config's own ``validate()`` (if it has one)."""
    config = build_config(cls, values)
    validate = getattr(config, "validate", None)
    if validate is not None:
        validate()
    return config


def resolve_config(
    agent: str, config_cls: type, preset: str, overrides: dict[str, Any] | None = None
) -> tuple[Any, TrainSettings]:
    """Agent config and train settings: dataclass defaults < preset < overrides, validated."""
    table = preset_table(agent)
    if preset not in table:
        raise ConfigError(f"unknown preset {preset!r} for {agent}; choose one of: {', '.join(table)}")
    values = {k: v for k, v in table[preset].items() if k != "description"}
    values.update(overrides or {})
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


def config_to_dict(config: Any) -> dict[str, Any]:
    """A dataclass config as JSON-able data (tuples become lists)."""
    return dataclasses.asdict(config)
