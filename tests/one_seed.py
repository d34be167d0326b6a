"""A single run's learner as the tests drive it: a population of one, seen as one seed.

``cartpole train --seed N`` trains the population of one built here; these helpers only unwrap the
population's by-seed answers (``learn()`` gives ``{seed: result}``) into the seed's own, so that a
test reads as the run it checks.
"""

from __future__ import annotations

from typing import Any

import torch

from cartpole.agents.learner import LearnResult
from cartpole.agents.population import Population
from cartpole.agents.registry import AgentSpec, build_population, get_agent
from cartpole.envs import EnvInfo
from cartpole.evaluation import Policy


class OneSeed:
    """Seed ``seed`` of ``population``: its learning steps, its greedy policy and its checkpoint."""

    def __init__(self, population: Population, seed: int):
        self.population, self.seed = population, seed

    def learn(self) -> LearnResult:
        return self.population.learn()[self.seed]

    def policy(self) -> Policy:
        return self.population.seed_policy(self.seed)

    def state_dict(self, resume: bool) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
        return self.population.seed_state_dict(self.seed, resume)

    def load_state_dict(self, tensors: dict[str, torch.Tensor], data: dict[str, Any]) -> None:
        self.population.load_seed_state_dict(self.seed, tensors, data)


def one_seed(agent: str | AgentSpec, config: Any, env: EnvInfo, seed: int, device: str = "cpu") -> OneSeed:
    """The learner ``cartpole train AGENT --seed SEED`` trains: a population of one."""
    spec = get_agent(agent) if isinstance(agent, str) else agent
    return OneSeed(build_population(spec, config, env, [seed], device), seed)
