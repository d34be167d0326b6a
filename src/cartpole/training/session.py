"""Start or resume a training run: build the agent, the callbacks and the run folder, then train.

This is the library form of ``cartpole train``; benchmarks and tests call it directly.
"""

from __future__ import annotations

import signal
import sys
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from cartpole.agents.registry import AgentSpec, get_agent
from cartpole.core.config import build_config, config_to_dict
from cartpole.core.errors import ConfigError
from cartpole.core.seeding import MAX_TRAIN_SEED, final_eval_seed
from cartpole.core.version import __version__
from cartpole.envs import EnvInfo, env_info
from cartpole.evaluation import MIN_EPISODES_FOR_SOLVED, EvalReport, evaluate
from cartpole.runs import CheckpointError, RunDir, load_checkpoint
from cartpole.runs.run_dir import utc_now
from cartpole.training.budget import Budget, parse_budget
from cartpole.training.callbacks import (
    BudgetCallback,
    CheckpointCallback,
    EvalCallback,
    MetricsCallback,
    ProgressCallback,
    StopWhenSolved,
    TensorBoardCallback,
    require_tensorboard,
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


@contextmanager
def stop_on_signals(loop: TrainingLoop) -> Iterator[list[int]]:
    """While training, SIGINT/SIGTERM finish the current step and stop cleanly."""
    received: list[int] = []

    def handler(signum: int, frame: Any) -> None:
        received.append(signum)
        loop.request_stop(f"interrupted ({signal.Signals(signum).name})")

    previous = {s: signal.signal(s, handler) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield received
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
        spec = get_agent(record["agent"])
        return cls(
            run=run,
            spec=spec,
            env=env_info(record["env_id"]),
            seed=record["seed"],
            config=build_config(spec.config_cls, record["config"]),
            settings=build_config(TrainSettings, record["settings"]),
            budget=Budget.from_dict(record["budget"]),
            tensorboard=bool(record.get("tensorboard", False)),
            meta={k: record[k] for k in ("agent", "env_id", "seed", "preset", "config")},
        )


def make_callbacks(setup: RunSetup, quiet: bool, extra: Sequence[Callback] = ()) -> list[Callback]:
    """The standard callbacks, in the order they must see events; ``extra`` ones see them last."""
    run, settings = setup.run, setup.settings
    callbacks: list[Callback] = [BudgetCallback(setup.budget), EvalCallback(setup.env, setup.seed, settings)]
    if settings.stop_when_solved:
        callbacks.append(StopWhenSolved())
    # Metrics before checkpoints: a step's rows are pending before ``latest`` is saved, which writes
    # them first, so a resume from ``latest`` continues the rows without a gap even after a kill -9.
    metrics = MetricsCallback(run)
    callbacks += [
        metrics,
        CheckpointCallback(run, setup.spec, setup.meta, settings.checkpoint_every, metrics),
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
    run, settings = setup.run, setup.settings
    policy = setup.spec.policy_from_checkpoint(load_checkpoint(run.checkpoint_path("best")))
    report = evaluate(
        policy,
        setup.env.env_id,
        max(settings.eval_episodes, MIN_EPISODES_FOR_SOLVED),
        seed=final_eval_seed(setup.seed),
        simulator=settings.eval_simulator,  # type: ignore[arg-type]
    )
    run.write_eval(report.to_dict())
    return report


def run_loop(
    setup: RunSetup, learner: Any, state: LoopState | None, quiet: bool, extra: Sequence[Callback] = ()
) -> TrainOutcome:
    """Drive the loop with the standard callbacks; compute the verdict unless interrupted."""
    loop = TrainingLoop(learner, make_callbacks(setup, quiet, extra), state)
    with stop_on_signals(loop) as received:
        loop.run()
    if received:
        return TrainOutcome(setup.run, loop.state, None, signal=received[0])
    return TrainOutcome(setup.run, loop.state, final_verdict(setup))


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
    run = RunDir.create(Path(runs_dir), env_id, agent, seed)
    record = {
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
        "tensorboard": tensorboard,
    }
    run.write_config(record)
    return run_loop(RunSetup.from_record(run, record), learner, None, quiet, callbacks)


class AlreadyFinished(Exception):
    """The run to resume has finished; there is nothing to do."""


def resume(
    run_path: Path | str, *, quiet: bool = True, device: str = "auto", callbacks: Sequence[Callback] = ()
) -> TrainOutcome:
    """Continue a run from ``checkpoints/latest.pt`` with its recorded config and budget."""
    run = RunDir.open(Path(run_path))
    record = run.config()
    status = run.status()
    if status.get("state") == "finished":
        raise AlreadyFinished(
            f"run {run.name} already finished ({status.get('stop_reason') or 'done'}); nothing to resume"
        )
    latest = run.checkpoint_path("latest")
    if not latest.is_file():
        raise CheckpointError(f"run {run.name} has no checkpoints/latest.pt to resume from")
    checkpoint = load_checkpoint(latest)
    if not checkpoint.meta.get("resumable"):
        raise CheckpointError(f"{latest} is not a resumable checkpoint")
    setup = RunSetup.from_record(run, record)
    learner = setup.spec.make_learner(setup.config, setup.env, setup.seed, resolve_device(device))
    learner.load_state_dict(checkpoint.tensors, checkpoint.meta["learner"])
    state = LoopState.from_dict(checkpoint.meta["loop"])
    run.truncate_metrics_after(state.env_steps)
    return run_loop(setup, learner, state, quiet, callbacks)
