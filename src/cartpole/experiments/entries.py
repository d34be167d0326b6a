"""What an experiment compares: entries ``agent``, ``agent:preset`` or ``agent:path/to/preset.toml``.
An entry that names no preset takes the agent's preset for the env, as ``cartpole train`` does."""

from __future__ import annotations

from dataclasses import dataclass, field

from cartpole.agents.presets import DEFAULT_PRESET, is_preset_file, resolve_preset
from cartpole.agents.registry import agent_names, get_agent
from cartpole.core.errors import InputError
from cartpole.core.file_names import portable_name
from cartpole.envs import env_info
from cartpole.training.config import resolve_config


class ExperimentError(InputError):
    """Bad input to an experiment or a sweep: shown as one line, exit code 2, nothing saved is lost."""


@dataclass(frozen=True)
class Entry:
    """One contestant: an agent with a preset (a name of the agent's, or a preset file)."""

    agent: str
    preset: str = DEFAULT_PRESET
    picked: bool = field(default=False, compare=False)
    """Whether the preset is the env's (``presets/by_env.toml``), none being named in the entry."""

    @property
    def label(self) -> str:
        """How the entry is written on the command line and in reports."""
        return self.agent if self.preset == DEFAULT_PRESET else f"{self.agent}:{self.preset}"

    @property
    def slug(self) -> str:
        """The label as a file-name part every OS accepts (``cem:my/fast.toml`` -> ``cem-my-fast.toml``)."""
        return portable_name(self.label)


def parse_entry(text: str, env_id: str = "CartPole-v1") -> Entry:
    """``agent``, ``agent:preset`` or ``agent:FILE.toml``, checked: the agent exists, the preset
    resolves and is made for ``env_id``'s kind of observations. ``agent`` alone takes its preset
    for ``env_id`` (:func:`~cartpole.agents.presets.resolve_preset`)."""
    agent, _, named = text.partition(":")
    if agent not in agent_names():
        raise ExperimentError(
            f"unknown agent {agent!r} in entry {text!r}; choose one of: {', '.join(agent_names())}"
        )
    env = env_info(env_id)
    try:
        get_agent(agent).check_env(env)
        preset = resolve_preset(agent, env, named or None)
        resolve_config(agent, get_agent(agent).config_cls, preset)
    except InputError as err:
        raise ExperimentError(f"entry {text!r}: {err}") from None
    return Entry(agent, preset, picked=not named)


def parse_entries(texts: list[str], env_id: str = "CartPole-v1") -> list[Entry]:
    """Entries in the order given, for ``env_id``; the same entry twice is an error."""
    entries = [parse_entry(t, env_id) for t in texts]
    labels = [e.label for e in entries]
    twice = sorted({label for label in labels if labels.count(label) > 1})
    if twice:
        raise ExperimentError(f"entry {twice[0]!r} is given twice")
    if len({e.slug for e in entries}) < len(entries):
        raise ExperimentError("two entries name the same preset file differently; give each once")
    return entries


__all__ = ["DEFAULT_PRESET", "Entry", "ExperimentError", "is_preset_file", "parse_entries", "parse_entry"]
