"""cartpole: train agents on CartPole, prove they solve it, watch them, play it yourself."""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("cartpole")
except PackageNotFoundError:  # running from a source tree that was not installed
    __version__ = "0.0.0+unknown"

from cartpole.evaluation import EvalReport, Policy, ScoredPolicy, evaluate


def load_policy(path: str) -> Policy:
    """Load any saved agent of ours (a checkpoint file or a run folder) as a greedy Policy."""
    from cartpole.agents.registry import load_policy as _load_policy

    return _load_policy(path)


__all__ = ["EvalReport", "Policy", "ScoredPolicy", "__version__", "evaluate", "load_policy"]
