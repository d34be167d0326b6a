"""What we need to know about an environment, read from Gymnasium's registry.

The "solved" threshold and the episode limit are never written in our code: they come from
``gymnasium.spec(env_id)``, so CartPole-v0 (195 over 200 steps) and CartPole-v1 (475 over 500)
each get their own rule.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import gymnasium as gym
import numpy as np

from cartpole.core.errors import InputError


class UnsupportedEnvError(InputError, ValueError):
    """The env id is unknown, or its spaces are not a Box observation and Discrete actions."""


@dataclass(frozen=True)
class EnvInfo:
    """Spaces and limits of one registered Gymnasium environment."""

    env_id: str
    obs_dim: int
    n_actions: int
    reward_threshold: float | None
    max_episode_steps: int | None
    obs_low: tuple[float, ...]
    obs_high: tuple[float, ...]

    @property
    def is_cartpole(self) -> bool:
        """True for Gymnasium's CartPole ids (our fast simulator can stand in for them)."""
        return self.env_id.removeprefix("cartpole/") in ("CartPole-v0", "CartPole-v1")


@cache
def env_info(env_id: str) -> EnvInfo:
    """Read spaces, threshold and episode limit of ``env_id``; raise UnsupportedEnvError if unusable."""
    try:
        spec = gym.spec(env_id)
    except Exception as err:  # gymnasium raises several error types for unknown ids
        raise UnsupportedEnvError(
            f"unknown environment {env_id!r}: use a registered Gymnasium id such as CartPole-v1, "
            "CartPole-v0 or Acrobot-v1"
        ) from err
    try:
        env = gym.make(spec)
    except Exception as err:
        raise UnsupportedEnvError(
            f"cannot create environment {env_id!r}: {err} (is its extra installed?)"
        ) from err
    try:
        obs_space, act_space = env.observation_space, env.action_space
    finally:
        env.close()
    if isinstance(obs_space, gym.spaces.Box) and len(obs_space.shape) == 3:
        raise UnsupportedEnvError(
            f"{env_id} has image observations {obs_space.shape}: training from pixels needs a "
            "convolutional network, which no agent here has yet; use a flat Box observation env "
            "such as CartPole-v1"
        )
    if not isinstance(obs_space, gym.spaces.Box) or len(obs_space.shape) != 1:
        raise UnsupportedEnvError(
            f"{env_id} has a {type(obs_space).__name__}{getattr(obs_space, 'shape', '')} "
            "observation; supported: a flat Box observation with Discrete actions"
        )
    if not isinstance(act_space, gym.spaces.Discrete):
        raise UnsupportedEnvError(
            f"{env_id} has {type(act_space).__name__} actions; supported: Discrete actions "
            "with a flat Box observation"
        )
    return EnvInfo(
        env_id=env_id,
        obs_dim=int(obs_space.shape[0]),
        n_actions=int(act_space.n),
        reward_threshold=spec.reward_threshold,
        max_episode_steps=spec.max_episode_steps,
        obs_low=tuple(float(v) for v in np.asarray(obs_space.low)),
        obs_high=tuple(float(v) for v in np.asarray(obs_space.high)),
    )
