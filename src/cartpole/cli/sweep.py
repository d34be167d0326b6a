"""``cartpole sweep``: tune an agent's settings with Optuna, K seeds per trial, on one machine or many."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from cartpole.cli.options import add_env_kwargs, add_slots, slots_of


def add_parser(sub: Any) -> None:
    parser = sub.add_parser(
        "sweep",
        help="tune an agent's settings with Optuna",
        description=(
            "Search AGENT's settings with Optuna (seeded TPE, pruning on the evaluations during training). "
            "Each trial trains the same seeds (--seeds, default 2: seeds 0-1); its objective is the "
            "median env steps to the first verified solve, a seed that does not solve counting twice "
            "the env steps it used. The study lives in "
            "RUNS_DIR/sweeps/NAME/journal.log, shared by the --workers processes, or in --storage "
            "postgresql://USER@HOST:PORT/DB, which the same command on several machines joins. --trials is "
            "the number of finished trials the study should hold; re-running adds trials or resumes. The "
            "best trial is written as RUNS_DIR/sweeps/NAME/best.toml, a preset: "
            "`cartpole train AGENT --preset RUNS_DIR/sweeps/NAME/best.toml`. Watch it live with "
            "`optuna-dashboard STORAGE`."
        ),
    )
    parser.add_argument("agent", metavar="AGENT", help="the agent to tune")
    parser.add_argument(
        "--preset",
        metavar="P",
        help="settings not searched (default: the agent's preset for --env, `cartpole presets`)",
    )
    parser.add_argument(
        "--trials", type=int, required=True, metavar="N", help="finished trials the study should hold"
    )
    parser.add_argument(
        "--seeds",
        metavar="SEEDS",
        help="the seeds every trial trains, as in train and compare: a count (2: seeds 0-1), a range "
        "(0-99), a list (3,5,8) or both (default: 2)",
    )
    parser.add_argument(
        "--seeds-per-trial", type=int, metavar="K", help="seeds 0..K-1 per trial (the same as --seeds K)"
    )
    parser.add_argument(
        "--workers",
        type=int,
        metavar="J",
        help="CPU slots: local worker processes on the CPU (default: 1; 0 where there are GPU slots)",
    )
    add_slots(parser, "--workers")
    parser.add_argument("--study", required=True, metavar="NAME", help="study name (and folder name)")
    parser.add_argument(
        "--storage",
        metavar="URL",
        help="share the study through this database: postgresql://USER@HOST:PORT/DB (needs the postgres "
        "extra; the same command on other machines joins it) or sqlite:///FILE.db (one machine)",
    )
    parser.add_argument("--budget", metavar="B", help="budget of every run (default: the preset's)")
    parser.add_argument("--space", metavar="FILE.toml", help="search space (default: the agent's own)")
    parser.add_argument("--sampler-seed", type=int, default=0, metavar="S", help="TPE seed (default: 0)")
    parser.add_argument(
        "--env", default="CartPole-v1", metavar="ID", help="env id or module:Id-vN (default: CartPole-v1)"
    )
    add_env_kwargs(parser)
    parser.add_argument("--runs-dir", default="runs", metavar="DIR", help="(default: runs)")
    parser.add_argument(
        "--tensorboard",
        action="store_true",
        help="also log every trial's runs as TensorBoard events in their RUN/tensorboard/, as train does: "
        "metrics, settings as hyperparameters with the final verdict as their metric, the command "
        "(`tensorboard --logdir RUNS_DIR/sweeps/STUDY/runs`; needs the tensorboard extra)",
    )
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from rich.console import Console

    from cartpole.experiments.sweep import make_spec, prepare_sweep, run_sweep
    from cartpole.training.request import parse_env_kwargs

    spec = make_spec(
        Path(args.runs_dir),
        args.study,
        args.agent,
        args.preset,
        args.trials,
        trial_seeds(args),
        env_id=args.env,
        budget=args.budget,
        space_file=args.space,
        storage=args.storage,
        sampler_seed=args.sampler_seed,
        env_kwargs=parse_env_kwargs(args.env_kwargs),
        tensorboard=args.tensorboard,
    )
    slots = slots_of(args, args.workers, "--workers")
    study = prepare_sweep(spec, slots)
    console = Console(soft_wrap=True, stderr=True)
    console.print(f"study {spec.name} in {spec.storage_label}", highlight=False)
    interrupted = False
    with SweepProgress(console, spec.trials) as progress:
        try:
            run_sweep(spec, study, slots, progress.update)
        except KeyboardInterrupt:
            interrupted = True
    best = spec.path / "best.toml"
    out = Console(soft_wrap=True)
    if best.is_file():
        out.print(f"best so far: {best}\n  cartpole train {spec.agent} --preset {best}", highlight=False)
    if interrupted:
        console.print(
            "interrupted: the study is consistent; re-run the same command to go on", highlight=False
        )
        return 130
    return 0


def trial_seeds(args: argparse.Namespace) -> list[int]:
    """The seeds of every trial: ``--seeds`` (train's and compare's syntax), or the earlier
    ``--seeds-per-trial K`` (seeds 0..K-1); 2 seeds when neither is given."""
    from cartpole.experiments.entries import ExperimentError
    from cartpole.training.session import parse_seeds

    if args.seeds is not None and args.seeds_per_trial is not None:
        raise ExperimentError("give --seeds or --seeds-per-trial, not both (--seeds K is K seeds per trial)")
    if args.seeds_per_trial is not None:
        if args.seeds_per_trial < 1:
            raise ExperimentError(f"--seeds-per-trial must be >= 1, got {args.seeds_per_trial}")
        return list(range(args.seeds_per_trial))
    return parse_seeds(args.seeds or "2")


class SweepProgress:
    """One progress display: finished trials of the study (all machines), pruned, best so far."""

    def __init__(self, console: Any, trials: int):
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

        self.progress = Progress(
            TextColumn("trials"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn("{task.fields[detail]}"),
            TimeElapsedColumn(),
            console=console,
        )
        self.task = self.progress.add_task("trials", total=trials, detail="")
        self.last = ""

    def __enter__(self) -> SweepProgress:
        self.progress.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.progress.stop()

    def update(self, counts: dict[str, int], best: Any) -> None:
        done = counts.get("COMPLETE", 0) + counts.get("PRUNED", 0)
        detail = f"pruned {counts.get('PRUNED', 0)}, running {counts.get('RUNNING', 0)}"
        if best is not None:
            detail += f", best {best.value:,.0f} env steps (trial {best.number})"
        self.progress.update(self.task, completed=done, detail=detail)
        line = f"trials {done}, {detail}"
        if not self.progress.console.is_terminal and line != self.last:
            self.progress.console.print(line, highlight=False)
        self.last = line
