"""cartpole: train agents on CartPole, prove they solve it, watch them, play it yourself.

Importing the package registers our fast simulator with Gymnasium as ``cartpole/CartPole-v1`` and
``cartpole/CartPole-v0`` (see :mod:`cartpole.envs.registration`).

In a notebook (:mod:`cartpole.notebook`)::

    run = cartpole.train("dqn", seed=0)
    run.plot(); run.show(episodes=3); run.evaluate()
    cartpole.show("runs/CartPole-v1__dqn__s0__...")
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from cartpole.core.version import __version__
from cartpole.evaluation import EvalReport, Policy, ScoredPolicy, evaluate

if TYPE_CHECKING:
    from cartpole.notebook import Run, open_run, show, train

NOTEBOOK_NAMES = ("Run", "open_run", "show", "train")
"""Found in :mod:`cartpole.notebook` on first use: it imports torch and matplotlib, which ``import
cartpole`` alone does not."""


def __getattr__(name: str) -> Any:
    if name in NOTEBOOK_NAMES:
        import cartpole.notebook

        return getattr(cartpole.notebook, name)
    raise AttributeError(f"module 'cartpole' has no attribute {name!r}")


def load_policy(path: str) -> Policy:
    """Load any saved agent of ours (a checkpoint file or a run folder) as a greedy Policy."""
    from cartpole.agents.registry import load_policy as _load_policy

    return _load_policy(path)


__all__ = [
    "EvalReport",
    "Policy",
    "Run",
    "ScoredPolicy",
    "__version__",
    "evaluate",
    "load_policy",
    "open_run",
    "show",
    "train",
]
