"""The CLI's errors: bad input found after parsing, printed as one line with exit code 2."""

from __future__ import annotations

from cartpole.core.errors import InputError

EXIT_BAD_INPUT = 2
"""Exit code of every bad-input error (argparse uses 2 too)."""


class UsageError(InputError):
    """Bad input found after parsing (a flag's value, a combination of flags)."""
