"""How many CPU threads torch computes with while a run trains: one default for every entry point
that trains (``cartpole train``, the notebook's ``cartpole.train``, an experiment's workers), and a
way to hold it for one training only.

Library code never changes the count by itself (the training session reads it, never sets it): a
process's entry point decides, and the notebook's ``train`` gives the caller's setting back after.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

from cartpole.core.errors import InputError

KEEP_TORCH_THREADS = 0
"""A thread count that leaves torch's as it is (for a fresh process: torch's own, one per core)."""


def default_torch_threads(env_id: str) -> int:
    """1 for state observations: their small networks spend more CPU on a second thread than it
    saves time, one seed or a population alike (``benchmarks/population.py --population-threads``
    measures it); :data:`KEEP_TORCH_THREADS` for image observations, whose conv nets keep every core
    busy. 1 for an env id that is not registered: the training that follows says what is wrong."""
    from cartpole.envs import env_info

    try:
        return KEEP_TORCH_THREADS if env_info(env_id).is_image else 1
    except InputError:
        return 1


@contextlib.contextmanager
def torch_threads(count: int) -> Iterator[None]:
    """torch computes with ``count`` CPU threads inside the block (:data:`KEEP_TORCH_THREADS`: as it
    is); the count from before is back after it, whether the block returns or raises."""
    import torch

    before = torch.get_num_threads()
    if count != KEEP_TORCH_THREADS:
        torch.set_num_threads(count)
    try:
        yield
    finally:
        if torch.get_num_threads() != before:
            torch.set_num_threads(before)
