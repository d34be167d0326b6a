"""``cartpole compare``: several agents/presets over many seeds, with a report and confidence intervals."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any


def add_parser(sub: Any) -> None:
    parser = sub.add_parser(
        "compare",
        help="compare agents/presets over many seeds",
        description=(
            "Train N seeds of each ENTRY (agent, agent:preset or agent:path/to/preset.toml), J at a time "
            "in worker processes, and write RUNS_DIR/experiments/NAME/: report.json, report.md (medians, "
            "IQRs and bootstrap 95% CIs of env steps, CPU and wall seconds to the first verified solve, "
            "unsolved runs censored at their budget; IQM of the final returns) and PNG curves. Every run "
            "is an ordinary run folder. Re-running the same command resumes; Ctrl-C stops every worker "
            "cleanly."
        ),
    )
    parser.add_argument("entries", nargs="+", metavar="ENTRY", help="agent, agent:preset or agent:FILE.toml")
    parser.add_argument("--seeds", type=int, default=5, metavar="N", help="seeds per entry (default: 5)")
    parser.add_argument("--first-seed", type=int, default=0, metavar="S", help="seeds S..S+N-1 (default: 0)")
    parser.add_argument("--jobs", type=int, default=1, metavar="J", help="runs at a time (default: 1)")
    parser.add_argument(
        "--env", default="CartPole-v1", metavar="ID", help="Gymnasium env id (default: CartPole-v1)"
    )
    parser.add_argument("--budget", metavar="B", help="budget of every run (default: each preset's own)")
    parser.add_argument(
        "--name", metavar="NAME", help="experiment name (default: the entries joined by '_vs_')"
    )
    parser.add_argument("--runs-dir", default="runs", metavar="DIR", help="(default: runs)")
    parser.set_defaults(run=run)


def default_name(entries: list[Any]) -> str:
    return "_vs_".join(e.slug for e in entries)


def run(args: argparse.Namespace) -> int:
    from rich.console import Console

    from cartpole.experiments.compare import Experiment
    from cartpole.experiments.entries import ExperimentError, parse_entries
    from cartpole.experiments.report import write_report

    if args.jobs < 1:
        raise ExperimentError(f"--jobs must be >= 1, got {args.jobs}")
    entries = parse_entries(args.entries)
    experiment = Experiment.open(
        Path(args.runs_dir),
        args.name or default_name(entries),
        entries,
        args.seeds,
        args.first_seed,
        args.env,
        args.budget,
        command=["cartpole", *sys.argv[1:]],
    )
    console = Console(soft_wrap=True, stderr=True)
    console.print(f"experiment: {experiment.folder}", highlight=False)
    interrupted = False
    with ExperimentProgress(console) as progress:
        try:
            problems = experiment.run(args.jobs, progress.update)
        except KeyboardInterrupt:
            interrupted, problems = True, []
    for line in problems:
        console.print(f"[red]{line}[/]", highlight=False)
    _, written = write_report(experiment)
    out = Console(soft_wrap=True)
    out.print((experiment.folder / "report.md").read_text(encoding="utf-8"), markup=False, highlight=False)
    out.print("wrote " + ", ".join(str(p) for p in written), highlight=False)
    if interrupted:
        console.print("interrupted: every run is saved; re-run the same command to resume", highlight=False)
        return 130
    return 1 if problems else 0


class ExperimentProgress:
    """One progress display for the whole experiment: runs done, solved so far, ETA."""

    def __init__(self, console: Any):
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TextColumn,
            TimeElapsedColumn,
            TimeRemainingColumn,
        )

        self.progress = Progress(
            TextColumn("runs"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn("solved {task.fields[solved]}"),
            TimeElapsedColumn(),
            TextColumn("ETA"),
            TimeRemainingColumn(),
            console=console,
            transient=False,
        )
        self.task = self.progress.add_task("runs", total=None, solved=0)

    def __enter__(self) -> ExperimentProgress:
        self.progress.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.progress.stop()

    def update(self, kind: str, done: int, solved: int, total: int) -> None:
        if kind == "start":  # reset: runs kept from before do not count towards the speed (the ETA)
            self.progress.reset(self.task, total=total, completed=done, solved=solved)
            return
        self.progress.update(self.task, completed=done, solved=solved)
        if not self.progress.console.is_terminal:
            self.progress.console.print(f"runs {done}/{total}, solved {solved}", highlight=False)
