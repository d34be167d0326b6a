"""The ``cartpole`` command: parse arguments, dispatch, and turn known errors into one clear line."""

from __future__ import annotations

import argparse
import errno
import os
import sys
from collections.abc import Sequence

from cartpole.cli import evaluate as eval_cmd
from cartpole.cli import runs as runs_cmd
from cartpole.cli import train as train_cmd
from cartpole.cli.allocator import keep_freed_memory
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
    """Commands added by later modules (plot, record, serve, compare, sweep, export) when they are present."""
    import importlib

    found = []
    for name in ("plot", "record", "serve", "compare", "sweep", "export"):
        try:
            found.append(importlib.import_module(f"cartpole.cli.{name}"))
        except ModuleNotFoundError as err:
            if err.name != f"cartpole.cli.{name}":
                raise
    return found


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    argv = list(sys.argv[1:] if argv is None else argv)
    if "--version" in argv and len(argv) > 1:
        parser.error(
            f"--version takes no other arguments, got {' '.join(a for a in argv if a != '--version')}"
        )
    args = parser.parse_args(argv)
    headless_pygame()
    keep_freed_memory()
    try:
        return int(args.run(args) or 0)
    except (InputError, FileNotFoundError) as err:
        print(f"cartpole {args.command}: error: {one_line(str(err))}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except BrokenPipeError:
        raise  # stdout was closed by its reader: run_main ends quietly
    except OSError as err:  # a full disk, a read-only folder, a file where a folder should be
        print(
            f"cartpole {args.command}: error: {one_line(describe_os_error(err, args.command))}",
            file=sys.stderr,
        )
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print(f"cartpole {args.command}: interrupted", file=sys.stderr)
        return 130


def headless_pygame() -> None:
    """No display and no sound card for pygame, which draws Gymnasium's ``rgb_array`` pictures
    here and in the picture workers this process starts: no command opens a window or plays a
    sound, and on a machine without a desktop session SDL prints ``error: XDG_RUNTIME_DIR is
    invalid or not set`` from every process that draws; nor does pygame greet on stdout (``--json``
    output stays JSON). Values the user set win."""
    os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
    os.environ.setdefault("SDL_AUDIODRIVER", "dummy")
    os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")


def one_line(message: str) -> str:
    """A message on one line: some library errors (torch's state-dict report) span several."""
    return " ".join(message.split())


OS_ERROR_HINTS = {
    errno.ENOSPC: "free some disk space, then try again",
    errno.EDQUOT: "free some space in your quota, then try again",
    errno.EROFS: "the file system is read-only: choose a writable folder (e.g. --runs-dir)",
    errno.EACCES: "you may not write there: choose another folder (e.g. --runs-dir) or fix its permissions",
    errno.EPERM: "you may not write there: choose another folder (e.g. --runs-dir) or fix its permissions",
    errno.ENOTDIR: "a part of this path is a file, not a folder: choose another path",
    errno.EISDIR: "this is a folder, not a file: give a file path",
    errno.ELOOP: "the path is a symbolic link loop: fix the link or choose another path",
    errno.EEXIST: "something is already there: choose another path",
    errno.EIO: "the disk failed to read or write: check it, then try again",
}
RESUME_HINTS = {
    "train": "a run continues with `cartpole train --resume RUN`",
    "compare": "the same command again resumes the experiment",
    "sweep": "the same command again resumes the study",
}
"""How the commands that train go on after a full disk or a failed disk; the others (plot, record,
eval, ...) only read runs and have nothing to resume."""


def describe_os_error(err: OSError, command: str) -> str:
    """One line for an OS error of ``command``: the file, what went wrong, and what to do about it."""
    what = err.strerror or str(err)
    where = f"{err.filename}: " if err.filename else ""
    hint = OS_ERROR_HINTS.get(err.errno or 0)
    if hint and err.errno in (errno.ENOSPC, errno.EIO) and command in RESUME_HINTS:
        hint += f"; {RESUME_HINTS[command]}"
    return f"{where}{what}" + (f" ({hint})" if hint else "")


def run_main() -> int:
    """The console entry point: ``main`` plus a quiet end when stdout is closed (``| head``)."""
    try:
        code = main()
        sys.stdout.flush()
    except BrokenPipeError:
        # The reader went away; Python would print a traceback on its final flush of stdout.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141  # 128 + SIGPIPE, as a shell pipeline expects
    return code
