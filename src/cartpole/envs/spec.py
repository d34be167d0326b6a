"""What we need to know about an environment, read from Gymnasium's registry.

The "solved" threshold and the episode limit are never written in our code: they come from
``gymnasium.spec(env_id)``, so CartPole-v0 (195 over 200 steps) and CartPole-v1 (475 over 500)
each get their own rule.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cache

import gymnasium as gym
import numpy as np

from cartpole.core.errors import InputError
from cartpole.envs.registration import PIXEL_REFERENCE_IDS


class UnsupportedEnvError(InputError, ValueError):
    """The env id is unknown, or its spaces are not a Box observation (flat or image) and Discrete
    actions."""


@dataclass(frozen=True)
class EnvInfo:
    """Spaces and limits of one registered Gymnasium environment."""

    env_id: str
    obs_dim: int
    """Numbers in one observation (of a flat one, its length; of an image, channels x height x width)."""
    n_actions: int
    reward_threshold: float | None
    max_episode_steps: int | None
    obs_low: tuple[float, ...]
    obs_high: tuple[float, ...]
    """Bounds of each number of a flat observation (of an image: its one pixel range, 0 and 255)."""
    obs_shape: tuple[int, ...] = ()
    """Shape of one observation: ``(obs_dim,)`` flat, ``(channels, height, width)`` for images, as
    agents choose their network by it."""

    def __post_init__(self) -> None:
        if not self.obs_shape:
            object.__setattr__(self, "obs_shape", (self.obs_dim,))

    @property
    def is_image(self) -> bool:
        """True for image observations ``[channels, height, width]`` (a convolutional network's)."""
        return len(self.obs_shape) == 3

    @property
    def is_cartpole(self) -> bool:
        """True for Gymnasium's CartPole ids (our fast simulator can stand in for them)."""
        return self.env_id.removeprefix("cartpole/") in ("CartPole-v0", "CartPole-v1")

    @property
    def pixels_of(self) -> str | None:
        """For our pixel envs, the Gymnasium CartPole id they show (their verdicts are played on it,
        seen through :class:`~cartpole.envs.pixels.GymnasiumPixels`); else None."""
        return PIXEL_REFERENCE_IDS.get("cartpole/" + self.env_id.removeprefix("cartpole/"))


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
    if not isinstance(obs_space, gym.spaces.Box) or len(obs_space.shape) not in (1, 3):
        raise UnsupportedEnvError(
            f"{env_id} has a {type(obs_space).__name__}{getattr(obs_space, 'shape', '')} "
            "observation; supported: a flat Box observation, or images [channels, height, width], "
            "with Discrete actions"
        )
    if not isinstance(act_space, gym.spaces.Discrete):
        raise UnsupportedEnvError(
            f"{env_id} has {type(act_space).__name__} actions; supported: Discrete actions "
            "with a flat Box observation"
        )
    shape = tuple(int(n) for n in obs_space.shape)
    low, high = np.asarray(obs_space.low), np.asarray(obs_space.high)
    if len(shape) == 3:  # one range for every pixel, not one per pixel
        low, high = np.asarray([low.min()]), np.asarray([high.max()])
    return EnvInfo(
        env_id=env_id,
        obs_dim=math.prod(shape),
        n_actions=int(act_space.n),
        reward_threshold=spec.reward_threshold,
        max_episode_steps=spec.max_episode_steps,
        obs_low=tuple(float(v) for v in low),
        obs_high=tuple(float(v) for v in high),
        obs_shape=shape,
    )
