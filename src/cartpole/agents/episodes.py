"""Every seed's envs with their running episodes, as one batch: what a neural population steps.

Each seed owns ``num_envs`` consecutive rows of every per-env array (its envs are those its own run
would make: :func:`~cartpole.envs.seed_envs.make_seed_envs`). :class:`SeedEpisodes` steps them all,
adds up each episode's return and length, hands each seed its finished episodes, and saves and puts
back one seed's envs and episodes for its checkpoint.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from cartpole.envs import EnvInfo
from cartpole.envs.seed_envs import env_rows, make_seed_envs

if TYPE_CHECKING:
    import torch

Finished = list[tuple[list[float], list[int]]]
"""Each seed's episodes that ended: their returns and their lengths."""


@dataclass
class EnvStep:
    """One batched step of every seed's envs, each array ``[S * N]``."""

    observations: np.ndarray
    """Where the envs were when they stepped."""
    next_observations: np.ndarray
    rewards: np.ndarray
    terminated: np.ndarray
    truncated: np.ndarray
    valid: np.ndarray
    """Which rows are transitions: not an autoreset step (Gymnasium's next-step autoreset: the step
    after an episode's end only resets the env), nor ignored."""
    ended: np.ndarray
    """Which transitions ended an episode."""
    lengths: np.ndarray
    """Each env's episode length after the step (before an ended episode's counter restarts)."""


class SeedEpisodes:
    """Every seed's ``num_envs`` envs as one batch (:func:`~cartpole.envs.seed_envs.make_seed_envs`),
    with their running episodes: the current observations, which envs reset on their next step,
    and each episode's return and length so far."""

    def __init__(self, env: EnvInfo, simulator: str, seeds: list[int], num_envs: int):
        self.envs = make_seed_envs(env, simulator, seeds, num_envs)
        self.num_envs = num_envs
        n = len(seeds) * num_envs
        self.observations = self.envs.observations()
        self.autoreset = np.zeros(n, dtype=bool)
        self.returns = np.zeros(n, dtype=np.float64)
        self.lengths = np.zeros(n, dtype=np.int64)

    def step(self, actions: np.ndarray, finished: Finished, ignored: np.ndarray | None = None) -> EnvStep:
        """Step every env with ``actions`` [S * N]; the episodes that end go to their seed's row of
        ``finished``. Envs where ``ignored`` step too, but take no transition."""
        observations = self.observations
        next_observations, rewards, terminated, truncated = self.envs.step(actions)
        valid = ~self.autoreset if ignored is None else ~(self.autoreset | ignored)
        ended = (terminated | truncated) & valid
        self.returns += np.where(valid, rewards, 0.0)
        self.lengths += valid
        lengths = self.lengths.copy()
        for i in np.flatnonzero(ended):
            finished[i // self.num_envs][0].append(float(self.returns[i]))
            finished[i // self.num_envs][1].append(int(self.lengths[i]))
        self.returns[ended] = 0.0
        self.lengths[ended] = 0
        self.autoreset = terminated | truncated
        self.observations = next_observations
        return EnvStep(observations, next_observations, rewards, terminated, truncated, valid, ended, lengths)

    def restart(self, seeds: list[int]) -> None:
        """A fresh episode in every env, row ``i``'s from seed ``seeds[i]``."""
        for row, seed in enumerate(seeds):
            self.envs.restart(row, seed)
        self.observations = self.envs.observations()
        self.autoreset[:] = False
        self.returns[:] = 0.0
        self.lengths[:] = 0

    def keep(self, rows: np.ndarray, envs: np.ndarray) -> None:
        """Keep only the seeds at ``rows`` (whose envs are ``envs``)."""
        self.envs.keep(rows)
        self.observations = self.observations[envs]
        self.autoreset = self.autoreset[envs]
        self.returns, self.lengths = self.returns[envs], self.lengths[envs]

    def seed_state(self, row: int) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
        """Seed ``row``'s envs and episodes, for its checkpoint."""
        import torch  # only populations of neural agents checkpoint their envs

        envs = env_rows(row, self.num_envs)
        collector = {
            "autoreset": self.autoreset[envs].tolist(),
            "episode_returns": self.returns[envs].tolist(),
            "episode_lengths": self.lengths[envs].tolist(),
            "env_state": self.envs.seed_state(row),
        }
        observations = torch.from_numpy(self.observations[envs].copy())
        return {"collector.observations": observations}, {"collector": collector}

    def load_seed_state(self, row: int, tensors: dict[str, torch.Tensor], data: dict[str, Any]) -> None:
        """Restore what :meth:`seed_state` gave (or a DQN checkpoint from before it, which kept the
        same at the top level and its observations as ``envs.observations``)."""
        envs, collector = env_rows(row, self.num_envs), data.get("collector", data)
        observations = tensors.get("collector.observations", tensors.get("envs.observations"))
        if observations is None:
            raise KeyError("collector.observations")
        self.observations[envs] = observations.numpy()
        self.autoreset[envs] = collector["autoreset"]
        self.returns[envs] = collector["episode_returns"]
        self.lengths[envs] = collector["episode_lengths"]
        self.envs.load_seed_state(row, collector["env_state"])


__all__ = ["EnvStep", "Finished", "SeedEpisodes"]
