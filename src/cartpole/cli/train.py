"""``cartpole train``: train an agent in a new run folder, or resume one."""

from __future__ import annotations

import argparse
import sys
from functools import partial
from typing import TYPE_CHECKING, Any

from rich.console import Console

from cartpole.agents.registry import DEFAULT_AGENT
from cartpole.cli.options import add_env_kwargs, env_overrides

if TYPE_CHECKING:
    from cartpole.runs import RunDir


def parse_overrides(pairs: list[str]) -> dict[str, Any]:
    from cartpole.cli.errors import UsageError

    overrides: dict[str, Any] = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or not key:
            raise UsageError(f"--set expects KEY=VALUE, got {pair!r}")
        overrides[key.strip().replace("-", "_")] = value.strip()
    return overrides


def add_parser(sub: Any) -> None:
    from cartpole.agents.registry import agent_names

    names = agent_names()
    parser = sub.add_parser(
        "train",
        help="train an agent on an environment",
        description=(
            "Train AGENT on ENV in a new run folder (runs/<env>__<agent>__s<seed>__<time>/) and print "
            "the verdict: the kept best policy judged on 100 fresh greedy episodes of Gymnasium's own "
            "env. Ctrl-C stops cleanly; --resume RUN_DIR continues."
        ),
        epilog=(
            f"agents: {', '.join(names)}. Presets: `cartpole presets AGENT`. Exit status: 0 when training "
            "and its verdict are done, whatever the verdict (it is in eval.json and printed last); 2 for "
            "bad input, a full disk or a damaged run; 130 when interrupted (Ctrl-C; resume it)."
        ),
    )
    parser.add_argument(
        "agent",
        nargs="?",
        choices=names,
        metavar="AGENT",
        help=f"one of: {', '.join(names)} (default: {DEFAULT_AGENT})",
    )
    parser.add_argument(
        "--env",
        default="CartPole-v1",
        metavar="ID",
        help="Gymnasium env id with Box observations and Discrete actions, or module:Id-vN for an env "
        "that importing module registers (default: CartPole-v1)",
    )
    add_env_kwargs(parser)
    parser.add_argument("--seed", type=int, default=0, metavar="N", help="training seed (default: 0)")
    parser.add_argument(
        "--preset",
        metavar="NAME|FILE.toml",
        help="hyperparameter preset of the agent, by name or as a .toml preset file such as a sweep's "
        "best.toml (default: the agent's preset for the env, `cartpole presets` lists them: e.g. pixels "
        "on cartpole/CartPolePixels-v1; default elsewhere)",
    )
    parser.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override one preset setting, e.g. --set lr=0.001 (repeatable)",
    )
    parser.add_argument(
        "--budget",
        metavar="B",
        help="stop at this budget: env steps (50000, 50k), episodes (300ep), "
        "generations of cem, random-search and hill-climbing (20gen) or time (90s, 5min); default: "
        "the preset's",
    )
    parser.add_argument(
        "--runs-dir", default="runs", metavar="DIR", help="where run folders go (default: runs)"
    )
    parser.add_argument(
        "--device",
        default="auto",
        choices=["auto", "cpu", "cuda"],
        help="torch device for neural agents (default: auto: CUDA when present; with --seeds, the CPU)",
    )
    parser.add_argument(
        "--no-stop-when-solved",
        action="store_true",
        help="keep training after the first verified solve, to the budget",
    )
    parser.add_argument(
        "--torch-threads",
        type=int,
        default=None,
        metavar="N",
        help="CPU threads for torch, and processes (at most 4) that draw Gymnasium's pictures in a "
        "pixel env's evaluations (default: 1, the least CPU for the small networks on state "
        "observations, one seed or a population: a second thread costs more CPU than it saves time, see "
        "benchmarks/population.py --population-threads 0; on image observations 0, where a conv net's "
        "batches keep every core busy); 0: torch's default, one per core",
    )
    parser.add_argument("--resume", metavar="RUN_DIR", help="continue this run from checkpoints/latest.pt")
    parser.add_argument(
        "--from-scratch",
        action="store_true",
        help="with --resume: train a run whose checkpoints/latest.pt is gone or cannot continue again "
        "from step 0 (without it, such a resume is refused, so that no training is thrown away unasked)",
    )
    parser.add_argument("--quiet", action="store_true", help="no progress output")
    # --- issue 5: TensorBoard (also passed to train() below) ---
    parser.add_argument(
        "--tensorboard",
        action="store_true",
        help="also log metrics as TensorBoard events in RUN/tensorboard/, with the run's settings as "
        "hyperparameters (the final verdict their metric) and its command (needs the tensorboard extra)",
    )
    # --- population training (run_population below) ---
    parser.add_argument(
        "--seeds",
        metavar="SEEDS",
        help="train these seeds in one process, a run folder each, as compare and sweep name seeds: a "
        "count (10: seeds 0-9), a range (0-99), a list (3,5,8) or both (0-9,20); every agent on every "
        "env, batched (each seed bit for bit its run alone). --resume of any of them continues them all",
    )
    parser.set_defaults(run=run)


def configure_process(torch_threads: int, seed: int) -> None:
    """The process-wide settings, decided once here and never by library code: torch's CPU thread
    count, and seeds for the global generators of Python, numpy and torch (our agents draw only from
    generators they own; this makes any library that draws from the global ones repeat too)."""
    import random

    import numpy as np
    import torch

    if torch_threads:
        torch.set_num_threads(torch_threads)
    seed %= 2**32  # numpy's range; a seed out of the run's range is refused later, in one line
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


def torch_threads_for(args: argparse.Namespace) -> int:
    """Training's default thread count (:func:`cartpole.training.threads.default_torch_threads`) for
    the env asked for, or the one recorded in the run folder being resumed."""
    from pathlib import Path

    from cartpole.core.errors import InputError
    from cartpole.runs import RunDir
    from cartpole.training.threads import default_torch_threads

    try:
        env_id = RunDir.open(Path(args.resume)).config()["env_id"] if args.resume else args.env
    except InputError:  # a bad run folder is reported, in one line, when the run starts
        return 1
    return default_torch_threads(env_id)


def run(args: argparse.Namespace) -> int:
    from cartpole.cli.errors import UsageError
    from cartpole.training import resume, train
    from cartpole.training.session import is_population_run

    if args.torch_threads is not None and args.torch_threads < 0:
        raise UsageError(f"--torch-threads must be >= 0, got {args.torch_threads}")
    if args.from_scratch and not args.resume:
        raise UsageError("--from-scratch goes with --resume RUN_DIR (a new run always starts from scratch)")
    population = args.seeds is not None or bool(args.resume and is_population_run(args.resume))
    threads = torch_threads_for(args) if args.torch_threads is None else args.torch_threads
    configure_process(threads, args.seed)
    console = Console(soft_wrap=True)
    if not args.resume:
        say_picked_preset(args, console)
    if population:
        return run_population(args)
    if args.resume:
        if args.agent or args.overrides or args.env_kwargs or args.budget is not None:
            raise UsageError(
                "--resume continues a run with its recorded config; drop AGENT/--set/--env-kwargs/--budget"
            )
        outcome = resume_unless_finished(resume, args, console)
        if outcome is None:
            return 0
        console.print(f"run: {outcome.run.path}")
    else:
        outcome = train(
            args.agent or DEFAULT_AGENT,
            args.env,
            seed=args.seed,
            preset=args.preset,
            overrides=parse_overrides(args.overrides) | env_overrides(args),
            budget=args.budget,  # checked with every other choice (training/request.py)
            runs_dir=args.runs_dir,
            device=args.device,
            stop_when_solved=False if args.no_stop_when_solved else None,
            quiet=args.quiet,
            command=["cartpole", *sys.argv[1:]],
            tensorboard=args.tensorboard,  # issue 5: --tensorboard
            announce=partial(name_runs, console, population=False),
        )
    state = outcome.state
    console.print(
        f"trained {state.env_steps:,} env steps, {state.episodes:,} episodes in {state.elapsed:.1f} s "
        f"({state.stop_detail})"
    )
    if outcome.signal is not None:
        console.print(
            "interrupted: checkpoints/latest.pt saved. Resume with:\n"
            f"  cartpole train --resume {outcome.run.path}"
        )
        return 128 + outcome.signal
    if state.solved_at_step is not None:
        at = f"{state.solved_at_step:,} env steps, {state.solved_at_seconds:.2f} s"
        console.print(f"solved in training: first at {at}")
    report = outcome.report
    if report is not None:
        judged = judged_checkpoint(outcome.run)
        console.print(f"verdict on {judged}, judged on {report.episodes} fresh episodes:")
        color = "green" if report.solved else "red"
        console.print(f"[bold {color}]{report.verdict}[/]", highlight=False)
        last = outcome.last_report
        if last is not None and last.solved != report.solved:  # the best and the last policy disagree
            console.print(
                f"the last policy (env step {state.env_steps:,}) on the same episodes: {last.verdict} "
                "(last_eval.json)",
                highlight=False,
            )
    return 0


def name_runs(console: Console, runs: dict[int, RunDir], population: bool) -> None:
    """Name the new run folder(s) as training starts, flushed at once: a kill -9 or the out-of-memory
    killer never reaches the end, and ``--resume`` needs the RUN."""
    from cartpole.core.seeding import describe_seeds

    first = runs[min(runs)].path
    if population:
        console.print(
            f"runs: {len(runs)} in {first.parent}/ (seeds {describe_seeds(list(runs))}), the first {first}",
            highlight=False,
        )
    else:
        console.print(f"run: {first}", highlight=False)
    console.file.flush()


def say_picked_preset(args: argparse.Namespace, console: Console) -> None:
    """Without --preset, say which preset the env's agent takes (when it is not "default")."""
    from cartpole.agents.presets import picked_preset_line

    line = None if args.preset else picked_preset_line(args.agent or DEFAULT_AGENT, args.env)
    if line:
        console.print(line, highlight=False)


def resume_unless_finished(resume_run: Any, args: argparse.Namespace, console: Console) -> Any:
    """``resume_run`` (a single run's or a population's resume) with the command's options; None, once
    it has said so, when there is nothing left to resume."""
    from cartpole.training import AlreadyFinished

    try:
        return resume_run(args.resume, quiet=args.quiet, device=args.device, from_scratch=args.from_scratch)
    except AlreadyFinished as done:
        console.print(str(done))
        return None


def judged_checkpoint(run: RunDir) -> str:
    """Which policy the verdict judged, for people: the kept best checkpoint, and when it was kept."""
    from cartpole.core.names import CheckpointName
    from cartpole.runs import CheckpointError, load_checkpoint

    try:
        step = load_checkpoint(run.checkpoint_path(CheckpointName.BEST)).meta.get("step")
    except CheckpointError:
        step = None
    at = f" (kept at env step {step:,})" if isinstance(step, int) else ""
    return f"the best checkpoint{at}, not the last policy"


# --- population training -------------------------------------------------------------


def run_population(args: argparse.Namespace) -> int:
    """``cartpole train AGENT --seeds 0-99`` (or ``--resume`` of a population's run)."""
    from cartpole.cli.errors import UsageError
    from cartpole.training.engine import population_summary
    from cartpole.training.session import parse_seeds, resume_population, train_population

    console = Console(soft_wrap=True)
    if args.resume:
        if (
            args.agent
            or args.overrides
            or args.env_kwargs
            or args.budget is not None
            or args.seeds is not None
        ):
            raise UsageError(
                "--resume continues a population with its recorded config; drop AGENT/--set/--budget/--seeds"
            )
        outcome = resume_unless_finished(resume_population, args, console)
        if outcome is None:
            return 0
    else:
        agent = args.agent or DEFAULT_AGENT
        seeds = parse_seeds(args.seeds)
        outcome = train_population(
            agent,
            seeds,
            args.env,
            preset=args.preset,
            overrides=parse_overrides(args.overrides) | env_overrides(args),
            budget=args.budget,
            runs_dir=args.runs_dir,
            device=args.device,
            stop_when_solved=False if args.no_stop_when_solved else None,
            quiet=args.quiet,
            command=["cartpole", *sys.argv[1:]],
            tensorboard=args.tensorboard,
            announce=partial(name_runs, console, population=True),
        )
    for line in population_summary(outcome):
        console.print(line, highlight=False)
    if outcome.signal is not None:
        first = outcome.runs[min(outcome.runs)]
        console.print(
            "interrupted: every seed saved checkpoints/latest.pt. Resume them all with:\n"
            f"  cartpole train --resume {first.path}"
        )
        return 128 + outcome.signal
    return 0
