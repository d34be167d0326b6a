"""The agents we ship, by name: how to configure, build and reload each one."""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from cartpole.envs import EnvInfo
from cartpole.evaluation import Policy
from cartpole.runs import Checkpoint, CheckpointError, RunDir, load_checkpoint

if TYPE_CHECKING:
    from cartpole.agents.learner import Learner


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
    score_label: str = "score"
    """What its policy's ``scores()`` are, for people ("Q-values", "action probabilities", ...)."""


AGENT_MODULES = {
    "random-search": "cartpole.agents.linear",
    "hill-climbing": "cartpole.agents.linear",
    "cem": "cartpole.agents.linear",
    "dqn": "cartpole.agents.dqn",
}
"""Agent name -> the module that defines it (imported only when the agent is used: torch is slow)."""


def agent_names() -> list[str]:
    return list(AGENT_MODULES)


def get_agent(name: str) -> AgentSpec:
    """The spec of agent ``name``, importing its module on first use."""
    if name not in AGENT_MODULES:
        raise ValueError(f"unknown agent {name!r}; choose one of: {', '.join(AGENT_MODULES)}")
    module = importlib.import_module(AGENT_MODULES[name])
    specs = getattr(module, "AGENTS", None) or [module.AGENT]
    return next(spec for spec in specs if spec.name == name)


def agents() -> dict[str, AgentSpec]:
    """Every agent by name (imports every agent module)."""
    return {name: get_agent(name) for name in AGENT_MODULES}


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
    return open_policy(path)[2]


def open_policy(path: str | Path) -> tuple[Path, Checkpoint, Policy]:
    """(checkpoint file, checkpoint, greedy policy) of a checkpoint file or run folder."""
    file = resolve_checkpoint_path(path)
    checkpoint = load_checkpoint(file)
    return file, checkpoint, spec_of(checkpoint).policy_from_checkpoint(checkpoint)


def spec_of(checkpoint: Checkpoint) -> AgentSpec:
    """The agent that wrote ``checkpoint``; CheckpointError if we do not know it."""
    agent = checkpoint.meta.get("agent")
    if agent not in AGENT_MODULES:
        raise CheckpointError(f"checkpoint names an unknown agent {agent!r}")
    return get_agent(str(agent))
