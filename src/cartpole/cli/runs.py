"""``cartpole runs`` and ``cartpole presets``: what has been trained, and what can be."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from cartpole.runs import RunSummary


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
        description=(
            "Every agent, its presets, what each preset sets and the file it comes from; which preset "
            "each agent takes on which env when --preset is not given (presets by env); then the "
            "presets that sweeps under --runs-dir wrote (sweeps/NAME/best.toml). Any .toml preset file "
            "can be given to `cartpole train AGENT --preset FILE.toml`."
        ),
    )
    presets.add_argument("agent", nargs="?", metavar="AGENT", help="show only this agent's presets")
    presets.add_argument(
        "--runs-dir", default="runs", metavar="DIR", help="where to look for sweeps (default: runs)"
    )
    presets.set_defaults(run=presets_command)


def list_runs_command(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.table import Table

    from cartpole.runs import list_runs

    runs_dir = Path(args.runs_dir)
    runs = list_runs(runs_dir)
    if args.json:
        print(json.dumps([run_as_json(r, runs_dir) for r in runs], indent=2))
        return 0
    console = Console(soft_wrap=True)
    if not console.is_terminal:
        console.width = PIPED_WIDTH  # piped or redirected: whole names and problems, never "CartPol…"
    if not runs:
        console.print(f"no runs in {args.runs_dir}/ yet: make one with `cartpole train cem`")
        return 0
    table = Table(title=f"runs in {args.runs_dir}/")
    for column in ("run", "agent", "env", "seed", "state", "steps", "best eval", "solved?"):
        table.add_column(
            column,
            justify="right" if column in ("seed", "steps", "best eval") else "left",
            overflow="fold" if column in ("run", "state") else "ellipsis",
        )
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
            style="red" if r.problem else None,
        )
    console.print(table)
    return 0


PIPED_WIDTH = 10_000
"""Console width when stdout is not a terminal: wide enough that no cell is cut."""


def run_as_json(summary: RunSummary, runs_dir: Path) -> dict[str, Any]:
    """One run for scripts: the same facts as the table, with the path relative to the runs dir."""
    return {
        "name": summary.name,
        "path": Path(summary.path).relative_to(runs_dir).as_posix(),
        "agent": summary.agent,
        "preset": summary.preset,
        "env_id": summary.env_id,
        "seed": summary.seed,
        "state": summary.state,
        "env_steps": summary.env_steps,
        "episodes": summary.episodes,
        "best_eval_mean": summary.best_eval_mean,
        "solved": summary.solved,
        "verdict": summary.verdict,
        "created": summary.created,
        "problem": summary.problem,
    }


def presets_command(args: argparse.Namespace) -> int:
    from rich.console import Console

    from cartpole.agents.presets import by_env_source, preset_source, preset_table, presets_by_env
    from cartpole.agents.registry import agent_names, get_agent
    from cartpole.cli.errors import UsageError
    from cartpole.experiments.best import sweep_presets

    names = agent_names()
    if args.agent and args.agent not in names:
        raise UsageError(f"unknown agent {args.agent!r}; choose one of: {', '.join(names)}")
    console = Console(soft_wrap=True)
    shown = [args.agent] if args.agent else names
    for name in shown:
        console.print(f"[bold]{name}[/]: {get_agent(name).summary}")
        console.print(f"  from {preset_source(name)}", highlight=False)
        for preset, values in preset_table(name).items():
            _print_preset(console, preset, values)
    console.print(f"[bold]presets by env[/] without --preset (from {by_env_source()}; elsewhere: default):")
    for env_id, picks in presets_by_env().items():
        listed = [f"{agent} {preset}" for agent, preset in picks.items() if agent in shown]
        if listed:
            console.print(f"  {env_id}: {', '.join(listed)}", highlight=False)
    found = [p for p in sweep_presets(Path(args.runs_dir)) if p.agent in shown]
    if found:
        console.print(f"[bold]sweep presets[/] in {args.runs_dir}/ (use --preset FILE.toml):")
    for item in found:
        _print_preset(console, f"{item.path} ({item.agent})", item.values)
    return 0


def _print_preset(console: Any, name: str, values: dict[str, Any]) -> None:
    console.print(f"  [cyan]{name}[/]: {values.get('description', '')}", highlight=False)
    settings = ", ".join(f"{k}={v}" for k, v in values.items() if k != "description")
    console.print(f"    {settings}", highlight=False)
    console.print(f"    solves: {stop_rule(values)}", highlight=False)


def stop_rule(values: dict[str, Any]) -> str:
    """What a preset's solve does to its training, in words (TrainSettings' stop_when_solved and
    confirm_solves, the defaults where the preset leaves them)."""
    from cartpole.training.config import TrainSettings

    defaults = TrainSettings()
    if not values.get("stop_when_solved", defaults.stop_when_solved):
        return "no solve stops training (the whole budget runs); the verdict judges the kept best"
    if values.get("confirm_solves", defaults.confirm_solves):
        return "a passing 100-episode evaluation stops training once the next 100 episodes pass too"
    return "the first passing 100-episode evaluation stops training (no second one: confirm_solves=false)"
