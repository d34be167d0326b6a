"""The agents we ship, by name: how to configure, build and reload each one."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from cartpole.envs import EnvInfo
from cartpole.evaluation import Policy
from cartpole.runs import Checkpoint, CheckpointError, RunDir, load_checkpoint

if TYPE_CHECKING:
    from cartpole.training.loop import Learner


@dataclass(frozen=True)
class AgentSpec:
    """One agent: its config type, a learner factory and a policy loader."""

    name: str
    summary: str
    config_cls: type
    make_learner: Callable[[Any, EnvInfo, int, str], Learner]
    """(config, env info, seed, device) -> a fresh learner."""
    policy_from_checkpoint: Callable[[Checkpoint], Policy]
    """Rebuild the greedy policy from a checkpoint's tensors and metadata."""
    iteration: str = "step"
    """What one ``learn()`` call is, in words: "generation" or "step"."""


def agents() -> dict[str, AgentSpec]:
    """Every agent by name (imported lazily so the CLI starts fast)."""
    from cartpole.agents import dqn, linear

    specs = [*linear.AGENTS, dqn.AGENT]
    return {spec.name: spec for spec in specs}


def get_agent(name: str) -> AgentSpec:
    table = agents()
    if name not in table:
        raise ValueError(f"unknown agent {name!r}; choose one of: {', '.join(table)}")
    return table[name]


def resolve_checkpoint_path(path: str | Path) -> Path:
    """A checkpoint file, or a run folder's best (else latest) checkpoint."""
    path = Path(path)
    if path.is_dir():
        run = RunDir.open(path)
        for name in ("best", "solved", "latest"):
            if run.checkpoint_path(name).is_file():
                return run.checkpoint_path(name)
        raise CheckpointError(f"run {path} has no checkpoint yet; train it (or wait for one)")
    return path


def load_policy(path: str | Path) -> Policy:
    """Load any saved agent of ours as a greedy Policy."""
    checkpoint = load_checkpoint(resolve_checkpoint_path(path))
    agent = checkpoint.meta.get("agent")
    table = agents()
    if agent not in table:
        raise CheckpointError(f"checkpoint names an unknown agent {agent!r}")
    return table[agent].policy_from_checkpoint(checkpoint)
