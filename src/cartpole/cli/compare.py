"""``cartpole compare``: several agents/presets over many seeds, with a report and confidence intervals."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from cartpole.cli.options import add_env_kwargs, add_slots, slots_of
from cartpole.experiments.storage import DEFAULT_CLAIM_TIMEOUT


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
            "cleanly. With --storage URL the comparison NAME lives in that database and the same command "
            "run on many machines shares it: each (entry, seed) run is claimed by one worker, runs of a "
            "worker that dies are taken over after --claim-timeout, and every run's results are stored "
            "as it ends, so `--report --storage URL --name NAME` builds the whole report on any machine."
        ),
    )
    parser.add_argument(
        "entries",
        nargs="*",
        metavar="ENTRY",
        help="agent, agent:preset or agent:FILE.toml (not with --report); an agent alone takes its "
        "preset for --env (`cartpole presets`)",
    )
    parser.add_argument(
        "--seeds",
        default="5",
        metavar="SEEDS",
        help="the seeds of every entry, as in train and sweep: a count (5: seeds 0-4), a range (0-99), "
        "a list (3,5,8) or both (default: 5)",
    )
    parser.add_argument(
        "--first-seed", type=int, default=0, metavar="S", help="with a count N: seeds S..S+N-1 (default: 0)"
    )
    parser.add_argument(
        "--jobs",
        type=int,
        metavar="J",
        help="CPU slots: runs at a time on the CPU (default: 1; 0 where there are GPU slots)",
    )
    add_slots(parser, "--jobs")
    parser.add_argument(
        "--env",
        default="CartPole-v1",
        metavar="ID",
        help="Gymnasium env id, or module:Id-vN for an env that importing module registers (default: "
        "CartPole-v1)",
    )
    add_env_kwargs(parser)
    parser.add_argument("--budget", metavar="B", help="budget of every run (default: each preset's own)")
    parser.add_argument(
        "--name", metavar="NAME", help="experiment name (default: the entries joined by '_vs_')"
    )
    parser.add_argument("--runs-dir", default="runs", metavar="DIR", help="(default: runs)")
    parser.add_argument(
        "--storage",
        metavar="URL",
        help="share the comparison through this database: postgresql://USER@HOST:PORT/DB (needs the "
        "postgres extra; the same command on other machines joins it) or sqlite:///FILE.db (processes "
        "of one machine)",
    )
    parser.add_argument(
        "--chunk",
        type=int,
        default=10,
        metavar="K",
        help="with --storage: seeds of an entry a worker claims together and trains as one population "
        "(default: 10)",
    )
    parser.add_argument(
        "--claim-timeout",
        type=float,
        default=DEFAULT_CLAIM_TIMEOUT,
        metavar="SECONDS",
        help="with --storage, when the comparison is created: seconds without a heartbeat after which a "
        f"worker's claims are taken over (default: {DEFAULT_CLAIM_TIMEOUT:g})",
    )
    parser.add_argument(
        "--tensorboard",
        action="store_true",
        help="also log every run as TensorBoard events in its RUN/tensorboard/, as train does: metrics, "
        "settings as hyperparameters with the final verdict as their metric, the command (`tensorboard "
        "--logdir RUNS_DIR/experiments/NAME/runs`; needs the tensorboard extra)",
    )
    parser.add_argument(
        "--report",
        action="store_true",
        help="train nothing: write the report of experiment NAME from its records (with --storage: from "
        "the database, every machine's runs)",
    )
    parser.set_defaults(run=run)


def default_name(entries: list[Any]) -> str:
    return "_vs_".join(e.slug for e in entries)


def run(args: argparse.Namespace) -> int:
    from cartpole.experiments.entries import ExperimentError

    if args.report:
        return report_only(args)
    if not args.entries:
        raise ExperimentError("name at least one ENTRY to compare (or pass --report --name NAME)")
    if args.jobs is not None and args.jobs < 1:
        raise ExperimentError(f"--jobs must be >= 1, got {args.jobs}")
    if args.chunk < 1:
        raise ExperimentError(f"--chunk must be >= 1, got {args.chunk}")
    if args.first_seed < 0:
        raise ExperimentError(f"--first-seed must be >= 0, got {args.first_seed}")
    return train_and_report(args)


def report_only(args: argparse.Namespace) -> int:
    """``--report``: the report of an existing experiment, from its folder or its database."""
    from rich.console import Console

    from cartpole.experiments.compare import Experiment, check_name
    from cartpole.experiments.entries import ExperimentError
    from cartpole.experiments.report import Results, write_report
    from cartpole.experiments.shared import SharedComparison
    from cartpole.runs.atomic import write_json_atomic

    if args.entries:
        raise ExperimentError("--report takes no ENTRY: it reports what experiment NAME holds (give --name)")
    if not args.name:
        raise ExperimentError("--report needs --name NAME, the experiment to report")
    folder = Path(args.runs_dir) / "experiments" / check_name(args.name, "experiment")
    if args.storage:
        shared = SharedComparison.open(args.storage, args.name)
        results = Results.of_shared(shared)
        folder.mkdir(parents=True, exist_ok=True)
        write_json_atomic(
            folder / "experiment.json",
            {**shared.setup, "command": ["cartpole", *sys.argv[1:]], "storage": args.storage},
        )
    else:
        results = Results.of_experiment(Experiment.from_folder(Path(args.runs_dir), args.name))
    _, written = write_report(results, folder)
    print_report(Console(soft_wrap=True), folder, written)
    return 0


def print_report(out: Any, folder: Path, written: list[Path]) -> None:
    out.print((folder / "report.md").read_text(encoding="utf-8"), markup=False, highlight=False)
    out.print("wrote " + ", ".join(str(p) for p in written), highlight=False)


def train_and_report(args: argparse.Namespace) -> int:
    """Train the pending runs (this machine's share, with --storage), then write the report."""
    from rich.console import Console

    from cartpole.agents.presets import BY_ENV, DEFAULT_PRESET
    from cartpole.experiments.compare import Experiment
    from cartpole.experiments.entries import parse_entries
    from cartpole.experiments.report import Results, write_report
    from cartpole.experiments.shared import SharedComparison
    from cartpole.training.request import parse_env_kwargs
    from cartpole.training.session import parse_seeds

    slots = slots_of(args, args.jobs, "--jobs")
    seeds = parse_seeds(args.seeds, args.first_seed)
    entries = parse_entries(args.entries, args.env)
    experiment = Experiment.open(
        Path(args.runs_dir),
        args.name or default_name(entries),
        entries,
        seeds,
        args.env,
        args.budget,
        command=["cartpole", *sys.argv[1:]],
        env_kwargs=parse_env_kwargs(args.env_kwargs),
        tensorboard=args.tensorboard,
    )
    shared = None
    if args.storage:
        shared = SharedComparison.join(
            args.storage,
            experiment.folder.name,
            experiment.setup,
            entries,
            experiment.seeds,
            args.claim_timeout,
        )
    console = Console(soft_wrap=True, stderr=True)
    console.print(f"experiment: {experiment.folder}", highlight=False)
    if any(slot.device != "cpu" for slot in slots):
        console.print("worker slots: " + ", ".join(map(str, slots)), highlight=False)
    for entry in entries:
        if entry.picked and entry.preset != DEFAULT_PRESET:
            console.print(
                f"entry {entry.label}: {entry.agent}'s preset for {args.env} ({BY_ENV}; "
                f"write {entry.agent}:PRESET for another)",
                highlight=False,
            )
    interrupted = False
    with ExperimentProgress(console) as progress:
        try:
            if shared is None:
                problems = experiment.run(slots, progress.update)
            else:
                problems = experiment.run_shared(shared, slots, args.chunk, progress.update)
        except KeyboardInterrupt:
            interrupted, problems = True, []
    for line in problems:
        console.print(f"[red]{line}[/]", highlight=False)
    results = Results.of_experiment(experiment) if shared is None else Results.of_shared(shared)
    _, written = write_report(results, experiment.folder)
    print_report(Console(soft_wrap=True), experiment.folder, written)
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
