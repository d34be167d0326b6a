"""The ``cartpole`` command: parse arguments, dispatch, and turn known errors into one clear line."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from cartpole import __version__
from cartpole.cli import evaluate as eval_cmd
from cartpole.cli import runs as runs_cmd
from cartpole.cli import train as train_cmd

EXIT_BAD_INPUT = 2


class UsageError(Exception):
    """Bad input found after parsing: printed as one line, exit code 2."""


class Parser(argparse.ArgumentParser):
    """argparse, but errors are one line (``cartpole train: error: ...``) without the usage dump."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {message} (see `{self.prog} --help`)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(
        prog="cartpole",
        description="Train agents on CartPole, prove they solve it, watch them, play it yourself.",
    )
    parser.add_argument("--version", action="version", version=f"cartpole {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=Parser)
    sub.required = True
    for module in (train_cmd, eval_cmd, runs_cmd):
        module.add_parser(sub)
    for module in _optional_commands():
        module.add_parser(sub)
    return parser


def _optional_commands() -> list:
    """Commands added by later modules (plot, record, serve, compare, sweep) when they are present."""
    import importlib

    found = []
    for name in ("plot", "record", "serve", "compare", "sweep"):
        try:
            found.append(importlib.import_module(f"cartpole.cli.{name}"))
        except ModuleNotFoundError as err:
            if err.name != f"cartpole.cli.{name}":
                raise
    return found


def known_errors() -> tuple[type[BaseException], ...]:
    """Errors that mean bad input: shown as one line, never as a traceback."""
    from cartpole.envs import UnsupportedEnvError
    from cartpole.runs import CheckpointError, RunError
    from cartpole.training import ConfigError

    return (UsageError, ConfigError, UnsupportedEnvError, CheckpointError, RunError, FileNotFoundError)


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.run(args) or 0)
    except known_errors() as err:
        print(f"cartpole {args.command}: error: {err}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print(f"cartpole {args.command}: interrupted", file=sys.stderr)
        return 130
