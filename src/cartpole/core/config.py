"""Typed configs from plain data: dataclasses filled from TOML or the command line, then checked.

Every agent config and the training settings are dataclasses; :func:`build_config` fills one from a
dict (strings from ``--set`` are converted by the field's type) and :func:`require` is the one-line
check their ``validate()`` methods use.
"""

from __future__ import annotations

import dataclasses
import types
import typing
from dataclasses import fields
from typing import Any

from cartpole.core.errors import ConfigError


def require(condition: bool, message: str) -> None:
    """Raise ConfigError(message) unless ``condition``: the one-line check configs use."""
    if not condition:
        raise ConfigError(message)


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


def config_to_dict(config: Any) -> dict[str, Any]:
    """A dataclass config as JSON-able data (tuples become lists)."""
    return dataclasses.asdict(config)
