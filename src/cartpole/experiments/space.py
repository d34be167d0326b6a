"""Search spaces of ``cartpole sweep``: a TOML table per setting, checked before any trial runs.

The default space of an agent lives beside its presets, in ``cartpole/agents/search_spaces/<agent>.toml``;
``--space FILE.toml`` replaces it. Each table names a setting of the agent's config or of
:class:`TrainSettings` and holds either ``choices = [...]`` or ``low``/``high`` (integers when both are
integers), with optional ``log = true`` or ``step``.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, fields
from importlib import resources
from pathlib import Path
from typing import Any

from cartpole.agents.registry import get_agent
from cartpole.core.errors import ConfigError
from cartpole.experiments.entries import ExperimentError
from cartpole.training.config import TrainSettings, resolve_config

RANGE_KEYS = {"low", "high", "log", "step"}


@dataclass(frozen=True)
class Param:
    """One setting to search: a list of choices, or a range."""

    name: str
    choices: tuple[Any, ...] = ()
    low: float | None = None
    high: float | None = None
    log: bool = False
    step: float | None = None

    @property
    def is_int(self) -> bool:
        return isinstance(self.low, int) and isinstance(self.high, int) and not isinstance(self.step, float)

    def suggest(self, trial: Any) -> Any:
        """The value an Optuna trial picks for this setting."""
        if self.choices:
            return trial.suggest_categorical(self.name, list(self.choices))
        assert self.low is not None and self.high is not None
        if self.is_int:
            step = int(self.step or 1)
            return trial.suggest_int(self.name, int(self.low), int(self.high), step=step, log=self.log)
        return trial.suggest_float(self.name, float(self.low), float(self.high), step=self.step, log=self.log)

    def holds(self, value: Any) -> bool:
        """Whether ``value`` is one this parameter can suggest (a choice, or in the range on its grid)."""
        if self.choices:
            return value in self.choices
        if isinstance(value, bool) or not isinstance(value, int | float):
            return False
        assert self.low is not None and self.high is not None
        if not self.low <= value <= self.high:
            return False
        return (
            self.step is None
            or abs((value - self.low) / self.step - round((value - self.low) / self.step)) < 1e-9
        )

    def extremes(self) -> list[Any]:
        return list(self.choices) if self.choices else [self.low, self.high]


def default_space_path(agent: str) -> Any:
    return resources.files("cartpole.agents").joinpath("search_spaces", f"{agent}.toml")


def read_space_text(agent: str, path: str | None) -> tuple[str, str]:
    """(TOML text, where it came from) of ``path``, or of the agent's default space."""
    if path is None:
        source = default_space_path(agent)
        if not source.is_file():
            raise ExperimentError(f"{agent} has no default search space; give one with --space FILE.toml")
        return source.read_text(encoding="utf-8"), str(source)
    try:
        return Path(path).read_text(encoding="utf-8"), path
    except OSError as err:
        raise ExperimentError(f"cannot read the search space {path}: {err.strerror or err}") from None


def parse_space(agent: str, text: str, source: str) -> dict[str, Param]:
    """Parse and check a search space for ``agent``: known settings, non-empty ranges, valid values."""
    try:
        table = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise ExperimentError(f"search space {source} is not valid TOML: {err}") from None
    spec = get_agent(agent)
    known = {f.name for f in fields(spec.config_cls)} | {f.name for f in fields(TrainSettings)}
    if not table:
        raise ExperimentError(f"search space {source} names no setting")
    space = {}
    for name, body in table.items():
        where = f"search space {source}, [{name}]"
        if name not in known:
            raise ExperimentError(f"{where}: unknown setting for {agent}; valid: {', '.join(sorted(known))}")
        if not isinstance(body, dict):
            raise ExperimentError(f"{where}: expected a table with choices or low/high")
        space[name] = parse_param(name, body, where)
    return space


def parse_param(name: str, body: dict[str, Any], where: str) -> Param:
    if "choices" in body:
        extra = set(body) - {"choices"}
        choices = body["choices"]
        if extra:
            raise ExperimentError(f"{where}: choices cannot be combined with {', '.join(sorted(extra))}")
        if not isinstance(choices, list) or not choices:
            raise ExperimentError(f"{where}: choices is empty; list at least one value")
        if any(isinstance(c, dict | list) for c in choices):
            raise ExperimentError(f'{where}: choices must be plain values (a list as a string: "64,64")')
        return Param(name, choices=tuple(choices))
    unknown = set(body) - RANGE_KEYS
    if unknown:
        raise ExperimentError(
            f"{where}: unknown key {sorted(unknown)[0]!r}; use choices, or low/high/log/step"
        )
    low, high = body.get("low"), body.get("high")
    numbers = (int, float)
    if not isinstance(low, numbers) or not isinstance(high, numbers) or isinstance(low, bool):
        raise ExperimentError(f"{where}: give numeric low and high (or choices)")
    if not low < high:
        raise ExperimentError(f"{where}: the range is empty (low {low} must be below high {high})")
    log = bool(body.get("log", False))
    if log and low <= 0:
        raise ExperimentError(f"{where}: a log range needs low > 0")
    step = body.get("step")
    if step is not None and (not isinstance(step, numbers) or step <= 0 or log):
        raise ExperimentError(f"{where}: step must be a positive number, and not with log")
    return Param(name, low=low, high=high, log=log, step=step)


def check_values(agent: str, preset: str, space: dict[str, Param]) -> None:
    """Every end of every range and every choice must be a valid setting with the preset."""
    spec = get_agent(agent)
    for param in space.values():
        for value in param.extremes():
            try:
                resolve_config(agent, spec.config_cls, preset, {param.name: value})
            except ConfigError as err:
                raise ExperimentError(f"search space [{param.name}] = {value!r}: {err}") from None


def load_space(agent: str, preset: str, path: str | None) -> tuple[dict[str, Param], str]:
    """The checked search space (the agent's default, or ``path``) and the TOML text it came from."""
    text, source = read_space_text(agent, path)
    space = parse_space(agent, text, source)
    check_values(agent, preset, space)
    return space, text


def space_description(space: dict[str, Param]) -> dict[str, Any]:
    """The space as plain data: what a study records, so another space cannot join it."""
    return {
        name: {"choices": list(p.choices)}
        if p.choices
        else {"low": p.low, "high": p.high, "log": p.log, "step": p.step}
        for name, p in sorted(space.items())
    }


def preset_point(agent: str, preset: str, space: dict[str, Param]) -> dict[str, Any]:
    """The preset's own values of the searched settings that the space can suggest (lists as "a,b")."""
    from cartpole.core.config import config_to_dict

    config, settings = resolve_config(agent, get_agent(agent).config_cls, preset)
    values = config_to_dict(config) | config_to_dict(settings)
    point = {}
    for name, param in space.items():
        value = values[name]
        if isinstance(value, list | tuple):
            value = ",".join(str(v) for v in value)
        if param.holds(value):
            point[name] = value
    return point
