"""The ``cartpole`` command: parse arguments, dispatch, and turn known errors into one clear line."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from cartpole.cli import evaluate as eval_cmd
from cartpole.cli import runs as runs_cmd
from cartpole.cli import train as train_cmd
from cartpole.cli.errors import EXIT_BAD_INPUT
from cartpole.core.errors import InputError
from cartpole.core.version import __version__


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
    """Commands added by later modules (plot, record, serve) when they are present."""
    import importlib

    found = []
    for name in ("plot", "record", "serve"):
        try:
            found.append(importlib.import_module(f"cartpole.cli.{name}"))
        except ModuleNotFoundError as err:
            if err.name != f"cartpole.cli.{name}":
                raise
    return found


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.run(args) or 0)
    except (InputError, FileNotFoundError) as err:
        print(f"cartpole {args.command}: error: {err}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print(f"cartpole {args.command}: interrupted", file=sys.stderr)
        return 130
