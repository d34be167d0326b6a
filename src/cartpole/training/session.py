"""Start or resume training: ``train`` (one seed), ``train_population`` (``--seeds``) and their
resumes. Both start the same way and train through the one engine
(:func:`cartpole.training.engine.run_members`): a single run is a population of one.

This is the library form of ``cartpole train``; benchmarks, experiments and tests call it directly.
"""

from __future__ import annotations

import shutil
import sys
import uuid
from collections.abc import Callable, Sequence
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from cartpole.agents.population import Population
from cartpole.agents.registry import build_population
from cartpole.core.errors import ConfigError, InputError
from cartpole.core.names import CheckpointName, RunState, StopReason
from cartpole.core.seeding import MAX_TRAIN_SEED
from cartpole.envs import EnvInfo
from cartpole.envs.resumable_envs import why_episodes_restart
from cartpole.evaluation import EvalReport
from cartpole.runs import (
    Checkpoint,
    CheckpointError,
    RunDir,
    UnreadableCheckpoint,
    displayed_state,
    load_checkpoint,
)
from cartpole.training.budget import Budget
from cartpole.training.callbacks import require_tensorboard
from cartpole.training.engine import PopulationOutcome, SeedLearner, run_members
from cartpole.training.loop import Callback, LoopState
from cartpole.training.request import (
    MAX_SEEDS,
    check_memory,
    is_seed_count,
    parse_seeds,
    plan_training,
)
from cartpole.training.setup import RunSetup, resolve_device, run_record


@dataclass
class TrainOutcome:
    """What training one seed produced."""

    run: RunDir
    state: LoopState
    report: EvalReport | None
    """The final verdict: the kept best policy on 100 fresh episodes (None if interrupted)."""
    signal: int | None = None
    """The signal that interrupted training, if any."""
    last_report: EvalReport | None = None
    """The last policy on the verdict's own episodes, when training went on past the kept best one."""

    @classmethod
    def of_seed(cls, outcome: PopulationOutcome, seed: int) -> TrainOutcome:
        return cls(
            run=outcome.runs[seed],
            state=outcome.states[seed],
            report=outcome.reports.get(seed),
            signal=outcome.signal,
            last_report=outcome.last_reports.get(seed),
        )


# ----------------------------------------------------------------------------------------------
# Start
# ----------------------------------------------------------------------------------------------


def train(
    agent: str,
    env_id: str = "CartPole-v1",
    *,
    seed: int = 0,
    preset: str | None = None,
    overrides: dict[str, Any] | None = None,
    budget: Budget | str | None = None,
    runs_dir: Path | str = "runs",
    device: str = "auto",
    stop_when_solved: bool | None = None,
    quiet: bool = True,
    command: list[str] | None = None,
    tensorboard: bool = False,
    callbacks: Sequence[Callback] = (),
    announce: Callable[[dict[int, RunDir]], None] | None = None,
) -> TrainOutcome:
    """Train ``agent`` on ``env_id`` in a new run folder and return the outcome: a population of one.

    ``preset`` None takes the agent's preset for the env (``presets/by_env.toml``, else "default").

    With ``tensorboard`` the metrics also go to ``<run>/tensorboard/`` (needs the tensorboard extra).
    ``callbacks`` see every event after the standard ones (experiments time solves, sweeps prune).
    ``announce`` is given the run folder (by seed) as soon as it is made, before training (the CLI
    names it, so that a kill -9 leaves in the output the RUN that ``--resume`` needs).
    """
    if not 0 <= seed <= MAX_TRAIN_SEED:
        raise ConfigError(f"seed must be between 0 and {MAX_TRAIN_SEED}, got {seed}")
    outcome = start(
        agent, [seed], env_id, preset=preset, overrides=overrides, budget=budget, runs_dir=runs_dir,
        device=device, stop_when_solved=stop_when_solved, quiet=quiet, command=command, stream=None,
        tensorboard=tensorboard, callbacks=callbacks, announce=announce, population=False,
    )  # fmt: skip
    return TrainOutcome.of_seed(outcome, seed)


def train_population(
    agent: str,
    seeds: list[int],
    env_id: str = "CartPole-v1",
    *,
    preset: str | None = None,
    overrides: dict[str, Any] | None = None,
    budget: Budget | str | None = None,
    runs_dir: Path | str = "runs",
    device: str = "auto",
    stop_when_solved: bool | None = None,
    quiet: bool = True,
    command: list[str] | None = None,
    stream: TextIO | None = None,
    tensorboard: bool = False,
    callbacks: Sequence[Callback] = (),
    announce: Callable[[dict[int, RunDir]], None] | None = None,
) -> PopulationOutcome:
    """Train ``agent`` with every seed of ``seeds`` in one process; a run folder per seed. Their
    configs record the population (an id and the seeds): ``--resume`` of any member continues
    every unfinished member. ``callbacks`` (one list for all seeds) see every seed's events after
    the standard ones; ``announce`` is given the run folders, by seed, as soon as they are made."""
    if not seeds:
        raise InputError("no seeds to train")
    if len(set(seeds)) != len(seeds):
        raise InputError("each seed may appear once in a population")
    return start(
        agent, seeds, env_id, preset=preset, overrides=overrides, budget=budget, runs_dir=runs_dir,
        device=device, stop_when_solved=stop_when_solved, quiet=quiet, command=command, stream=stream,
        tensorboard=tensorboard, callbacks=callbacks, announce=announce, population=True,
    )  # fmt: skip


def start(
    agent: str,
    seeds: list[int],
    env_id: str,
    *,
    preset: str | None,
    overrides: dict[str, Any] | None,
    budget: Budget | str | None,
    runs_dir: Path | str,
    device: str,
    stop_when_solved: bool | None,
    quiet: bool,
    command: list[str] | None,
    stream: TextIO | None,
    tensorboard: bool,
    callbacks: Sequence[Callback],
    announce: Callable[[dict[int, RunDir]], None] | None,
    population: bool,
) -> PopulationOutcome:
    """Check everything, build the agent (spec, config) and the seeds' population once, make their run
    folders (each records the agent), train: the population and every seed's callbacks use the same
    agent."""
    if tensorboard:
        require_tensorboard()  # before a run folder is made
    command = command or python_command(
        agent, seeds, env_id, preset, overrides, budget, runs_dir, device, stop_when_solved, tensorboard,
        population,
    )  # fmt: skip
    plan = plan_training(
        agent, env_id, len(seeds), preset=preset, overrides=overrides, budget=budget,
        stop_when_solved=stop_when_solved,
    )  # fmt: skip
    spec, env, preset, config, settings, budget = (
        plan.spec, plan.env, plan.preset, plan.config, plan.settings, plan.budget
    )  # fmt: skip
    device = resolve_device(device, len(seeds))
    learner = build_population(spec, config, env, seeds, device)
    population_record = {"population": {"id": uuid.uuid4().hex[:12], "seeds": list(seeds)}}
    with ExitStack() as stack:
        setups, made = [], []
        try:
            for seed in seeds:
                run = RunDir.create(Path(runs_dir), env_id, agent, seed)
                made.append(run)
                stack.enter_context(run.lock())
                record = run_record(
                    agent, env_id, seed, preset, config, settings, overrides, budget, device, command
                )
                record |= (population_record if population else {}) | {"tensorboard": tensorboard}
                run.write_config(record)
                setups.append(RunSetup.of(run, record, spec, env, config, settings, budget))
        except BaseException:  # a full disk, say: no folder without its config, listed for ever
            stack.close()
            for run in made:
                shutil.rmtree(run.path, ignore_errors=True)
            raise
        if announce is not None:
            announce({setup.seed: setup.run for setup in setups})
        return run_members(learner, setups, {}, quiet, stream, callbacks)


def python_command(
    agent: str,
    seeds: list[int],
    env_id: str,
    preset: str | None,
    overrides: dict[str, Any] | None,
    budget: Budget | str | None,
    runs_dir: Path | str,
    device: str,
    stop_when_solved: bool | None,
    tensorboard: bool,
    population: bool,
) -> list[str]:
    """The ``cartpole train`` command line that starts the same training as this call from Python (a
    notebook's ``cartpole.train``, a script), as the CLI would write it, for the run's config.json (and
    so TensorBoard's command text and a hub card's "How it was trained"): not the Python process's
    own command line. A budget of several limits, which only Python can give, is written as its first."""
    from cartpole.core.seeding import describe_seeds
    from cartpole.training.request import TrainRequest, train_command

    settings = dict(overrides or {})
    env_kwargs = settings.pop("env_kwargs", None) or {}
    if stop_when_solved is True:
        settings["stop_when_solved"] = True
    text = budget if isinstance(budget, str) or budget is None else budget_text(budget)
    request = TrainRequest(agent, env_id, preset, tuple(seeds), text, settings, str(runs_dir))
    argv = train_command(request)
    for flag in ("--seed", "--seeds"):  # the seeds just after the agent, always named
        if flag in argv:
            del argv[argv.index(flag) : argv.index(flag) + 2]
    if not population:
        argv[3:3] = ["--seed", str(seeds[0])]
    else:  # --seeds N alone is a count: a population of one seed is N-N
        argv[3:3] = ["--seeds", describe_seeds(seeds) if len(seeds) > 1 else f"{seeds[0]}-{seeds[0]}"]
    if device != "auto":
        argv += ["--device", device]
    if stop_when_solved is False:
        argv.append("--no-stop-when-solved")
    if tensorboard:
        argv.append("--tensorboard")
    if env_kwargs:  # last: --env-kwargs takes every KEY=VALUE after it
        argv += ["--env-kwargs", *(f"{key}={env_kwarg_text(value)}" for key, value in env_kwargs.items())]
    return argv


def budget_text(budget: Budget) -> str | None:
    """``budget`` as ``--budget`` takes it (its first limit), or None where it has none."""
    for limit, value in budget.to_dict().items():
        return {"env_steps": f"{value}", "episodes": f"{value}ep", "iterations": f"{value}gen"}.get(
            limit, f"{value:g}s"
        )
    return None


def env_kwarg_text(value: Any) -> str:
    """A value as ``--env-kwargs KEY=VALUE`` reads it back: quoted where the bare text reads as another."""
    import json

    from cartpole.core.config import plain_value, setting_text

    text = setting_text(value)
    return text if plain_value(text) == value else json.dumps(value)


# ----------------------------------------------------------------------------------------------
# Resume
# ----------------------------------------------------------------------------------------------


class AlreadyFinished(Exception):
    """The run to resume has finished; there is nothing to do."""


class LostProgress(InputError):
    """A resume would start a run again from step 0: its ``latest.pt`` is gone."""


RESUMABLE_STOPS = (StopReason.INTERRUPTED, StopReason.FAILED, StopReason.BUDGET)
"""Stops a resume trains on from (the budget is checked again at start: a spent one stops at once).
After the others (solved, a callback's stop) a resume only gives the final verdict."""


def resume(
    run_path: Path | str,
    *,
    quiet: bool = True,
    device: str = "auto",
    callbacks: Sequence[Callback] = (),
    from_scratch: bool = False,
) -> TrainOutcome:
    """Continue a single run from ``checkpoints/latest.pt`` with its recorded config and budget.

    Any run that has no final verdict is accepted: interrupted, failed, crashed (its process was
    killed), or killed between the end of training and the verdict (then only the verdict is given).
    RunBusy if another process is training it. A run whose ``latest.pt`` is gone although its status
    records training is refused (LostProgress) unless ``from_scratch``: it would start again from 0.
    """
    run = RunDir.open(Path(run_path))
    outcome = resume_members([run], quiet, None, device, from_scratch, callbacks)
    return TrainOutcome.of_seed(outcome, next(iter(outcome.runs)))


def resume_population(
    run_path: Path | str,
    *,
    quiet: bool = True,
    stream: TextIO | None = None,
    device: str = "auto",
    from_scratch: bool = False,
) -> PopulationOutcome:
    """Continue every unfinished member of ``run_path``'s population from its ``latest.pt``, as
    :func:`resume` continues one run (a run of no population is a population of one)."""
    members = population_members(run_path)
    unfinished = [run for run in members if displayed_state(run.status()) is not RunState.FINISHED]
    if not unfinished:
        name = Path(run_path).name
        raise AlreadyFinished(f"every run of {name}'s population has finished; nothing to resume")
    return resume_members(unfinished, quiet, stream, device, from_scratch, ())


def resume_members(
    runs: list[RunDir],
    quiet: bool,
    stream: TextIO | None,
    device: str,
    from_scratch: bool,
    callbacks: Sequence[Callback],
) -> PopulationOutcome:
    """Lock ``runs``, check each can go on (LostProgress, a damaged ``latest.pt`` named by its path:
    before anything changes), put every seed back where its ``latest.pt`` left it, and train on."""
    with ExitStack() as stack:
        for run in runs:
            stack.enter_context(run.lock())
        setups = [check_resumable(run, from_scratch) for run in runs]
        first = setups[0]
        device = resolve_device(device, len(setups))
        seeds = [s.seed for s in setups]
        check_memory(first.spec, first.config, first.env, len(seeds))
        learner = build_population(first.spec, first.config, first.env, seeds, device)
        states, unusable = restore_all(setups, learner, from_scratch)
        if unusable:  # a failed load may have left part of its seed's state: start again from a new one
            learner = build_population(first.spec, first.config, first.env, seeds, device)
            states, _ = restore_all([s for s in setups if s.seed not in unusable], learner, False)
            states |= dict.fromkeys(unusable)
        for setup in setups:
            state = states[setup.seed]
            setup.run.truncate_metrics_after(state.env_steps if state else 0)
        if not quiet:
            print(resume_line(setups, states), file=stream or sys.stderr)
            fresh = fresh_episodes_line(first.env) if first.spec.iteration != "generation" else None
            if fresh and any(states.values()):  # (a generation's episodes all end within it)
                print(fresh, file=stream or sys.stderr)
        found = {seed: state for seed, state in states.items() if state is not None}
        return run_members(learner, setups, found, quiet, stream, callbacks)


def check_resumable(run: RunDir, from_scratch: bool) -> RunSetup:
    """The setup of ``run`` if a resume may go on with it; AlreadyFinished, LostProgress or a one-line
    error for a record it cannot read."""
    record = run.config()
    status = run.status(strict=True)
    run.eval_report(strict=True)  # a resume may rewrite it: never over a record it cannot read
    if displayed_state(status) is RunState.FINISHED:
        raise AlreadyFinished(
            f"run {run.name} already finished ({status.get('stop_detail') or 'done'}); nothing to resume"
        )
    setup = RunSetup.from_record(run, record)
    check_latest_exists(run, status, from_scratch)
    return setup


def population_members(run_path: Path | str) -> list[RunDir]:
    """The run folders of the population that ``run_path`` belongs to (beside it, same id)."""
    run = RunDir.open(Path(run_path))
    population = run.config().get("population")
    if not population:
        return [run]
    members = []
    for path in sorted(run.path.parent.iterdir()):
        try:
            other = RunDir.open(path).config()
        except InputError:
            continue
        if (other.get("population") or {}).get("id") == population["id"]:
            members.append(RunDir(path))
    return members


def is_population_run(run_path: Path | str) -> bool:
    return bool(RunDir.open(Path(run_path)).config().get("population"))


def check_latest_exists(run: RunDir, status: dict[str, Any], from_scratch: bool) -> None:
    """LostProgress when ``run`` has trained (its status says so) but has no ``latest.pt`` to go on
    from, unless ``from_scratch``: a silent restart from 0 would throw that training away."""
    latest = run.checkpoint_path(CheckpointName.LATEST)
    trained = status.get("env_steps")
    if from_scratch or latest.exists() or latest.is_symlink() or not isinstance(trained, int) or trained <= 0:
        return
    raise LostProgress(
        f"run {run.name} has no checkpoints/latest.pt although its status records {trained:,} env steps: "
        "a resume would train it again from step 0; to do that, add --from-scratch"
    )


def resume_line(setups: list[RunSetup], states: dict[int, LoopState | None]) -> str:
    """Where a resume goes on from, for people."""
    steps = [state.env_steps if state else 0 for state in states.values()]
    if len(setups) == 1:
        name = setups[0].run.name
        if states[setups[0].seed] is None:  # a latest.pt written at step 0 is one to go on from
            return f"resuming {name} from step 0 (no checkpoints/latest.pt to go on from)"
        return f"resuming {name} from env step {steps[0]:,} (checkpoints/latest.pt)"
    where = f"{min(steps):,}" if min(steps) == max(steps) else f"{min(steps):,} to {max(steps):,}"
    return (
        f"resuming {len(setups)} seed(s) of the population from env step {where} "
        "(each seed's checkpoints/latest.pt)"
    )


def fresh_episodes_line(env: EnvInfo) -> str | None:
    """What a resume says when it cannot continue the episodes in progress (resumable_envs), else None."""
    reason = why_episodes_restart(env)
    if reason is None:
        return None
    return f"the episodes in progress start afresh: their state cannot be saved ({reason})"


def load_latest(latest: Path) -> Checkpoint:
    """A run's ``latest.pt`` for a resume; CheckpointError saying that only it can resume the run."""
    try:
        return load_checkpoint(latest)
    except UnreadableCheckpoint as err:
        raise CheckpointError(
            f"cannot resume: {latest} {err.reason}. A run resumes only from its latest.pt (best.pt and "
            "solved.pt hold policies, which `cartpole eval` still judges): train a new run to go on"
        ) from err


def restore_all(
    setups: list[RunSetup], population: Population, from_scratch: bool
) -> tuple[dict[int, LoopState | None], list[int]]:
    """Each run's loop counters after :func:`restore` (CheckpointError for a ``latest.pt`` that
    cannot continue), and, with ``from_scratch``, the seeds whose ``latest.pt`` could not: they start
    again from step 0 instead."""
    states: dict[int, LoopState | None] = {}
    unusable = []
    for setup in setups:
        try:
            states[setup.seed] = restore(setup, population)
        except CheckpointError:
            if not from_scratch:
                raise
            unusable.append(setup.seed)
    return states, unusable


def restore(setup: RunSetup, population: Population) -> LoopState | None:
    """Load the run's ``latest.pt`` into its seed of ``population`` and return the loop counters to go
    on from; None (start over, as the run's seed makes it the same run) for a run killed before its
    first ``latest``. CheckpointError, in one line naming the file, for a checkpoint of another run or
    one that does not fit."""
    run = setup.run
    latest = run.checkpoint_path(CheckpointName.LATEST)
    if not latest.exists() and not latest.is_symlink():  # a dangling link is damage, not absence
        return None
    checkpoint = load_latest(latest)
    if not checkpoint.meta.get("resumable"):
        raise CheckpointError(f"{latest} is not a resumable checkpoint")
    if (checkpoint.agent, checkpoint.env_id) != (setup.spec.name, setup.env.env_id):
        raise CheckpointError(
            f"{latest} holds {checkpoint.agent} on {checkpoint.env_id}, but run {run.name} trains "
            f"{setup.spec.name} on {setup.env.env_id}: it belongs to another run"
        )
    seed = SeedLearner(population, setup.seed)
    try:
        seed.load_state_dict(checkpoint.tensors, checkpoint.meta["learner"])
        seed.policy().act(np.zeros((1, *setup.env.obs_shape), dtype=np.float32))  # weights of the right size?
        state = LoopState.from_dict(checkpoint.meta["loop"])
    except ConfigError as err:  # the learner says why, in one line
        raise CheckpointError(f"{latest}: {err}") from err
    except (KeyError, IndexError, TypeError, ValueError, RuntimeError, AttributeError) as err:
        raise CheckpointError(
            f"{latest} does not fit run {run.name}'s config ({type(err).__name__}: {err!s:.100}); "
            "it may come from another run: restore the run's own latest.pt, or train again"
        ) from err
    if state.stop_reason in RESUMABLE_STOPS:
        state.clear_stop()
    return state


__all__ = [
    "MAX_SEEDS",
    "AlreadyFinished",
    "LostProgress",
    "TrainOutcome",
    "is_population_run",
    "is_seed_count",
    "parse_seeds",
    "resume",
    "resume_population",
    "train",
    "train_population",
]
