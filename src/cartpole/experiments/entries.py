"""What an experiment compares: entries ``agent``, ``agent:preset`` or ``agent:path/to/preset.toml``."""

from __future__ import annotations

import re
from dataclasses import dataclass

from cartpole.agents.presets import is_preset_file
from cartpole.agents.registry import agent_names, get_agent
from cartpole.core.errors import ConfigError, InputError
from cartpole.training.config import resolve_config

DEFAULT_PRESET = "default"


class ExperimentError(InputError):
    """Bad input to an experiment or a sweep: shown as one line, exit code 2, nothing saved is lost."""


@dataclass(frozen=True)
class Entry:
    """One contestant: an agent with a preset (a name of the agent's, or a preset file)."""

    agent: str
    preset: str = DEFAULT_PRESET

    @property
    def label(self) -> str:
        """How the entry is written on the command line and in reports."""
        return self.agent if self.preset == DEFAULT_PRESET else f"{self.agent}:{self.preset}"

    @property
    def slug(self) -> str:
        """The label as a safe file-name part."""
        return re.sub(r"[^A-Za-z0-9._-]+", "-", self.label).strip("-")


def parse_entry(text: str) -> Entry:
    """``agent``, ``agent:preset`` or ``agent:FILE.toml``, checked: the agent exists, the preset resolves."""
    agent, _, preset = text.partition(":")
    if agent not in agent_names():
        raise ExperimentError(
            f"unknown agent {agent!r} in entry {text!r}; choose one of: {', '.join(agent_names())}"
        )
    entry = Entry(agent, preset or DEFAULT_PRESET)
    try:
        resolve_config(agent, get_agent(agent).config_cls, entry.preset)
    except ConfigError as err:
        raise ExperimentError(f"entry {text!r}: {err}") from None
    return entry


def parse_entries(texts: list[str]) -> list[Entry]:
    """Entries in the order given; the same entry twice is an error."""
    entries = [parse_entry(t) for t in texts]
    labels = [e.label for e in entries]
    twice = sorted({label for label in labels if labels.count(label) > 1})
    if twice:
        raise ExperimentError(f"entry {twice[0]!r} is given twice")
    if len({e.slug for e in entries}) < len(entries):
        raise ExperimentError("two entries name the same preset file differently; give each once")
    return entries


__all__ = ["DEFAULT_PRESET", "Entry", "ExperimentError", "is_preset_file", "parse_entries", "parse_entry"]
