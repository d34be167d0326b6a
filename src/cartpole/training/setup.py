"""What a run trains with: its setup (the agent, built once per run and handed down), the record that
goes to ``config.json``, the device, and the standard callbacks every seed's loop gets."""

from __future__ import annotations

import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from cartpole.agents.registry import AgentSpec, agent_names, get_agent
from cartpole.core.config import build_valid_config, config_to_dict
from cartpole.core.errors import ConfigError
from cartpole.core.seeding import MAX_TRAIN_SEED
from cartpole.core.version import __version__
from cartpole.envs import EnvInfo, env_info
from cartpole.evaluation import EvalReport
from cartpole.runs import LiveStatus, RunDir
from cartpole.runs.run_dir import utc_now
from cartpole.training.budget import Budget
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
)
from cartpole.training.config import TrainSettings
from cartpole.training.loop import Callback, TrainingLoop


def resolve_device(device: str, seeds: int = 1) -> str:
    """The torch device, decided once, at start. ``auto``: for one seed ``cuda`` when a GPU is
    present, else ``cpu``; for several seeds the CPU (a population runs on a GPU only when asked:
    its envs step on the CPU whatever the device, and ``benchmarks/population.py --device cuda``
    measures whether the GPU pays)."""
    import torch

    if device == "auto":
        return "cuda" if seeds == 1 and torch.cuda.is_available() else "cpu"
    if device not in ("cpu", "cuda"):
        raise ConfigError(f"unknown device {device!r}; use auto, cpu or cuda")
    if device == "cuda" and not torch.cuda.is_available():
        raise ConfigError("--device cuda was asked for but no CUDA GPU is available; use auto or cpu")
    return device


@dataclass(frozen=True)
class RunSetup:
    """Everything a run is trained with. A new run's agent (spec, env, config) and settings are those
    the session built and checked, handed down as they are (:meth:`of`); a resume builds them once
    from the run's ``config.json``, which records them (:meth:`from_record`)."""

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
    def of(
        cls,
        run: RunDir,
        record: dict[str, Any],
        spec: AgentSpec,
        env: EnvInfo,
        config: Any,
        settings: TrainSettings,
        budget: Budget,
    ) -> RunSetup:
        """The setup of ``run``, whose ``record`` (its ``config.json``) was written from ``spec``,
        ``env``, ``config``, ``settings`` and ``budget``."""
        return cls(
            run=run,
            spec=spec,
            env=env,
            seed=record["seed"],
            config=config,
            settings=settings,
            budget=budget,
            tensorboard=bool(record.get("tensorboard", False)),
            meta={k: record[k] for k in ("agent", "env_id", "seed", "preset", "config")}
            | {"env_kwargs": settings.env_kwargs, "wrappers": settings.wrappers},
        )

    @classmethod
    def from_record(cls, run: RunDir, record: dict[str, Any]) -> RunSetup:
        """The setup of a run to resume, built from its ``config.json`` ``record``."""
        if record["agent"] not in agent_names():
            raise ConfigError(f"{run.path / 'config.json'} names an unknown agent {record['agent']!r}")
        missing = [key for key in ("config", "settings", "budget") if key not in record]
        if missing:
            raise ConfigError(f"{run.path / 'config.json'} records no {missing[0]!r}: it cannot be resumed")
        if not 0 <= record["seed"] <= MAX_TRAIN_SEED:
            raise ConfigError(f"{run.path / 'config.json'} records seed {record['seed']}, out of range")
        spec = get_agent(record["agent"])
        settings = build_valid_config(TrainSettings, record["settings"])
        return cls.of(
            run,
            record,
            spec,
            env_info(record["env_id"], settings.env_kwargs, settings.wrappers),
            build_valid_config(spec.config_cls, record["config"]),
            settings,
            Budget.from_dict(record["budget"]),
        )


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

    ``evaluator`` may hand the evaluation callback a report computed elsewhere (the engine evaluates
    the seeds due at a step together); ``flush_seconds`` is how often metric rows and status are
    written.
    """
    run, settings = setup.run, setup.settings
    callbacks: list[Callback] = [
        BudgetCallback(setup.budget, setup.spec.name if setup.spec.iteration == "generation" else None),
        EvalCallback(setup.env, setup.seed, settings, evaluator),
    ]
    if settings.stop_when_solved:
        callbacks.append(StopWhenSolved())
    # Metrics before checkpoints: a step's rows are pending before ``latest`` is saved, which writes
    # them first, so a resume from ``latest`` continues the rows without a gap even after a kill -9.
    metrics = MetricsCallback(run, flush_seconds)
    schedule = CheckpointSchedule.from_settings(setup.budget, settings)
    status_writer = StatusCallback(status, flush_seconds)
    callbacks += [
        metrics,
        CheckpointCallback(run, setup.spec, setup.meta, schedule, metrics, status_writer),
        status_writer,
    ]
    if setup.tensorboard:
        callbacks.append(TensorBoardCallback(run, metrics, run.config()))
    if not quiet:
        callbacks.append(ProgressCallback(setup.budget, setup.spec.iteration))
    return callbacks + list(extra)


__all__ = ["RunSetup", "make_callbacks", "resolve_device", "run_record"]
