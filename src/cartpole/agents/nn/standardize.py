"""Observations standardized by fixed constants, ``(x - mean) / std`` per dimension, before a network.

Some envs' observations differ in scale by orders of magnitude: MountainCar's position spans 1.8
and its velocity 0.14, and a small network with tanh units hardly reads the velocity. Here the
constants are settings (a preset names them), not statistics gathered while training: a checkpoint's
policy standardizes exactly as its network learned to, and a seed alone standardizes as the same
seed in a population. :class:`StandardizeObservations` is the torch layer;
:class:`Standardize` its numpy twin, for the numpy greedy policies.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import torch
from torch import nn


@dataclass(frozen=True)
class Standardize:
    """``(x - mean) / std`` over the last axis, in float32 (as the torch layer computes it). Equal
    constants compare equal, so networks that share them stack (:class:`StackedNumpyMLP`)."""

    mean: tuple[float, ...]
    std: tuple[float, ...]

    @cached_property
    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """The constants as float32 arrays, made once (a policy standardizes at every env step)."""
        return np.asarray(self.mean, dtype=np.float32), np.asarray(self.std, dtype=np.float32)

    def __call__(self, x: np.ndarray) -> np.ndarray:
        mean, std = self.arrays
        return (np.asarray(x, dtype=np.float32) - mean) / std


class StandardizeObservations(nn.Module):
    """The first layer of a trunk: ``(x - mean) / std`` per observation dimension; no parameters."""

    def __init__(self, mean: Sequence[float], std: Sequence[float]):
        super().__init__()
        self.constants = Standardize(tuple(float(m) for m in mean), tuple(float(s) for s in std))
        self.register_buffer("mean", torch.tensor(self.constants.mean, dtype=torch.float32), persistent=False)
        self.register_buffer("std", torch.tensor(self.constants.std, dtype=torch.float32), persistent=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        mean, std = self.mean, self.std
        assert isinstance(mean, torch.Tensor) and isinstance(std, torch.Tensor)
        return (x - mean.to(x.device)) / std.to(x.device)

    def extra_repr(self) -> str:
        return f"mean={list(self.constants.mean)}, std={list(self.constants.std)}"


__all__ = ["Standardize", "StandardizeObservations"]
