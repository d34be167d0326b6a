"""Presets: named settings of each agent, kept as data in ``presets/<agent>.toml``."""

from __future__ import annotations

import tomllib
from importlib import resources
from typing import Any


def preset_table(agent: str) -> dict[str, dict[str, Any]]:
    """All presets of ``agent`` as read from its TOML file."""
    text = resources.files("cartpole.agents").joinpath("presets", f"{agent}.toml").read_text()
    return tomllib.loads(text)


def preset_names(agent: str) -> list[str]:
    return list(preset_table(agent))
