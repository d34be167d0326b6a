"""Errors that mean "bad input a person can fix": the CLI prints them as one line and exits with 2."""

from __future__ import annotations


class InputError(Exception):
    """Base of every error caused by input (a flag, a setting, a file): one line, what to do."""


class ConfigError(InputError, ValueError):
    """A preset, an override or a config value is wrong."""
