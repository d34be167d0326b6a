"""Linear policies found by search: random search, hill climbing and the cross-entropy method.

The policy is the second tutorial's: for two actions, ``action = 1 if w . s (+ b) > 0 else 0``; for
more actions, ``argmax(s W + b)``. With ``normalize_observations`` the policy reads each observation
dimension scaled from its finite Box bounds to [-1, 1] (MountainCar's velocity spans +-0.07 against a
position range of 1.8: on raw observations random weights almost never weigh velocity enough), and the
scaling is saved with the policy. The three searches differ only in how they propose the next
candidates. Every generation's candidates play their episodes together in one batched simulator call
(the fast simulator for CartPole), and a candidate is judged on its mean over
``episodes_per_candidate`` episodes, so a lucky single episode does not pick the policy. The
``tutorial`` preset of random search reproduces the tutorial exactly: 100 candidates, one episode each.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np
import torch

from cartpole.agents.learner import LearnResult
from cartpole.core.config import require
from cartpole.envs import EnvInfo, make_vec_env
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
        scores = np.einsum("kmd,kd->km", observations, params[:, :d])
        if shape.bias:
            scores += params[:, d, None]
        return (scores > 0).astype(np.int64)
    return batched_scores(params, observations, shape).argmax(axis=-1)


def batched_scores(params: np.ndarray, observations: np.ndarray, shape: LinearPolicy | Any) -> np.ndarray:
    """Scores of K candidates on their own observations: params [K, P], obs [K, M, D] -> [K, M, A]."""
    d, n = shape.obs_dim, shape.n_actions
    if shape.scaling is not None:
        observations = shape.scaling.apply(observations)
    columns = 1 if n == 2 else n
    weights = params[:, : d * columns].reshape(-1, d, columns)
    scores = observations @ weights
    if shape.bias:
        scores = scores + params[:, d * columns :].reshape(-1, 1, columns)
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


@dataclass
class LinearSearchConfig:
    """Settings shared by the three linear-policy searches."""

    population: int = 64
    """Candidates proposed per generation."""
    episodes_per_candidate: int = 5
    """Episodes each candidate plays; its score is their mean (1 = the tutorial's lucky pick)."""
    bias: bool = False
    """Add a bias term to the linear score."""
    normalize_observations: bool = False
    """Scale each observation dimension with finite Box bounds to [-1, 1] before the linear score
    (infinite bounds: left as they are); the saved policy scales the same way."""
    init_range: float = 0.5
    """Random-search candidates and initial guesses are uniform in [-init_range, init_range]."""
    noise: float = 0.1
    """Hill climbing: std of the perturbation added to the current best."""
    elite_fraction: float = 0.2
    """CEM: share of the population whose mean and spread make the next distribution."""
    init_std: float = 0.5
    """CEM: initial std of the search distribution."""
    extra_std: float = 0.02
    """CEM: std added each generation so the search does not collapse too early."""
    simulator: str = "fast"
    """Simulator for training episodes: "fast" (ours, CartPole only) or "gymnasium"."""

    def validate(self) -> None:
        require(self.population >= 1, "population must be >= 1")
        require(self.episodes_per_candidate >= 1, "episodes_per_candidate must be >= 1")
        require(self.init_range > 0, "init_range must be > 0")
        require(self.noise > 0, "noise must be > 0")
        require(0 < self.elite_fraction <= 1, "elite_fraction must be in (0, 1]")
        require(self.init_std > 0, "init_std must be > 0")
        require(self.extra_std >= 0, "extra_std must be >= 0")
        require(self.simulator in ("fast", "gymnasium"), "simulator must be fast or gymnasium")


class LinearSearch:
    """The shared machinery: batched candidate evaluation, state, and the policy it found."""

    name = "linear"

    def __init__(self, config: LinearSearchConfig, env: EnvInfo, seed: int, device: str = "cpu"):
        self.config, self.env = config, env
        self.rng = np.random.default_rng(seed)
        self.size = param_count(env.obs_dim, env.n_actions, config.bias)
        self.scaling = (
            ObservationScaling.from_bounds(env.obs_low, env.obs_high)
            if config.normalize_observations
            else None
        )
        self.shape = LinearPolicy(np.zeros(self.size), env.obs_dim, env.n_actions, config.bias, self.scaling)
        self.best = self.rng.uniform(-config.init_range, config.init_range, self.size)
        self.best_score = -np.inf
        n_envs = config.population * config.episodes_per_candidate
        self.vec_env: gym.vector.VectorEnv = make_vec_env(env.env_id, n_envs, simulator=config.simulator)

    def policy(self) -> LinearPolicy:
        return LinearPolicy(self.best, self.env.obs_dim, self.env.n_actions, self.config.bias, self.scaling)

    def score_candidates(self, candidates: np.ndarray) -> tuple[np.ndarray, int]:
        """Mean return of each candidate over its episodes, all played at once; and env steps used."""
        start = self.reset_episodes()
        returns, steps = play_candidates(self.vec_env, candidates, start, self.shape)
        return returns.mean(axis=1), int(steps.sum())

    def reset_episodes(self) -> np.ndarray:
        """Start a generation's episodes: this search's envs reset from a seed drawn from its own
        generator; their start observations."""
        observations, _ = self.vec_env.reset(seed=int(self.rng.integers(2**31)))
        return observations

    def propose(self) -> np.ndarray:
        """The next generation's candidates, shape [population, size]."""
        raise NotImplementedError

    def update(self, candidates: np.ndarray, scores: np.ndarray) -> None:
        """Learn from the scored generation (default: keep the best candidate ever seen)."""
        i = int(scores.argmax())
        if scores[i] > self.best_score:
            self.best, self.best_score = candidates[i].copy(), float(scores[i])

    def learn(self) -> LearnResult:
        candidates = self.propose()
        scores, steps = self.score_candidates(candidates)
        return self.finish_generation(candidates, scores, steps)

    def finish_generation(self, candidates: np.ndarray, scores: np.ndarray, steps: int) -> LearnResult:
        """Learn from a scored generation; what ``learn`` reports of it."""
        self.update(candidates, scores)
        return LearnResult(
            env_steps=steps,
            summarized_episodes=scores.size * self.config.episodes_per_candidate,
            scalars={
                "train/mean_return": float(scores.mean()),
                "train/best_candidate_return": float(scores.max()),
                "train/kept_score": float(self.best_score),
            },
            log_scalars=True,
        )

    def extra_state(self) -> dict[str, Any]:
        return {}

    def load_extra_state(self, tensors: dict[str, torch.Tensor], data: dict[str, Any]) -> None:
        pass

    def state_dict(self, resume: bool) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
        tensors = {"params": torch.from_numpy(self.best.copy())}
        data: dict[str, Any] = {
            "obs_dim": self.env.obs_dim,
            "n_actions": self.env.n_actions,
            "bias": self.config.bias,
            "best_score": self.best_score if np.isfinite(self.best_score) else None,  # JSON: None = none yet
        }
        if self.scaling is not None:
            data["observation_scaling"] = self.scaling.to_data()
        if resume:
            data["rng"] = self.rng.bit_generator.state
            data.update(self.extra_state())
            tensors.update({k: v for k, v in self.extra_tensors().items()})
        return tensors, data

    def extra_tensors(self) -> dict[str, torch.Tensor]:
        return {}

    def load_state_dict(self, tensors: dict[str, torch.Tensor], data: dict[str, Any]) -> None:
        self.best = tensors["params"].numpy().astype(np.float64)
        self.best_score = -np.inf if data["best_score"] is None else float(data["best_score"])
        if "rng" in data:
            self.rng.bit_generator.state = data["rng"]
        self.load_extra_state(tensors, data)


class RandomSearch(LinearSearch):
    """Uniform random candidates in [-init_range, init_range]; keep the best."""

    name = "random-search"

    def propose(self) -> np.ndarray:
        r = self.config.init_range
        return self.rng.uniform(-r, r, (self.config.population, self.size))


class HillClimbing(LinearSearch):
    """Perturb the best with Gaussian noise; adapt the noise (halve on success, double otherwise).

    A linear policy's actions depend only on the direction of its parameters, so candidates are
    scaled to unit norm and ``noise`` is an angle-like step, the same at every stage of the search.
    """

    name = "hill-climbing"

    def __init__(self, config: LinearSearchConfig, env: EnvInfo, seed: int, device: str = "cpu"):
        super().__init__(config, env, seed, device)
        self.noise = config.noise

    def propose(self) -> np.ndarray:
        noise = self.rng.normal(0.0, self.noise, (self.config.population, self.size))
        noise[0] = 0.0  # re-score the current best too, so one lucky score does not stick forever
        candidates = self.best + noise
        return candidates / np.linalg.norm(candidates, axis=1, keepdims=True).clip(min=1e-12)

    def update(self, candidates: np.ndarray, scores: np.ndarray) -> None:
        before = self.best_score
        if self.best_score > -np.inf:
            self.best_score = float(scores[0])  # the current best's fresh score
        super().update(candidates, scores)
        improved = self.best_score > before
        self.noise = max(self.noise / 2, 1e-3) if improved else min(self.noise * 2, 2.0)

    def extra_state(self) -> dict[str, Any]:
        return {"noise": self.noise}

    def load_extra_state(self, tensors: dict[str, torch.Tensor], data: dict[str, Any]) -> None:
        self.noise = float(data.get("noise", self.config.noise))


class CrossEntropyMethod(LinearSearch):
    """Sample from N(mean, std); refit mean and std to the elite; the policy is the mean."""

    name = "cem"

    def __init__(self, config: LinearSearchConfig, env: EnvInfo, seed: int, device: str = "cpu"):
        super().__init__(config, env, seed, device)
        self.mean = np.zeros(self.size)
        self.std = np.full(self.size, config.init_std)

    def propose(self) -> np.ndarray:
        noise = self.rng.standard_normal((self.config.population, self.size))
        candidates = self.mean + self.std * noise
        candidates[0] = self.mean  # the current policy is always one of the candidates
        return candidates

    def update(self, candidates: np.ndarray, scores: np.ndarray) -> None:
        n_elite = max(1, round(self.config.elite_fraction * len(scores)))
        elite = candidates[np.argsort(scores)[-n_elite:]]
        self.mean = elite.mean(axis=0)
        self.std = elite.std(axis=0) + self.config.extra_std
        self.best, self.best_score = self.mean.copy(), float(scores[0])

    def extra_tensors(self) -> dict[str, torch.Tensor]:
        return {"mean": torch.from_numpy(self.mean.copy()), "std": torch.from_numpy(self.std.copy())}

    def load_extra_state(self, tensors: dict[str, torch.Tensor], data: dict[str, Any]) -> None:
        if "mean" in tensors:
            self.mean = tensors["mean"].numpy().astype(np.float64)
            self.std = tensors["std"].numpy().astype(np.float64)


def policy_from_checkpoint(checkpoint: Checkpoint) -> LinearPolicy:
    data = checkpoint.meta["learner"]
    return LinearPolicy(
        checkpoint.tensors["params"].numpy(),
        int(data["obs_dim"]),
        int(data["n_actions"]),
        bool(data["bias"]),
        ObservationScaling.from_data(data.get("observation_scaling")),  # absent: raw observations
    )
