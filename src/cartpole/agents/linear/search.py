"""Linear policies found by search: random search, hill climbing and the cross-entropy method.

The policy is the second tutorial's (:mod:`cartpole.agents.linear.policy`): for two actions,
``action = 1 if w . s (+ b) > 0 else 0``; for more actions, ``argmax(s W + b)``. With
``normalize_observations`` the policy reads each observation dimension scaled from its finite Box
bounds to [-1, 1] (MountainCar's velocity spans +-0.07 against a position range of 1.8: on raw
observations random weights almost never weigh velocity enough), and the scaling is saved with the
policy. The three searches differ only in how they propose the next
candidates. Every generation's candidates play their episodes together in one batched simulator call
(the fast simulator for CartPole), and a candidate is judged on its mean over
``episodes_per_candidate`` episodes, so a lucky single episode does not pick the policy. The
``tutorial`` preset of random search reproduces the tutorial exactly: 100 candidates, one episode each.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np
import torch

from cartpole.agents.learner import LearnResult
from cartpole.agents.linear.policy import (
    LinearPolicy,
    ObservationScaling,
    param_count,
    play_candidates,
    policy_from_checkpoint,
    scores_from_checkpoint,
)
from cartpole.agents.linear.population import LinearPopulation, Search
from cartpole.agents.registry import AgentSpec
from cartpole.core.config import require
from cartpole.envs import EnvInfo, make_vec_env, resolve_simulator

# ----------------------------------------------------------------------------------------------
# Configuration
# ----------------------------------------------------------------------------------------------


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


# ----------------------------------------------------------------------------------------------
# The search every seed runs, and the three ways to propose candidates
# ----------------------------------------------------------------------------------------------


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
        self.vec_env: gym.vector.VectorEnv = make_vec_env(env, n_envs, simulator=config.simulator)

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


# ----------------------------------------------------------------------------------------------
# The specs
# ----------------------------------------------------------------------------------------------


def linear_bytes_per_seed(config: LinearSearchConfig, env: EnvInfo) -> int:
    """About what one seed of a search holds: its generation's envs, and its run's bookkeeping."""
    envs = config.population * config.episodes_per_candidate
    return envs * (env.obs_dim + 8) * 8 * 4 + 2 * 1024**2


def linear_spec(cls: type[LinearSearch], summary: str) -> AgentSpec:
    """The agent that runs search ``cls``: one search per seed, every seed's candidates played
    together (:class:`~cartpole.agents.linear.population.LinearPopulation`)."""

    def make_population(
        config: LinearSearchConfig, env: EnvInfo, seeds: list[int], device: str
    ) -> LinearPopulation:
        config.validate()
        searches: dict[int, Search] = {seed: cls(config, env, seed) for seed in seeds}
        return LinearPopulation(searches, env, resolve_simulator(env, config.simulator) == "fast")

    return AgentSpec(
        name=cls.name,
        summary=summary,
        config_cls=LinearSearchConfig,
        policy_from_checkpoint=policy_from_checkpoint,
        bytes_per_seed=linear_bytes_per_seed,
        make_population=make_population,
        iteration="generation",
        score_label="linear score",
        scores_network=scores_from_checkpoint,
    )


AGENTS = [
    linear_spec(RandomSearch, "random linear policies, keep the best (the second tutorial)"),
    linear_spec(HillClimbing, "perturb the best linear policy with adaptive noise"),
    linear_spec(CrossEntropyMethod, "cross-entropy method over linear policies (fastest to solve)"),
]


__all__ = [
    "AGENTS",
    "CrossEntropyMethod",
    "HillClimbing",
    "LinearSearch",
    "LinearSearchConfig",
    "RandomSearch",
    "linear_bytes_per_seed",
]
