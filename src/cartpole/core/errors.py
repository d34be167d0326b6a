"""Errors that mean "bad input a person can fix": the CLI prints them as one line and exits with 2."""

from __future__ import annotations


class InputError(Exception):
    """Base of every error caused by input (a flag, a setting, a file): one line, what to do."""

    field: str | None = None
    """Which input of a training request it is about, where known ("budget", "seeds", a setting's
    name, ...): the web app shows the message beside that field (``training/request.py``)."""


class ConfigError(InputError, ValueError):
    """A preset, an override or a config value is wrong."""
