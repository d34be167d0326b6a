"""Agent configs and presets: typed dataclasses filled from TOML data files, then validated.

A preset is a table in ``cartpole/agents/presets/<agent>.toml``, or a ``.toml`` file anywhere (for
example the ``best.toml`` a sweep writes) holding one table of settings. Its keys are fields of the agent's
config dataclass or of :class:`TrainSettings`; anything else is an error that names the valid keys.
"""

from __future__ import annotations

import dataclasses
import tomllib
import types
import typing
from dataclasses import dataclass, fields
from importlib import resources
from pathlib import Path
from typing import Any

from cartpole.training.budget import parse_budget


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
        parse_budget(self.budget)
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


def preset_source(agent: str) -> str:
    """Where ``agent``'s named presets are read from (a file path, for ``cartpole presets``)."""
    return str(resources.files("cartpole.agents").joinpath("presets", f"{agent}.toml"))


def is_preset_file(preset: str) -> bool:
    """A preset given as a path to a TOML file (``best.toml``, ``my/preset.toml``) rather than a name."""
    return preset.endswith(".toml")


def read_preset_file(path: str | Path) -> dict[str, Any]:
    """The settings of a preset file: one table of settings (the form ``cartpole sweep`` writes as
    ``best.toml``), or a file holding exactly one named table of them."""
    path = Path(path)
    try:
        table = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(f"preset file {path} does not exist") from None
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as err:
        raise ConfigError(f"preset file {path} is not readable TOML: {err}") from None
    tables = [v for v in table.values() if isinstance(v, dict)]
    if tables and len(tables) == len(table):
        if len(tables) > 1:
            raise ConfigError(
                f"preset file {path} holds {len(tables)} presets ({', '.join(table)}); keep one table"
            )
        return tables[0]
    return table


def preset_values(agent: str, preset: str) -> dict[str, Any]:
    """The settings a preset sets (without its description): by name, or from a ``.toml`` file."""
    if is_preset_file(preset):
        values = read_preset_file(preset)
    else:
        table = preset_table(agent)
        if preset not in table:
            raise ConfigError(
                f"unknown preset {preset!r} for {agent}; choose one of: {', '.join(table)} "
                "(or give a path to a .toml preset file)"
            )
        values = table[preset]
    return {k: v for k, v in values.items() if k != "description"}


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
                if isinstance(value, bool):
                    continue
                if origin is int and isinstance(value, float) and not value.is_integer():
                    continue
                return origin(float(value)) if origin is int else origin(value)
            elif origin is str:
                return str(value)
            elif origin in (list, tuple):
                items = value if isinstance(value, list | tuple) else str(value).split(",")
                (item_type,) = typing.get_args(option)[:1] or (str,)
                return origin(_coerce(v, item_type, key) for v in items if v != "")
        except (TypeError, ValueError):
            continue
    raise ConfigError(f"{key}={value!r} is not a valid {hint}")


def build_config(cls: type, values: dict[str, Any]) -> Any:
    """An instance of dataclass ``cls`` from ``values`` (unknown keys were filtered before)."""
    kinds = {f.name: f.type for f in fields(cls)}
    kwargs = {k: _coerce(v, kinds[k], k) for k, v in values.items()}
    return cls(**kwargs)


def resolve_config(
    agent: str, config_cls: type, preset: str, overrides: dict[str, Any] | None = None
) -> tuple[Any, TrainSettings]:
    """Agent config and train settings: dataclass defaults < preset < overrides, validated.

    ``preset`` is a preset name of the agent or a path to a ``.toml`` preset file.
    """
    values = preset_values(agent, preset)
    values.update(overrides or {})
    agent_keys = {f.name for f in fields(config_cls)}
    train_keys = {f.name for f in fields(TrainSettings)}
    unknown = sorted(set(values) - agent_keys - train_keys)
    if unknown:
        raise ConfigError(
            f"unknown setting {unknown[0]!r} for {agent}; valid: {', '.join(sorted(agent_keys | train_keys))}"
        )
    config = build_config(config_cls, {k: v for k, v in values.items() if k in agent_keys})
    settings = build_config(TrainSettings, {k: v for k, v in values.items() if k in train_keys})
    validate = getattr(config, "validate", None)
    if validate is not None:
        validate()
    settings.validate()
    return config, settings


def config_to_dict(config: Any) -> dict[str, Any]:
    """A dataclass config as JSON-able data (tuples become lists)."""
    return dataclasses.asdict(config)
