"""The linear policy of the searches, and how a generation's candidates play.

For two actions, ``action = 1 if w . s (+ b) > 0 else 0`` (the second tutorial's policy); for more
actions, ``argmax(s W + b)``. With an :class:`ObservationScaling` the policy reads each observation
dimension scaled from its finite Box bounds to [-1, 1], and the scaling is saved with the policy.
:func:`play_candidates` plays K candidates' episodes in one vector env, all at once. A candidate's
scores are float64 sums in our fixed order (:func:`~cartpole.agents.nn.fixed_order.matmul_arrays`),
so a seed's candidates act the same whatever other seeds' candidates share the batch.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from torch import nn

from cartpole.agents.nn.fixed_order import matmul_arrays
from cartpole.core.config import require
from cartpole.runs import Checkpoint


class LinearPolicy:
    """Greedy linear policy over a flat parameter vector (weights, then optional bias), on the
    observations as they are or, given ``scaling``, on ``(s - center) / half_width``."""

    def __init__(
        self,
        params: np.ndarray,
        obs_dim: int,
        n_actions: int,
        bias: bool,
        scaling: ObservationScaling | None = None,
    ):
        self.params = np.asarray(params, dtype=np.float64)
        self.obs_dim, self.n_actions, self.bias = obs_dim, n_actions, bias
        self.scaling = scaling
        require(self.params.size == param_count(obs_dim, n_actions, bias), "wrong parameter count")
        require(scaling is None or scaling.center.size == obs_dim, "wrong observation scaling size")

    def scores(self, observations: np.ndarray) -> np.ndarray:
        """``[-s, s]`` for two actions (s = w . obs + b); ``obs W + b`` otherwise (obs scaled first
        where the policy has a scaling)."""
        return batched_scores(self.params[None], np.asarray(observations)[None], self)[0]

    def act(self, observations: np.ndarray) -> np.ndarray:
        return batched_actions(self.params[None], np.asarray(observations)[None], self)[0]


@dataclass(frozen=True)
class ObservationScaling:
    """What a linear policy reads instead of observation ``s``: ``(s - center) / half_width``."""

    center: np.ndarray
    half_width: np.ndarray

    @classmethod
    def from_bounds(cls, low: Sequence[float], high: Sequence[float]) -> ObservationScaling:
        """Each dimension with finite bounds mapped from [low, high] to [-1, 1]; one with an
        infinite (or empty) range left as it is."""
        lo, hi = np.asarray(low, dtype=np.float64), np.asarray(high, dtype=np.float64)
        finite = np.isfinite(lo) & np.isfinite(hi) & (hi > lo)
        lo, hi = np.where(finite, lo, -1.0), np.where(finite, hi, 1.0)  # (-1, 1): left as it is
        center = (hi + lo) / 2
        half_width = (hi - lo) / 2
        return cls(center, half_width)

    def apply(self, observations: np.ndarray) -> np.ndarray:
        return (observations - self.center) / self.half_width

    def to_data(self) -> dict[str, list[float]]:
        """Plain data for a checkpoint's metadata (all finite, so JSON keeps it exactly)."""
        return {"center": self.center.tolist(), "half_width": self.half_width.tolist()}

    @classmethod
    def from_data(cls, data: dict[str, list[float]] | None) -> ObservationScaling | None:
        """Back from a checkpoint; None for one saved without scaling (or before it existed)."""
        if data is None:
            return None
        return cls(
            np.asarray(data["center"], dtype=np.float64), np.asarray(data["half_width"], dtype=np.float64)
        )


def param_count(obs_dim: int, n_actions: int, bias: bool) -> int:
    columns = 1 if n_actions == 2 else n_actions
    return (obs_dim + int(bias)) * columns


def batched_actions(params: np.ndarray, observations: np.ndarray, shape: LinearPolicy | Any) -> np.ndarray:
    """Greedy actions of K candidates on their own observations: [K, M, D] -> [K, M]."""
    if shape.n_actions == 2:  # the hot path of every search: action = 1 iff w . s (+ b) > 0
        d = shape.obs_dim
        if shape.scaling is not None:
            observations = shape.scaling.apply(observations)
        bias = params[:, d, None, None] if shape.bias else None
        scores = matmul_arrays(np.asarray(observations, dtype=np.float64), params[:, :d, None], bias)
        return (scores[..., 0] > 0).astype(np.int64)
    return batched_scores(params, observations, shape).argmax(axis=-1)


def batched_scores(params: np.ndarray, observations: np.ndarray, shape: LinearPolicy | Any) -> np.ndarray:
    """Scores of K candidates on their own observations: params [K, P], obs [K, M, D] -> [K, M, A]."""
    d, n = shape.obs_dim, shape.n_actions
    if shape.scaling is not None:
        observations = shape.scaling.apply(observations)
    columns = 1 if n == 2 else n
    weights = params[:, : d * columns].reshape(-1, d, columns)
    bias = params[:, d * columns :].reshape(-1, 1, columns) if shape.bias else None
    scores = matmul_arrays(np.asarray(observations, dtype=np.float64), weights, bias)
    if n == 2:  # one score s: action 1 iff s > 0, so argmax([-s, s]) gives it (ties go to 0)
        return np.concatenate([-scores, scores], axis=-1)
    return scores


def play_candidates(
    env: gym.vector.VectorEnv, candidates: np.ndarray, observations: np.ndarray, shape: LinearPolicy
) -> tuple[np.ndarray, np.ndarray]:
    """K candidates play one episode in each of their E envs (env ``k * E + e`` is candidate k's),
    from ``observations`` (the envs were just reset), all at once; returns ``[K, E]`` and the env
    steps each candidate used ``[K]``."""
    k = candidates.shape[0]
    e = env.num_envs // k
    returns = np.zeros(k * e)
    running = np.ones(k * e, dtype=bool)
    steps = np.zeros(k, dtype=np.int64)
    while running.any():
        actions = batched_actions(candidates, observations.reshape(k, e, -1), shape).reshape(k * e)
        observations, rewards, terminated, truncated, _ = env.step(actions)
        returns += np.where(running, rewards, 0.0)
        steps += running.reshape(k, e).sum(axis=1)
        running &= ~(terminated | truncated)
    return returns.reshape(k, e), steps


class LinearScores(nn.Module):
    """A linear policy's scores (:meth:`LinearPolicy.scores`) as a torch module, in float64 as the
    policy computes them, its observation scaling included: the greedy path for export."""

    weights: torch.Tensor
    bias: torch.Tensor
    center: torch.Tensor
    half_width: torch.Tensor

    def __init__(self, policy: LinearPolicy):
        super().__init__()
        d, columns = policy.obs_dim, 1 if policy.n_actions == 2 else policy.n_actions
        params = torch.as_tensor(policy.params, dtype=torch.float64)
        bias = params[d * columns :] if policy.bias else torch.zeros(columns, dtype=torch.float64)
        scaling = policy.scaling or ObservationScaling(np.zeros(d), np.ones(d))  # none: x as it is
        self.two_actions = policy.n_actions == 2
        self.register_buffer("weights", params[: d * columns].reshape(d, columns).clone())
        self.register_buffer("bias", bias.clone())
        self.register_buffer("center", torch.as_tensor(scaling.center, dtype=torch.float64))
        self.register_buffer("half_width", torch.as_tensor(scaling.half_width, dtype=torch.float64))

    def forward(self, observations: torch.Tensor) -> torch.Tensor:
        x = (observations.to(torch.float64) - self.center) / self.half_width
        scores = x @ self.weights + self.bias
        return torch.cat([-scores, scores], dim=1) if self.two_actions else scores


def scores_from_checkpoint(checkpoint: Checkpoint) -> LinearScores:
    """The ``scores_network`` of a linear search's checkpoint."""
    return LinearScores(policy_from_checkpoint(checkpoint))


def policy_from_checkpoint(checkpoint: Checkpoint) -> LinearPolicy:
    data = checkpoint.meta["learner"]
    return LinearPolicy(
        checkpoint.tensors["params"].numpy(),
        int(data["obs_dim"]),
        int(data["n_actions"]),
        bool(data["bias"]),
        ObservationScaling.from_data(data.get("observation_scaling")),  # absent: raw observations
    )


__all__ = [
    "LinearPolicy",
    "LinearScores",
    "ObservationScaling",
    "batched_actions",
    "batched_scores",
    "param_count",
    "play_candidates",
    "policy_from_checkpoint",
    "scores_from_checkpoint",
]
