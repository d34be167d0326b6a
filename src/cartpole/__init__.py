"""cartpole: train agents on CartPole, prove they solve it, watch them, play it yourself.

Importing the package registers our fast simulator with Gymnasium as ``cartpole/CartPole-v1`` and
``cartpole/CartPole-v0`` (see :mod:`cartpole.envs.registration`).
"""

from __future__ import annotations

from cartpole.core.version import __version__
from cartpole.evaluation import EvalReport, Policy, ScoredPolicy, evaluate


def load_policy(path: str) -> Policy:
    """Load any saved agent of ours (a checkpoint file or a run folder) as a greedy Policy."""
    from cartpole.agents.registry import load_policy as _load_policy

    return _load_policy(path)


__all__ = ["EvalReport", "Policy", "ScoredPolicy", "__version__", "evaluate", "load_policy"]
