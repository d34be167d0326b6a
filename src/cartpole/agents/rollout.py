"""On-policy rollouts for the policy-gradient agents: collection, buffer, advantages.

- ``RolloutBuffer``: one rollout of ``num_steps`` batched steps from ``num_envs`` envs, in arrays
  allocated once. Each field is a numpy array and a torch tensor over the *same* memory: the env's
  numpy results are written with numpy (no conversion per step), the update reads tensors.
- ``RolloutCollector``: owns the vector env and steps it with the current actor. Acting runs the
  actor's frozen numpy copy (:class:`~cartpole.agents.actor_critic.CategoricalPolicy`, taken once per
  rollout) and samples from a numpy generator: for the few rows of one batched step, numpy's per-op
  overhead is a fraction of torch's, and collection, one actor call per batched step, would otherwise
  be most of a CartPole run's CPU. The log-probabilities the update needs are computed afterwards
  by torch, in one batched forward pass over the rollout.
  Gymnasium's next-step autoreset is respected: the step after an episode ends
  only resets that env (its action is ignored, its reward is 0), so that row is *not a transition*
  and is marked invalid (``valid = False``): it gets no advantage and no loss, and is not counted as
  an env step. At truncation (the time limit) the step returns the real final observation (the reset
  comes on the next step), which becomes the next row's observation: its value is what GAE bootstraps
  from.
- ``generalized_advantages``: GAE(lambda), bootstrapping from the next observation's value unless the
  step *terminated*; an ended episode (terminated or truncated) never carries advantage across into
  the next one.
- ``normalize``, ``explained_variance``: the small statistics the updates use and report.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from cartpole.agents.actor_critic import ActorCritic, CategoricalPolicy
from cartpole.core.seeding import derived_seed
from cartpole.envs import EnvInfo, check_simulator
from cartpole.envs.resumable_envs import make_resumable_vec_env, restore_vector_env_state, vector_env_state


class RolloutBuffer:
    """Preallocated storage of one rollout: rows ``[num_steps, num_envs]``.

    ``observations`` has one more row than the other fields: row ``num_steps`` holds the observation
    after the last step, whose value bootstraps the last transitions. ``values`` likewise.
    """

    def __init__(self, num_steps: int, num_envs: int, obs_dim: int, device: torch.device):
        shape = (num_steps, num_envs)
        self.num_steps, self.num_envs = num_steps, num_envs
        self.observations_np = np.zeros((num_steps + 1, num_envs, obs_dim), dtype=np.float32)
        self.rewards_np = np.zeros(shape, dtype=np.float32)
        self.terminated_np = np.zeros(shape, dtype=np.float32)
        self.truncated_np = np.zeros(shape, dtype=np.float32)
        self.valid_np = np.zeros(shape, dtype=bool)
        self.actions_np = np.zeros(shape, dtype=np.int64)
        # Tensors over the same memory (on CPU); moved to the learner's device once per rollout.
        self.observations = torch.from_numpy(self.observations_np)
        self.rewards = torch.from_numpy(self.rewards_np)
        self.terminated = torch.from_numpy(self.terminated_np)
        self.truncated = torch.from_numpy(self.truncated_np)
        self.valid = torch.from_numpy(self.valid_np)
        self.actions = torch.from_numpy(self.actions_np)
        self.device = device


def generalized_advantages(
    rewards: torch.Tensor,
    values: torch.Tensor,
    terminated: torch.Tensor,
    truncated: torch.Tensor,
    valid: torch.Tensor,
    gamma: float,
    gae_lambda: float,
) -> torch.Tensor:
    """GAE(lambda) advantages, shape [T, N], of a rollout of T steps from N envs.

    ``values`` has T + 1 rows: ``values[t + 1]`` is the value of the observation that step ``t``
    returned (row T: the observation after the rollout). The TD error of a valid step is
    ``r + gamma * (1 - terminated) * V(next) - V(obs)``: a terminated step has no future, a
    truncated one does (its next observation is the real final state, under next-step autoreset).
    The lambda-sum stops where an episode ended (terminated or truncated): the next row is the
    autoreset step, which is not a transition (``valid`` False) and gets advantage 0.
    """
    valid_f = valid.to(rewards.dtype)
    deltas = valid_f * (rewards + gamma * (1.0 - terminated) * values[1:] - values[:-1])
    carry = gamma * gae_lambda * valid_f * (1.0 - terminated) * (1.0 - truncated)
    steps = rewards.shape[0]
    advantages = torch.zeros((steps + 1, *rewards.shape[1:]), dtype=rewards.dtype, device=rewards.device)
    for t in range(steps - 1, -1, -1):
        torch.addcmul(deltas[t], carry[t], advantages[t + 1], out=advantages[t])
    return advantages[:steps]


def normalize(x: torch.Tensor, eps: float = 1e-8) -> torch.Tensor:
    """``(x - mean) / (std + eps)``; a single element is only centred."""
    if x.numel() < 2:
        return x - x.mean()
    return (x - x.mean()) / (x.std() + eps)


def explained_variance(predicted: torch.Tensor, target: torch.Tensor) -> float:
    """``1 - Var(target - predicted) / Var(target)``: 1 is perfect, 0 no better than a constant."""
    variance = float(target.var()) if target.numel() > 1 else 0.0
    if variance == 0.0:
        return float("nan")
    return 1.0 - float((target - predicted).var()) / variance


def sample_categorical(probabilities: np.ndarray, uniforms: np.ndarray) -> np.ndarray:
    """One action per row of ``probabilities`` [N, n_actions], by inverse CDF from one uniform in [0, 1)
    per row: the first action whose cumulative probability exceeds the uniform."""
    below = probabilities.cumsum(axis=1) <= uniforms[:, None]
    return np.minimum(below.sum(axis=1), probabilities.shape[1] - 1)


class RolloutCollector:
    """Steps ``num_envs`` vector envs with a categorical actor; keeps episodes running across rollouts."""

    def __init__(self, env: EnvInfo, num_envs: int, simulator: str, seed: int):
        self.env_info, self.seed = env, seed
        self.envs = make_resumable_vec_env(env.env_id, num_envs, check_simulator(simulator))
        self.observations = np.asarray(self.envs.reset(seed=seed)[0], dtype=np.float32)
        self.autoreset = np.zeros(num_envs, dtype=bool)
        """Envs whose last step ended an episode: their next step is a reset, not a transition."""
        self.episode_returns = np.zeros(num_envs, dtype=np.float64)
        self.episode_lengths = np.zeros(num_envs, dtype=np.int64)

    def collect(
        self,
        buffer: RolloutBuffer,
        model: ActorCritic,
        rng: np.random.Generator,
        steps: int | None = None,
        stop_when_all_ended: bool = False,
    ) -> tuple[int, list[float], list[int]]:
        """Fill ``buffer`` with up to ``steps`` batched steps (default: its length).

        With ``stop_when_all_ended`` collection ends once every env has ended an episode (REINFORCE's
        whole episodes); rows of an env after its episode ended are marked invalid. Returns the rows
        used, and the returns and lengths of the episodes that finished. Actions are drawn from ``rng``.
        """
        steps = buffer.num_steps if steps is None else steps
        actor = CategoricalPolicy(model)  # a numpy copy of the actor, fixed during the rollout
        uniforms = rng.random((steps, len(self.autoreset)))  # one draw per action, all at once
        returns: list[float] = []
        lengths: list[int] = []
        ended_once = np.zeros(len(self.autoreset), dtype=bool)
        used = 0
        for t in range(steps):
            buffer.observations_np[t] = self.observations
            actions = sample_categorical(actor.scores(self.observations), uniforms[t])
            buffer.actions_np[t] = actions
            observations, rewards, terminated, truncated, _ = self.envs.step(actions)
            # Gymnasium's next-step autoreset: an env that ended an episode at the last step has just
            # been reset (its action was ignored): that row is not a transition.
            valid = ~(self.autoreset | ended_once)
            done = terminated | truncated
            buffer.rewards_np[t] = rewards
            buffer.terminated_np[t] = terminated
            buffer.truncated_np[t] = truncated
            buffer.valid_np[t] = valid
            self.episode_returns += rewards * valid
            self.episode_lengths += valid
            ended = done & valid
            if ended.any():
                for i in np.flatnonzero(ended):
                    returns.append(float(self.episode_returns[i]))
                    lengths.append(int(self.episode_lengths[i]))
                self.episode_returns[ended] = 0.0
                self.episode_lengths[ended] = 0
                if stop_when_all_ended:
                    ended_once |= ended
            self.autoreset = done  # both False on an autoreset step
            self.observations = np.asarray(observations, dtype=np.float32)
            used = t + 1
            if stop_when_all_ended and ended_once.all():
                break
        buffer.observations_np[used] = self.observations
        return used, returns, lengths

    def restart(self, seed: int) -> None:
        """Start fresh episodes in every env from ``seed`` (REINFORCE: every batch from the start)."""
        self.observations = np.asarray(self.envs.reset(seed=seed)[0], dtype=np.float32)
        self.autoreset[:] = False
        self.episode_returns[:] = 0.0
        self.episode_lengths[:] = 0

    # -- resume ---------------------------------------------------------------------------------

    def state_dict(self) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
        tensors = {"observations": torch.from_numpy(self.observations.copy())}
        data = {
            "autoreset": self.autoreset.tolist(),
            "episode_returns": self.episode_returns.tolist(),
            "episode_lengths": self.episode_lengths.tolist(),
            "env_state": vector_env_state(self.envs),
        }
        return tensors, data

    def load_state_dict(self, tensors: dict[str, torch.Tensor], data: dict[str, Any], progress: int) -> None:
        """Restore what ``state_dict`` gave; ``progress`` (env steps) seeds fresh episodes if the
        env's own state could not be saved."""
        self.autoreset = np.asarray(data["autoreset"], dtype=bool)
        self.episode_returns = np.asarray(data["episode_returns"], dtype=np.float64)
        self.episode_lengths = np.asarray(data["episode_lengths"], dtype=np.int64)
        if restore_vector_env_state(self.envs, data.get("env_state"), self.episode_lengths, self.autoreset):
            self.observations = tensors["observations"].numpy().copy()
        else:
            self.restart(derived_seed(self.seed, f"resume-{progress}") % 2**32)
