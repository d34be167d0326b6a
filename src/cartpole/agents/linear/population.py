"""Linear-policy searches for a population of seeds in one process: a batch of populations.

Every seed is its single run's search (:mod:`cartpole.agents.linear.search`): its own generator, its own
candidates, its own update, the same start states. What is shared is the simulation: each
generation, the candidates of every seed play their episodes in one vector env of the fast
simulator, stepped by one call per step (on other envs and simulators each search plays its own).
Because the fast simulator steps every env on its own and a candidate's actions depend only on its
own parameters and observations, each seed's generations are bit-identical to its single run's
(tested), whichever seeds share the process.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import torch

from cartpole.agents.learner import LearnResult
from cartpole.agents.linear.search import (
    CrossEntropyMethod,
    HillClimbing,
    LinearPolicy,
    LinearSearch,
    LinearSearchConfig,
    RandomSearch,
    batched_actions,
    play_candidates,
    policy_from_checkpoint,
)
from cartpole.agents.registry import AgentSpec
from cartpole.envs import EnvInfo, make_vec_env, resolve_simulator
from cartpole.evaluation import BlockActor


class LinearPopulation:
    """The searches of seeds ``seeds``, all of class ``search`` with ``config``: one ``learn()`` =
    one generation of every seed."""

    def __init__(
        self, search: type[LinearSearch], config: LinearSearchConfig, env: EnvInfo, seeds: list[int]
    ):
        config.validate()
        self.config, self.env_info = config, env
        self.searches = {seed: search(config, env, seed) for seed in seeds}
        self.shared_env: gym.vector.VectorEnv | None = None
        self.plays_together = resolve_simulator(env.env_id, config.simulator) == "fast"
        """Whether every seed's candidates play in one fast vector env (CartPole on the fast
        simulator); elsewhere each search plays its own generation in its own envs."""

    @property
    def active_seeds(self) -> list[int]:
        return list(self.searches)

    def remove(self, seeds: list[int]) -> None:
        """Stop searching for ``seeds`` (solved or out of budget)."""
        for seed in seeds:
            self.searches.pop(seed).vec_env.close()

    def envs_for(self, count: int) -> gym.vector.VectorEnv:
        """One fast vector env of ``count`` envs (made again only when the population shrinks)."""
        if self.shared_env is None or self.shared_env.num_envs != count:
            if self.shared_env is not None:
                self.shared_env.close()
            self.shared_env = make_vec_env(self.env_info.env_id, count, simulator="fast")
        return self.shared_env

    def learn(self) -> dict[int, LearnResult]:
        """One generation of every seed: each proposes and resets its own envs as its single run
        does, then all candidates play together from those start states."""
        if not self.plays_together:
            return {seed: search.learn() for seed, search in self.searches.items()}
        searches = list(self.searches.items())
        candidates = [search.propose() for _, search in searches]
        starts = [search.reset_episodes() for _, search in searches]
        states = np.concatenate([search.vec_env.unwrapped.get_state() for _, search in searches])  # type: ignore[attr-defined]
        env = self.envs_for(len(states))
        env.reset(seed=0)  # fresh step counters; the states are overwritten just below
        env.unwrapped.set_state(states)  # type: ignore[attr-defined]
        shape = searches[0][1].shape
        returns, steps = play_candidates(env, np.concatenate(candidates), np.concatenate(starts), shape)
        results, first = {}, 0
        for (seed, search), mine in zip(searches, candidates, strict=True):
            rows = slice(first, first + len(mine))
            first += len(mine)
            scores = returns[rows].mean(axis=1)
            results[seed] = search.finish_generation(mine, scores, int(steps[rows].sum()))
        return results

    def greedy_actor(self, seeds: list[int]) -> BlockActor:
        """The kept policies of ``seeds`` as one :data:`~cartpole.evaluation.BlockActor` (block i
        holds seed i's rows)."""
        params = np.stack([self.searches[seed].best for seed in seeds])
        shape = self.searches[seeds[0]].shape
        obs_dim = self.env_info.obs_dim

        def act(observations: np.ndarray, blocks: np.ndarray) -> np.ndarray:
            rows = np.asarray(observations).reshape(len(blocks), -1, obs_dim)
            return batched_actions(params[blocks], rows, shape).reshape(-1)

        return act

    # -- one seed, as a single run sees it ----------------------------------------------------------

    def seed_policy(self, seed: int) -> LinearPolicy:
        return self.searches[seed].policy()

    def seed_state_dict(self, seed: int, resume: bool) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
        """Seed ``seed``'s checkpoint, in its single run's format."""
        return self.searches[seed].state_dict(resume)

    def load_seed_state_dict(self, seed: int, tensors: dict[str, torch.Tensor], data: dict[str, Any]) -> None:
        self.searches[seed].load_state_dict(tensors, data)


def linear_bytes_per_seed(config: LinearSearchConfig, env: EnvInfo) -> int:
    """About what one seed of a search holds: its generation's envs, and its run's bookkeeping."""
    envs = config.population * config.episodes_per_candidate
    return envs * (env.obs_dim + 8) * 8 * 4 + 2 * 1024**2


def _spec(cls: type[LinearSearch], summary: str) -> AgentSpec:
    def make_population(
        config: LinearSearchConfig, env: EnvInfo, seeds: list[int], device: str
    ) -> LinearPopulation:
        return LinearPopulation(cls, config, env, seeds)

    return AgentSpec(
        name=cls.name,
        summary=summary,
        config_cls=LinearSearchConfig,
        policy_from_checkpoint=policy_from_checkpoint,
        bytes_per_seed=linear_bytes_per_seed,
        make_population=make_population,
        iteration="generation",
        score_label="linear score",
    )


AGENTS = [
    _spec(RandomSearch, "random linear policies, keep the best (the second tutorial)"),
    _spec(HillClimbing, "perturb the best linear policy with adaptive noise"),
    _spec(CrossEntropyMethod, "cross-entropy method over linear policies (fastest to solve)"),
]
"""The linear searches: each seed's own search (linear.py) and their batched population (above)."""


__all__ = ["AGENTS", "LinearPopulation", "linear_bytes_per_seed"]
