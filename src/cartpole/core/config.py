"""Typed configs from plain data: dataclasses filled from TOML or the command line, then checked.

Every agent config and the training settings are dataclasses; :func:`build_config` fills one from a
dict (strings from ``--set`` are converted by the field's type) and :func:`require` is the one-line
check their ``validate()`` methods use.
"""

from __future__ import annotations

import ast
import dataclasses
import functools
import inspect
import json
import math
import textwrap
import tomllib
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
                return _number(value, origin)
            elif origin is str:
                return str(value)
            elif origin is dict:
                return dict(value if isinstance(value, dict) else _table(str(value)))
            elif origin in (list, tuple):
                items = value if isinstance(value, list | tuple) else _items(str(value))
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
    raise ConfigError(f"{key}={setting_text(value)!r} is not a valid {name}{rule}")


def setting_text(value: Any) -> str:
    """A value as ``--set KEY=VALUE`` writes it, which :func:`build_config` reads back to the same
    value: ``true``, ``0.001``, ``none``, ``[64, 64]`` (a TOML array); text stays as it is."""
    if value is None:
        return "none"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_toml_value(item) for item in value) + "]"
    if isinstance(value, dict):
        return _toml_value(value)
    return str(value)


def _toml_value(value: Any) -> str:
    """``value`` as TOML writes it inline (tables ``{key = value}``; strings, numbers as JSON)."""
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k} = {_toml_value(v)}" for k, v in value.items()) + "}"
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_toml_value(item) for item in value) + "]"
    return json.dumps(value)


def _items(text: str) -> list[Any]:
    """A list from the command line: ``64,64``, or as the presets write it, ``[64, 64]`` and
    ``[[16, 8, 4], [32, 3, 1]]`` (a TOML array); ValueError if it is neither."""
    if not text.strip().startswith("["):
        return text.split(",")
    items = _toml_of(text, list)
    assert isinstance(items, list)
    return items


def plain_value(text: str) -> Any:
    """A value from the command line whose type no field gives (an env's keyword argument): what it
    reads as in TOML (``5`` an int, ``0.5`` a float, ``true`` a bool, ``[1, 2]`` a list, ``"x"`` or
    any other text a string)."""
    try:
        return tomllib.loads(f"value = {text}")["value"]
    except tomllib.TOMLDecodeError:
        return text


def _table(text: str) -> dict[str, Any]:
    """A table from the command line as TOML writes one inline: ``{gravity = 5.0, name = "x"}``;
    ValueError if it is not one."""
    table = _toml_of(text, dict)
    assert isinstance(table, dict)
    return table


def _toml_of(text: str, kind: type) -> Any:
    """``text`` read as a TOML value of ``kind`` (a list, a table); ValueError if it is not one."""
    try:
        value = tomllib.loads(f"value = {text}")["value"]
    except tomllib.TOMLDecodeError as err:
        raise ValueError(str(err)) from None
    if not isinstance(value, kind):
        raise ValueError(f"not a {'list' if kind is list else 'table'}: {text!r}")
    return value


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


def config_to_dict(config: Any) -> dict[str, Any]:
    """A dataclass config as JSON-able data (tuples become lists)."""
    return dataclasses.asdict(config)


@functools.cache
def field_docs(cls: type) -> dict[str, str]:
    """Each field's docstring (the string literal under it in the class body, its own or a base
    class's) as one line: Python keeps no attribute docstrings at run time, so they are read from the
    source (installed with the package). A field without one maps to ""."""
    docs: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        if not dataclasses.is_dataclass(klass):
            continue
        try:
            tree = ast.parse(textwrap.dedent(inspect.getsource(klass)))
        except (OSError, TypeError, SyntaxError):  # no source (a frozen app): no docs, nothing breaks
            continue
        body = tree.body[0].body if tree.body and isinstance(tree.body[0], ast.ClassDef) else []
        for node, after in zip(body, [*body[1:], None], strict=True):
            if isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
                docs[node.target.id] = _docstring(after)
    return {f.name: docs.get(f.name, "") for f in fields(cls)}


def _docstring(node: ast.stmt | None) -> str:
    """The string literal statement ``node`` as one line ("" if it is not one)."""
    value = node.value.value if isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant) else None
    return " ".join(value.split()) if isinstance(value, str) else ""
