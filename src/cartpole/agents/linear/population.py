"""The linear searches of a population of seeds in one process: each seed's own search, their
candidates played together.

Every seed is its own search (:mod:`cartpole.agents.linear.search`): its own generator, its own
candidates, its own update, its own start states. What is shared is the simulation: each generation,
the candidates of every seed play their episodes in one vector env of the fast simulator, stepped by
one call per step (on other envs and simulators each search plays its own). Because the fast
simulator steps every env on its own and a candidate's actions depend only on its own parameters and
observations, each seed's generations are bit for bit those it has alone (tested), whichever seeds
share the process.
"""

from __future__ import annotations

from typing import Any, Protocol

import gymnasium as gym
import numpy as np
import torch

from cartpole.agents.learner import LearnResult
from cartpole.agents.linear.policy import LinearPolicy, batched_actions, play_candidates
from cartpole.envs import EnvInfo, make_vec_env
from cartpole.evaluation import BlockActor


class Search(Protocol):
    """One seed's search, as the population plays it
    (:class:`~cartpole.agents.linear.search.LinearSearch`)."""

    vec_env: gym.vector.VectorEnv
    """Its own envs: where it plays alone, and whose start states it draws."""
    shape: LinearPolicy
    """The shape of its candidates' policy (sizes, bias, scaling)."""
    best: np.ndarray
    """The parameters of its current policy."""

    def propose(self) -> np.ndarray: ...

    def reset_episodes(self) -> np.ndarray: ...

    def finish_generation(self, candidates: np.ndarray, scores: np.ndarray, steps: int) -> LearnResult: ...

    def learn(self) -> LearnResult: ...

    def policy(self) -> LinearPolicy: ...

    def state_dict(self, resume: bool) -> tuple[dict[str, torch.Tensor], dict[str, Any]]: ...

    def load_state_dict(self, tensors: dict[str, torch.Tensor], data: dict[str, Any]) -> None: ...


class LinearPopulation:
    """The searches ``searches`` (by seed) on ``env``: one ``learn()`` = one generation of every
    seed. With ``plays_together`` (CartPole on the fast simulator) every seed's candidates play in one
    fast vector env; elsewhere each search plays its own generation in its own envs."""

    def __init__(self, searches: dict[int, Search], env: EnvInfo, plays_together: bool):
        self.env_info = env
        self.searches = searches
        self.shared_env: gym.vector.VectorEnv | None = None
        self.plays_together = plays_together

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
            self.shared_env = make_vec_env(self.env_info, count, simulator="fast")
        return self.shared_env

    def learn(self) -> dict[int, LearnResult]:
        """One generation of every seed: each proposes and resets its own envs as it does alone, then
        all candidates play together from those start states."""
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

    # -- each seed's policy and checkpoint ----------------------------------------------------------

    def seed_policy(self, seed: int) -> LinearPolicy:
        return self.searches[seed].policy()

    def seed_state_dict(self, seed: int, resume: bool) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
        """Seed ``seed``'s checkpoint: its search's."""
        return self.searches[seed].state_dict(resume)

    def load_seed_state_dict(self, seed: int, tensors: dict[str, torch.Tensor], data: dict[str, Any]) -> None:
        self.searches[seed].load_state_dict(tensors, data)


__all__ = ["LinearPopulation", "Search"]
