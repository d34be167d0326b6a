"""Start or resume a training run: build the agent, the callbacks and the run folder, then train.

This is the library form of ``cartpole train``; benchmarks and tests call it directly.
"""

from __future__ import annotations

import signal
import sys
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager, suppress
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from cartpole.agents.registry import AgentSpec, agent_names, get_agent
from cartpole.core.config import build_valid_config, config_to_dict
from cartpole.core.errors import ConfigError, InputError
from cartpole.core.names import CheckpointName, RunState, StopReason
from cartpole.core.seeding import MAX_TRAIN_SEED, final_eval_seed
from cartpole.core.version import __version__
from cartpole.envs import EnvInfo, check_simulator, env_info
from cartpole.evaluation import MIN_EPISODES_FOR_SOLVED, EvalReport, Policy, evaluate
from cartpole.runs import (
    Checkpoint,
    CheckpointError,
    LiveStatus,
    RunDir,
    UnreadableCheckpoint,
    displayed_state,
    load_checkpoint,
)
from cartpole.runs.run_dir import utc_now
from cartpole.training.budget import Budget, parse_budget
from cartpole.training.callbacks import (
    BudgetCallback,
    CheckpointCallback,
    CheckpointSchedule,
    EvalCallback,
    MetricsCallback,
    ProgressCallback,
    StatusCallback,
    StopWhenSolved,
    TensorBoardCallback,
    require_tensorboard,
    status_fields,
)
from cartpole.training.config import TrainSettings, resolve_config
from cartpole.training.loop import Callback, LoopState, TrainingLoop


@dataclass
class TrainOutcome:
    """What a training session produced."""

    run: RunDir
    state: LoopState
    report: EvalReport | None
    """The final verdict: the kept best policy on 100 fresh episodes (None if interrupted)."""
    signal: int | None = None
    """The signal that interrupted training, if any."""
    last_report: EvalReport | None = None
    """The last policy on the verdict's own episodes, when training went on past the kept best one."""


def resolve_device(device: str) -> str:
    """``auto`` -> ``cuda`` when a GPU is present, else ``cpu``; decided once, at start."""
    import torch

    if device == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    if device not in ("cpu", "cuda"):
        raise ConfigError(f"unknown device {device!r}; use auto, cpu or cuda")
    if device == "cuda" and not torch.cuda.is_available():
        raise ConfigError("--device cuda was asked for but no CUDA GPU is available; use auto or cpu")
    return device


STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


@contextmanager
def stop_on_signals(loop: TrainingLoop) -> Iterator[list[int]]:
    """While training, SIGINT/SIGTERM finish the current step and stop cleanly."""
    received: list[int] = []

    def handler(signum: int, frame: Any) -> None:
        received.append(signum)
        loop.request_stop(StopReason.INTERRUPTED, f"interrupted ({signal.Signals(signum).name})")

    with signal_handler(handler):
        yield received


class Interrupted(Exception):
    """A stop signal arrived while the final verdict was being judged."""

    def __init__(self, signum: int):
        super().__init__(f"interrupted ({signal.Signals(signum).name})")
        self.signum = signum


@contextmanager
def interrupt_on_signals() -> Iterator[None]:
    """While judging the verdict, SIGINT/SIGTERM abandon it at once (raise :class:`Interrupted`)."""

    def handler(signum: int, frame: Any) -> None:
        raise Interrupted(signum)

    with signal_handler(handler):
        yield


@contextmanager
def signal_handler(handler: Any) -> Iterator[None]:
    previous = {s: signal.signal(s, handler) for s in STOP_SIGNALS}
    try:
        yield
    finally:
        for s, h in previous.items():
            signal.signal(s, h)


@dataclass(frozen=True)
class RunSetup:
    """Everything a run is trained with, rebuilt from its ``config.json`` (so a resume is the same)."""

    run: RunDir
    spec: AgentSpec
    env: EnvInfo
    seed: int
    config: Any
    settings: TrainSettings
    budget: Budget
    tensorboard: bool
    meta: dict[str, Any]
    """What every checkpoint of the run records about it."""

    @classmethod
    def from_record(cls, run: RunDir, record: dict[str, Any]) -> RunSetup:
        if record["agent"] not in agent_names():
            raise ConfigError(f"{run.path / 'config.json'} names an unknown agent {record['agent']!r}")
        missing = [key for key in ("config", "settings", "budget") if key not in record]
        if missing:
            raise ConfigError(f"{run.path / 'config.json'} records no {missing[0]!r}: it cannot be resumed")
        if not 0 <= record["seed"] <= MAX_TRAIN_SEED:
            raise ConfigError(f"{run.path / 'config.json'} records seed {record['seed']}, out of range")
        spec = get_agent(record["agent"])
        return cls(
            run=run,
            spec=spec,
            env=env_info(record["env_id"]),
            seed=record["seed"],
            config=build_valid_config(spec.config_cls, record["config"]),
            settings=build_valid_config(TrainSettings, record["settings"]),
            budget=Budget.from_dict(record["budget"]),
            tensorboard=bool(record.get("tensorboard", False)),
            meta={k: record[k] for k in ("agent", "env_id", "seed", "preset", "config")},
        )


def make_callbacks(
    setup: RunSetup,
    status: LiveStatus,
    quiet: bool,
    extra: Sequence[Callback] = (),
    *,
    evaluator: Callable[[TrainingLoop], EvalReport | None] | None = None,
    flush_seconds: float = MetricsCallback.FLUSH_SECONDS,
) -> list[Callback]:
    """The standard callbacks, in the order they must see events; ``extra`` ones see them last.

    ``evaluator`` may hand the evaluation callback a report computed elsewhere (a population
    evaluates its seeds together); ``flush_seconds`` is how often metric rows and status are written.
    """
    run, settings = setup.run, setup.settings
    callbacks: list[Callback] = [
        BudgetCallback(setup.budget),
        EvalCallback(setup.env, setup.seed, settings, evaluator),
    ]
    if settings.stop_when_solved:
        callbacks.append(StopWhenSolved())
    # Metrics before checkpoints: a step's rows are pending before ``latest`` is saved, which writes
    # them first, so a resume from ``latest`` continues the rows without a gap even after a kill -9.
    metrics = MetricsCallback(run, flush_seconds)
    schedule = CheckpointSchedule.from_settings(setup.budget, settings)
    callbacks += [
        metrics,
        CheckpointCallback(run, setup.spec, setup.meta, schedule, metrics),
        StatusCallback(status, flush_seconds),
    ]
    if setup.tensorboard:
        callbacks.append(TensorBoardCallback(run, metrics))
    if not quiet:
        callbacks.append(ProgressCallback(setup.budget, setup.spec.iteration))
    return callbacks + list(extra)


def final_verdict(setup: RunSetup) -> EvalReport:
    """Re-evaluate the kept best checkpoint on seeds no training or evaluation used: the verdict.

    The seeds follow from the run's seed, so the same run gives the same verdict; ``cartpole eval``
    judges it again on any other seeds.
    """
    run = setup.run
    policy = setup.spec.policy_from_checkpoint(load_checkpoint(run.checkpoint_path(CheckpointName.BEST)))
    report = play_verdict_episodes(setup, policy)
    run.write_eval(report.to_dict())
    return report


def play_verdict_episodes(setup: RunSetup, policy: Policy) -> EvalReport:
    """``policy`` on the run's verdict episodes: ``max(eval_episodes, 100)`` from ``final_eval_seed``."""
    settings = setup.settings
    return evaluate(
        policy,
        setup.env.env_id,
        max(settings.eval_episodes, MIN_EPISODES_FOR_SOLVED),
        seed=final_eval_seed(setup.seed),
        simulator=check_simulator(settings.eval_simulator),
    )


def went_past_best(run: RunDir, state: LoopState) -> bool:
    """Whether training went on after the kept best checkpoint (it did not stop at a solve)."""
    if state.stop_reason is StopReason.SOLVED:
        return False
    return load_checkpoint(run.checkpoint_path(CheckpointName.BEST)).meta.get("step") != state.env_steps


def last_policy_score(setup: RunSetup, learner: Any, state: LoopState) -> EvalReport | None:
    """When training went on past the kept best checkpoint, the last policy played on the verdict's
    own episodes, written to ``last_eval.json``: a policy that collapsed after an early best shows
    beside a verdict that judged the best. None when the two are the same."""
    if not went_past_best(setup.run, state):
        return None
    report = play_verdict_episodes(setup, learner.policy())
    setup.run.write_last_eval(report.to_dict() | {"step": state.env_steps})
    return report


def run_loop(
    setup: RunSetup, learner: Any, state: LoopState | None, quiet: bool, extra: Sequence[Callback] = ()
) -> TrainOutcome:
    """Drive the loop with the standard callbacks, then give the verdict unless interrupted.

    ``status.json`` says "running" (with a heartbeat) until ``latest.pt`` and the verdict are on disk;
    only then "finished". A kill, a signal or an error before that leaves a run ``--resume`` accepts:
    it trains on, or, when training was complete, only gives the verdict.
    """
    with LiveStatus(setup.run) as status:
        loop = TrainingLoop(learner, make_callbacks(setup, status, quiet, extra), state)
        try:
            with stop_on_signals(loop) as received:
                loop.run()
            if received:
                status.write(RunState.INTERRUPTED, status_fields(loop.state))
                return TrainOutcome(setup.run, loop.state, None, signal=received[0])
            with interrupt_on_signals():
                report = final_verdict(setup)
                last = last_policy_score(setup, learner, loop.state)
        except Interrupted as stop:
            loop.state.stop_detail = f"{loop.state.stop_detail}; verdict {stop}"
            status.write(RunState.INTERRUPTED, status_fields(loop.state))
            return TrainOutcome(setup.run, loop.state, None, signal=stop.signum)
        except BaseException:
            write_failed(status, loop.state)
            raise
        status.write(RunState.FINISHED, status_fields(loop.state) | {"solved": report.solved})
        return TrainOutcome(setup.run, loop.state, report, last_report=last)


def write_failed(status: LiveStatus, state: LoopState) -> None:
    """Record the failure if the disk lets us; if not, "running" with a dead process reads as crashed."""
    with suppress(OSError):
        status.write(RunState.FAILED, status_fields(state))


def run_record(
    agent: str,
    env_id: str,
    seed: int,
    preset: str,
    config: Any,
    settings: TrainSettings,
    overrides: dict[str, Any] | None,
    budget: Budget,
    device: str,
    command: list[str] | None,
) -> dict[str, Any]:
    """What a run's config.json holds: everything ``resume`` needs to continue it."""
    return {
        "agent": agent,
        "env_id": env_id,
        "seed": seed,
        "preset": preset,
        "config": config_to_dict(config),
        "settings": config_to_dict(settings),
        "overrides": overrides or {},
        "budget": budget.to_dict(),
        "device": device,
        "command": command or list(sys.argv),
        "package_version": __version__,
        "created": utc_now(),
        "tensorboard": False,
    }


def train(
    agent: str,
    env_id: str = "CartPole-v1",
    *,
    seed: int = 0,
    preset: str = "default",
    overrides: dict[str, Any] | None = None,
    budget: Budget | str | None = None,
    runs_dir: Path | str = "runs",
    device: str = "auto",
    stop_when_solved: bool | None = None,
    quiet: bool = True,
    command: list[str] | None = None,
    tensorboard: bool = False,
    callbacks: Sequence[Callback] = (),
) -> TrainOutcome:
    """Train ``agent`` on ``env_id`` in a new run folder and return the outcome.

    With ``tensorboard`` the metrics also go to ``<run>/tensorboard/`` (needs the tensorboard extra).
    ``callbacks`` see every event after the standard ones (experiments time solves, sweeps prune).
    """
    if tensorboard:
        require_tensorboard()  # before a run folder is made
    spec = get_agent(agent)
    env = env_info(env_id)
    if not 0 <= seed <= MAX_TRAIN_SEED:
        raise ConfigError(f"seed must be between 0 and {MAX_TRAIN_SEED}, got {seed}")
    config, settings = resolve_config(agent, spec.config_cls, preset, overrides)
    if stop_when_solved is not None:
        settings.stop_when_solved = stop_when_solved
    if isinstance(budget, str):
        budget = parse_budget(budget)
    budget = budget or parse_budget(settings.budget)
    device = resolve_device(device)
    learner = spec.make_learner(config, env, seed, device)
    record = run_record(agent, env_id, seed, preset, config, settings, overrides, budget, device, command)
    record["tensorboard"] = tensorboard
    run = RunDir.create(Path(runs_dir), env_id, agent, seed)
    with run.lock():
        run.write_config(record)
        return run_loop(RunSetup.from_record(run, record), learner, None, quiet, callbacks)


class AlreadyFinished(Exception):
    """The run to resume has finished; there is nothing to do."""


def resume(
    run_path: Path | str,
    *,
    quiet: bool = True,
    device: str = "auto",
    callbacks: Sequence[Callback] = (),
    from_scratch: bool = False,
) -> TrainOutcome:
    """Continue a run from ``checkpoints/latest.pt`` with its recorded config and budget.

    Any run that has no final verdict is accepted: interrupted, failed, crashed (its process was
    killed), or killed between the end of training and the verdict (then only the verdict is given).
    RunBusy if another process is training it. A run whose ``latest.pt`` is gone although its status
    records training is refused (LostProgress) unless ``from_scratch``: it would start again from 0.
    """
    run = RunDir.open(Path(run_path))
    with run.lock():
        record = run.config()
        status = run.status(strict=True)
        run.eval_report(strict=True)  # a resume may rewrite it: never over a record it cannot read
        if displayed_state(status) is RunState.FINISHED:
            raise AlreadyFinished(
                f"run {run.name} already finished ({status.get('stop_detail') or 'done'}); nothing to resume"
            )
        setup = RunSetup.from_record(run, record)
        check_latest_exists(run, status, from_scratch)
        learner = setup.spec.make_learner(setup.config, setup.env, setup.seed, resolve_device(device))
        state = restore(run, setup, learner)
        run.truncate_metrics_after(state.env_steps if state else 0)
        if not quiet:
            print(resume_line(run, state), file=sys.stderr)
        return run_loop(setup, learner, state, quiet, callbacks)


class LostProgress(InputError):
    """A resume would start a run again from step 0: its ``latest.pt`` is gone."""


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


def resume_line(run: RunDir, state: LoopState | None) -> str:
    """Where a resume goes on from, for people."""
    if state is None:
        return f"resuming {run.name} from step 0 (no checkpoints/latest.pt yet)"
    return f"resuming {run.name} from env step {state.env_steps:,} (checkpoints/latest.pt)"


def load_latest(latest: Path) -> Checkpoint:
    """A run's ``latest.pt`` for a resume; CheckpointError saying that only it can resume the run."""
    try:
        return load_checkpoint(latest)
    except UnreadableCheckpoint as err:
        raise CheckpointError(
            f"cannot resume: {latest} {err.reason}. A run resumes only from its latest.pt (best.pt and "
            "solved.pt hold policies, which `cartpole eval` still judges): train a new run to go on"
        ) from err


RESUMABLE_STOPS = (StopReason.INTERRUPTED, StopReason.FAILED, StopReason.BUDGET)
"""Stops a resume trains on from (the budget is checked again at start: a spent one stops at once).
After the others (solved, a callback's stop) a resume only gives the final verdict."""


def restore(run: RunDir, setup: RunSetup, learner: Any) -> LoopState | None:
    """Load ``latest.pt`` into ``learner`` and return the loop counters to go on from; None (start
    over, as the run's seed makes it the same run) for a run killed before its first ``latest``.
    CheckpointError, in one line, for a checkpoint of another run or one that does not fit."""
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
    try:
        learner.load_state_dict(checkpoint.tensors, checkpoint.meta["learner"])
        learner.policy().act(np.zeros((1, setup.env.obs_dim), dtype=np.float32))  # weights of the right size?
        state = LoopState.from_dict(checkpoint.meta["loop"])
    except (KeyError, IndexError, TypeError, ValueError, RuntimeError, AttributeError) as err:
        raise CheckpointError(
            f"{latest} does not fit run {run.name}'s config ({type(err).__name__}: {err!s:.100}); "
            "it may come from another run: restore the run's own latest.pt, or train again"
        ) from err
    if state.stop_reason in RESUMABLE_STOPS:
        state.clear_stop()
    return state
