"""The env a verdict is played on when wrappers are put around it: what the agent sees and does goes
through every wrapper, but the episode and its return are the env's own.

Gymnasium's rule ("solved" is a mean return of the registry's ``reward_threshold`` over 100
episodes) is about the env's own reward over the env's own episode. A wrapper may scale or shape
rewards, repeat actions, or end episodes on its own terms, for training. In a verdict
:class:`OwnReward` (just above the env and its registry's time limit, below every wrapper) adds up
the env's reward over every step the env takes, however many steps an action became, and notes the
env's own episode end; :class:`JudgedByOwnReward` (above every wrapper) hands them on instead of the
wrappers' own. So:

- a wrapper that changes rewards changes no judged return;
- a wrapper that repeats actions (frame skip) has each of the env's rewards counted once;
- a wrapper that hides the env's end does not lengthen a judged episode: it ends where the env's does;
- a wrapper that ends an episode before the env does (its own time limit, an early stop) leaves
  an episode that is not the env's: with negative rewards a cut episode scores *better*, so no rule
  can be read from it. The episode ends there and counts as *cut* by that wrapper
  (:attr:`JudgedByOwnReward.cut_by`); a verdict with cut episodes calls nothing solved
  (:attr:`~cartpole.evaluation.EvalReport.cut_by`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable
from typing import Any, SupportsFloat

import gymnasium as gym

from cartpole.envs.spec import EnvInfo, make_env


class OwnReward(gym.Wrapper[Any, Any, Any, Any]):
    """Adds up the reward of the env below it until :meth:`take_reward`, and notes its episode's
    end, passing everything on unchanged. Rewards after the env's own end are not the episode's,
    not even where a wrapper resets the env itself and plays on: only :meth:`start`, at the judged
    episode's reset, begins another."""

    def __init__(self, env: gym.Env[Any, Any]):
        super().__init__(env)
        self.reward = 0.0
        self.terminated = self.truncated = False

    @property
    def ended(self) -> bool:
        return self.terminated or self.truncated

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        observation, reward, terminated, truncated, info = self.env.step(action)
        if not self.ended:
            self.reward += float(reward)
            self.terminated, self.truncated = bool(terminated), bool(truncated)
        return observation, reward, terminated, truncated, info

    def take_reward(self) -> float:
        """The env's reward since the last call (every step an action became), and zero after."""
        reward, self.reward = self.reward, 0.0
        return reward

    def start(self) -> None:
        """A judged episode begins: nothing counted yet."""
        self.reward, self.terminated, self.truncated = 0.0, False, False


class EndProbe(gym.Wrapper[Any, Any, Any, Any]):
    """Notes whether the wrapper below it (``label``) ended the last step's episode."""

    def __init__(self, env: gym.Env[Any, Any], label: str):
        super().__init__(env)
        self.label = label
        self.ended = False

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        observation, reward, terminated, truncated, info = self.env.step(action)
        self.ended = bool(terminated or truncated)
        return observation, reward, terminated, truncated, info


class JudgedByOwnReward(gym.Wrapper[Any, Any, Any, Any]):
    """Reports ``own``'s reward instead of the wrappers', and ends the episode where the env's own
    episode ends; where a wrapper ended it first, the episode ends there too and :attr:`cut_by`
    names the lowest wrapper that ended it (``probes``, from the env upwards)."""

    def __init__(self, env: gym.Env[Any, Any], own: OwnReward, probes: Iterable[EndProbe]):
        super().__init__(env)
        self.own = own
        self.probes = list(probes)
        self.cut_by: str | None = None
        """The wrapper that ended this episode before the env did (None: the env ended it, or it
        runs on)."""

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        observation, _, terminated, truncated, info = self.env.step(action)
        reward = self.own.take_reward()
        if self.own.ended:
            return observation, reward, self.own.terminated, not self.own.terminated, info
        if terminated or truncated:  # a wrapper ended an episode the env had not
            self.cut_by = next((probe.label for probe in self.probes if probe.ended), "a wrapper")
            return observation, reward, False, True, info
        return observation, reward, False, False, info

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict]:
        self.own.start()
        self.cut_by = None
        return self.env.reset(seed=seed, options=options)


def make_judged_env(env: EnvInfo, **make_args: Any) -> gym.Env[Any, Any]:
    """One env of ``env`` as configured, for a verdict: its wrappers act, its own reward and episode
    count."""
    own = OwnReward(make_env(dataclasses.replace(env, wrappers=()), **make_args))
    wrapped: gym.Env[Any, Any] = own
    probes = []
    for wrapper in env.wrappers:
        wrapped = EndProbe(wrapper.wrap(wrapped), wrapper.label)
        probes.append(wrapped)
    return JudgedByOwnReward(wrapped, own, probes)


def cut_by_episode(envs: Iterable[gym.Env[Any, Any]]) -> list[str | None]:
    """For each of ``envs``, the wrapper that cut its last episode short (None: none did; an env
    that is not judged cuts none)."""
    return [env.cut_by if isinstance(env, JudgedByOwnReward) else None for env in envs]


__all__ = ["EndProbe", "JudgedByOwnReward", "OwnReward", "cut_by_episode", "make_judged_env"]
