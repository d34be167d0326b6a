"""The env a verdict is played on when wrappers are put around it: what the agent sees and does goes
through every wrapper, but the return is the env's own.

Gymnasium's rule ("solved" is a mean return of the registry's ``reward_threshold`` over 100
episodes) is about the env's own reward over the env's own episode. A wrapper may scale or shape
rewards, or end episodes on its own terms, for training; in a verdict :class:`OwnReward` (just above
the env and its registry's time limit, below every wrapper) notes the env's reward and episode end,
and :class:`JudgedByOwnReward` (above every wrapper) hands them on instead of the wrappers' own.
A wrapper that ends episodes earlier can only lower a verdict; one that changes rewards cannot
change it.
"""

from __future__ import annotations

import dataclasses
from typing import Any, SupportsFloat

import gymnasium as gym

from cartpole.envs.spec import EnvInfo, make_env


class OwnReward(gym.Wrapper[Any, Any, Any, Any]):
    """Notes the reward and episode end of the env below it, passing everything on unchanged."""

    def __init__(self, env: gym.Env[Any, Any]):
        super().__init__(env)
        self.last_reward = 0.0
        self.ended = False

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        observation, reward, terminated, truncated, info = self.env.step(action)
        self.last_reward, self.ended = float(reward), bool(terminated or truncated)
        return observation, reward, terminated, truncated, info

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict]:
        self.last_reward, self.ended = 0.0, False
        return self.env.reset(seed=seed, options=options)


class JudgedByOwnReward(gym.Wrapper[Any, Any, Any, Any]):
    """Reports ``own``'s reward instead of the wrappers', and ends the episode where either the
    env's own episode or the wrappers' ends."""

    def __init__(self, env: gym.Env[Any, Any], own: OwnReward):
        super().__init__(env)
        self.own = own

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        observation, _, terminated, truncated, info = self.env.step(action)
        ended_below = self.own.ended and not (terminated or truncated)  # a wrapper hid the end
        return observation, self.own.last_reward, bool(terminated), bool(truncated or ended_below), info


def make_judged_env(env: EnvInfo, **make_args: Any) -> gym.Env[Any, Any]:
    """One env of ``env`` as configured, for a verdict: its wrappers act, its own reward counts."""
    own = OwnReward(make_env(dataclasses.replace(env, wrappers=()), **make_args))
    wrapped: gym.Env[Any, Any] = own
    for wrapper in env.wrappers:
        wrapped = wrapper.wrap(wrapped)
    return JudgedByOwnReward(wrapped, own)


__all__ = ["JudgedByOwnReward", "OwnReward", "make_judged_env"]
