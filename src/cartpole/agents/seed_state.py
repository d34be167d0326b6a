"""One seed's checkpoint out of a population's batches, and back: what every population's
``seed_state_dict`` and ``load_seed_state_dict`` share.

A seed's checkpoint is ``(tensors, data)``: tensors by name (a part's prefixed, ``model.*``,
``optim.*``, ``replay.*``) and JSON-able data. Without ``resume`` it holds only the greedy policy
(``load_policy`` reads it); with ``resume`` every part of the seed's training state is added
(:func:`with_training_state`), marked so that a resume can tell it from a policy-only checkpoint
(:func:`require_training_state`).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

from cartpole.core.errors import ConfigError

if TYPE_CHECKING:  # only in annotations: the linear searches' imports stay light
    import torch

SeedState = tuple[dict[str, "torch.Tensor"], dict[str, Any]]
"""A seed's checkpoint, or one part of it: tensors by name, and JSON-able data."""


def with_training_state(policy: SeedState, *parts: SeedState) -> SeedState:
    """A seed's checkpoint to resume from: its ``policy`` part and every training part (optimizer,
    generators, envs, replay, counters), marked as holding training state."""
    tensors, data = dict(policy[0]), dict(policy[1])
    for part_tensors, part_data in parts:
        tensors |= part_tensors
        data |= part_data
    data["population"] = True
    return tensors, data


def require_training_state(data: dict[str, Any]) -> None:
    """A checkpoint's metadata must hold a population's training state to resume from."""
    if not data.get("population"):
        raise ConfigError(
            "holds no training state to continue from (a policy-only checkpoint, or a run an "
            "earlier version trained with a seed's own learner); to train it again from step 0, add "
            "--from-scratch"
        )


def unprefixed(tensors: dict[str, torch.Tensor], prefix: str) -> dict[str, torch.Tensor]:
    """The tensors named ``prefix...``, by the rest of their names."""
    return {k.removeprefix(prefix): v for k, v in tensors.items() if k.startswith(prefix)}


def none_if_nan(value: float) -> float | None:
    """JSON metadata holds no NaN (checkpoints are written with ``allow_nan=False``)."""
    return None if math.isnan(value) else value


def nan_if_none(value: float | None) -> float:
    """Back from :func:`none_if_nan`."""
    return math.nan if value is None else float(value)


__all__ = [
    "SeedState",
    "nan_if_none",
    "none_if_nan",
    "require_training_state",
    "unprefixed",
    "with_training_state",
]
