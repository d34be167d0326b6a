"""``cartpole runs`` and ``cartpole presets``: what has been trained, and what can be."""

from __future__ import annotations

import argparse
import json
from dataclasses import asdict
from pathlib import Path
from typing import Any


def add_parser(sub: Any) -> None:
    parser = sub.add_parser(
        "runs",
        help="list training runs",
        description="A table of the run folders under --runs-dir, newest first.",
    )
    parser.add_argument("--runs-dir", default="runs", metavar="DIR", help="(default: runs)")
    parser.add_argument("--json", action="store_true", help="print the list as JSON")
    parser.set_defaults(run=list_runs_command)

    presets = sub.add_parser(
        "presets",
        help="list agents and their presets",
        description="Every agent, its presets and what each preset sets.",
    )
    presets.add_argument("agent", nargs="?", metavar="AGENT", help="show only this agent's presets")
    presets.set_defaults(run=presets_command)


def list_runs_command(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.table import Table

    from cartpole.runs import list_runs

    runs = list_runs(Path(args.runs_dir))
    if args.json:
        print(json.dumps([asdict(r) for r in runs], indent=2))
        return 0
    console = Console(soft_wrap=True)
    if not runs:
        console.print(f"no runs in {args.runs_dir}/ yet: make one with `cartpole train cem`")
        return 0
    table = Table(title=f"runs in {args.runs_dir}/")
    for column in ("run", "agent", "env", "seed", "state", "steps", "best eval", "solved?"):
        table.add_column(column, justify="right" if column in ("seed", "steps", "best eval") else "left")
    for r in runs:
        best = "-" if r.best_eval_mean is None else f"{r.best_eval_mean:.1f}"
        steps = "-" if r.env_steps is None else f"{r.env_steps:,}"
        solved = "[green]yes[/]" if r.solved else "no"
        state = r.state if r.problem is None else f"{r.state}: {r.problem}"
        table.add_row(
            r.name,
            r.agent or "?",
            r.env_id or "?",
            str(r.seed if r.seed is not None else "?"),
            state,
            steps,
            best,
            solved,
        )
    console.print(table)
    return 0


def presets_command(args: argparse.Namespace) -> int:
    from rich.console import Console

    from cartpole.agents.presets import preset_table
    from cartpole.agents.registry import agent_names, get_agent
    from cartpole.cli.errors import UsageError

    names = agent_names()
    if args.agent and args.agent not in names:
        raise UsageError(f"unknown agent {args.agent!r}; choose one of: {', '.join(names)}")
    console = Console(soft_wrap=True)
    for name in [args.agent] if args.agent else names:
        console.print(f"[bold]{name}[/]: {get_agent(name).summary}")
        for preset, values in preset_table(name).items():
            console.print(f"  [cyan]{preset}[/]: {values.get('description', '')}")
            settings = ", ".join(f"{k}={v}" for k, v in values.items() if k != "description")
            console.print(f"    {settings}", highlight=False)
    return 0
