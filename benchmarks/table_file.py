"""A benchmark's current table, written where ``benchmarks/run.py`` finds it.

A script that takes ``--table NAME`` (:func:`add_table_arguments`) writes, when it ends, its table as
markdown and its raw results as JSON: ``benchmarks/results/NAME.md`` and ``NAME.json``. Both name the
command that made them, the date, the commit, the machine (CPU model, AVX-512 or not, CPUs) and its
load when the script started, so a table says where its figures come from. ``run.py`` re-runs chosen
tables and copies them into ``benchmarks/README.md`` and the README's "How fast" table.
"""

from __future__ import annotations

import argparse
import json
import shlex
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cpu import machine

from cartpole.runs.atomic import write_text_atomic

BENCHMARKS = Path(__file__).resolve().parent
RESULTS_DIR = BENCHMARKS / "results"
NOT_RECORDED_OPTIONS = ("--results-dir", "--note", "--json")
"""Options that change where a table (or a raw copy of its runs) goes or what its machine line says, never
its figures."""


def add_table_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--table",
        metavar="NAME",
        help="also write the table and the raw results as benchmarks/results/NAME.md and NAME.json "
        "(benchmarks/run.py names them)",
    )
    parser.add_argument("--results-dir", default=str(RESULTS_DIR), help="where --table writes")
    parser.add_argument(
        "--note", default="", help="said on the table's machine line, e.g. 'shared with other jobs'"
    )


@dataclass
class Table:
    """A table's rows, and what its JSON keeps beside them."""

    columns: list[str]
    rows: list[list[str]]
    summary: dict[str, Any] = field(default_factory=dict)
    """The figures other readers take from it (``run.py``'s "How fast" rows)."""
    results: Any = None
    """Every measurement, raw."""
    notes: list[str] = field(default_factory=list)
    """Lines under the table: targets met or not, figures that fit no row."""

    def markdown(self) -> str:
        lines = ["| " + " | ".join(self.columns) + " |", "|" + "---|" * len(self.columns)]
        lines += ["| " + " | ".join(str(cell) for cell in row) + " |" for row in self.rows]
        if self.notes:
            lines += ["", *self.notes]
        return "\n".join(lines)


def recorded_command(argv: list[str]) -> str:
    """``python benchmarks/SCRIPT ARGS`` as given, without the options that change no figure."""
    kept, skip = [], False
    for arg in argv[1:]:
        if skip:
            skip = False
            continue
        name = arg.split("=", 1)[0]
        if name in NOT_RECORDED_OPTIONS:
            skip = "=" not in arg
            continue
        kept.append(arg)
    script = Path(argv[0]).resolve()
    try:
        shown = script.relative_to(BENCHMARKS.parent)
    except ValueError:
        shown = script
    return shlex.join(["python", str(shown), *kept])


def commit() -> str | None:
    """The repository's commit, with "+changes" where tracked files differ from it."""

    def git(*args: str) -> str:
        return subprocess.run(
            ["git", *args], cwd=BENCHMARKS, capture_output=True, text=True, check=True
        ).stdout.strip()

    try:
        head = git("rev-parse", "--short", "HEAD")
        changed = git("status", "--porcelain", "--untracked-files=no")
    except (OSError, subprocess.CalledProcessError):
        return None
    return head + ("+changes" if changed else "")


def describe_machine(found: dict[str, Any]) -> str:
    """``AMD EPYC, AVX-512, 2 CPUs`` (or ``..., emulated AVX2 on AVX-512 (what), ...`` where the table ran
    under the AVX2 settings of ``cpu.AVX2_SETTINGS``, saying which kernels took them: a table made
    before NumPy's dispatch was among them says that NumPy's stayed on AVX-512): what a table's
    machine line and the README's rows say."""
    if found.get("emulated"):
        took = "numba, torch, MKL and NumPy kernels"
        if found.get("numpy_simd") in (None, "X86_V4"):
            took = "numba, torch and MKL kernels; NumPy's own on AVX-512"
        avx = f"emulated {found['emulated']} on AVX-512 ({took})"
    else:
        avx = "AVX-512" if found.get("avx512") else "no AVX-512"
    return f"{found.get('cpu', '?')}, {avx}, {found.get('cpus', '?')} CPUs"


def source_line(record: dict[str, Any]) -> str:
    """The line above a table: its command, date, commit, machine, load at start, and any note."""
    parts = [f"`{record['command']}`", record["date"]]
    if record.get("commit"):
        parts.append(f"at {record['commit']}")
    found = record["machine"]
    parts.append(describe_machine(found))
    if found.get("load_average") is not None:
        parts.append(f"load {found['load_average']:.1f} at start")
    if record.get("note"):
        parts.append(f"**{record['note']}**")
    return " · ".join(parts)


class Measurement:
    """Started with the script, before it works (the machine's load then); :meth:`finish` writes the
    table when ``--table`` asked for it."""

    def __init__(self, args: argparse.Namespace, argv: list[str] | None = None):
        self.args = args
        self.command = recorded_command(argv or sys.argv)
        self.machine = machine()
        self.started = time.time()

    def finish(self, table: Table) -> Path | None:
        """Write ``NAME.md`` and ``NAME.json`` (``--table NAME``); the markdown file's path, or None."""
        name = getattr(self.args, "table", None)
        if not name:
            return None
        folder = Path(self.args.results_dir)
        folder.mkdir(parents=True, exist_ok=True)
        record = {
            "table": name,
            "command": self.command,
            "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
            "seconds": round(time.time() - self.started, 1),
            "commit": commit(),
            "machine": self.machine,
            "note": self.args.note,
            "columns": table.columns,
            "rows": table.rows,
            "notes": table.notes,
            "summary": table.summary,
            "results": table.results,
        }
        write_text_atomic(folder / f"{name}.json", json.dumps(finite(record), indent=1) + "\n")
        markdown = folder / f"{name}.md"
        write_text_atomic(markdown, source_line(record) + "\n\n" + table.markdown() + "\n")
        print(f"wrote {markdown} and {name}.json", file=sys.stderr)
        return markdown


def finite(value: Any) -> Any:
    """``value`` with every infinite or NaN float as None (JSON has neither)."""
    if isinstance(value, float):
        return value if value == value and abs(value) != float("inf") else None
    if isinstance(value, dict):
        return {key: finite(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite(item) for item in value]
    return value
