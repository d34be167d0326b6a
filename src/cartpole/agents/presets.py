"""Presets: named settings of each agent, kept as data in ``presets/<agent>.toml``, or preset files.

A preset file is a ``.toml`` file anywhere (for example the ``best.toml`` a sweep writes) holding one
table of settings, or exactly one named table of them.
"""

from __future__ import annotations

import tomllib
from importlib import resources
from pathlib import Path
from typing import Any

from cartpole.core.errors import ConfigError


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
