"""Vector envs that a checkpoint can put back mid-episode, from public per-env state only.

A learner that collects from a vector env must, on resume, continue the episodes in progress: the
same states, the same random start states after them, the same time limits. No private internals of
Gymnasium's vector envs are saved; a checkpoint holds, as plain JSON data:

- our fast CartPole simulator: its public ``snapshot()`` (states, step counters, pending autoresets,
  reset bounds, generator state), given back to ``restore()``;
- Gymnasium's ``CartPoleVectorEnv``: its public ``state`` array and its ``np_random`` bit-generator
  state; its ``steps`` and ``prev_done`` are set from the episode lengths and pending autoresets the
  learner tracks itself;
- every other env (Acrobot-v1, MountainCar-v0, ...): Gymnasium's ``SyncVectorEnv`` over single envs
  whose time limit is :class:`EpisodeClock` instead of Gymnasium's ``TimeLimit`` (whose step count is
  private). Per env, ``env.unwrapped.state`` and ``env.unwrapped.np_random``'s bit-generator state are
  saved; the clock's elapsed steps and pending reset are set from the learner's own counters.

An env whose state is not reachable this way (e.g. Box2D envs such as LunarLander, whose
``unwrapped.state`` does not exist, and any env inside wrappers, which may keep state of their own)
cannot be saved: :func:`vector_env_state` returns None and the learner starts fresh episodes on
resume (the resume says so).
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np

from cartpole.envs import EnvInfo, Simulator, as_env_info, make_env, make_vec_env, registered_spec


class EpisodeClock(gym.Wrapper[Any, Any, Any, Any]):
    """Gymnasium's ``TimeLimit`` with public counters: truncates once ``elapsed_steps`` reaches
    ``max_episode_steps`` (the same rule, the same flags), and lets a checkpoint set where it stands.

    ``reset_pending`` makes the next ``step`` a reset (reward 0, not terminated, not truncated, the
    action ignored): exactly what ``SyncVectorEnv``'s next-step autoreset does for an env that ended an
    episode, so a restored env that was awaiting its autoreset gets it.
    """

    def __init__(self, env: gym.Env[Any, Any], max_episode_steps: int | None):
        super().__init__(env)
        self.max_episode_steps = max_episode_steps
        self.elapsed_steps = 0
        self.reset_pending = False

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        if self.reset_pending:
            observation, info = self.reset()
            return observation, 0.0, False, False, info
        observation, reward, terminated, truncated, info = self.env.step(action)
        self.elapsed_steps += 1
        if self.max_episode_steps is not None and self.elapsed_steps >= self.max_episode_steps:
            truncated = True
        return observation, reward, terminated, truncated, info

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict]:
        self.elapsed_steps = 0
        self.reset_pending = False
        return self.env.reset(seed=seed, options=options)


def make_resumable_vec_env(env: str | EnvInfo, num_envs: int, simulator: Simulator) -> gym.vector.VectorEnv:
    """A vector env of ``num_envs`` copies of ``env`` (next-step autoreset) that
    :func:`restore_vector_env_state` can put back mid-episode (where its state is public)."""
    info = as_env_info(env)
    if info.is_cartpole and not info.wrappers:  # batched CartPole, ours or Gymnasium's: both keep
        return make_vec_env(info, num_envs, simulator=simulator)  # their per-env state public
    if info.pixels_of:  # Gymnasium's CartPole seen through its pictures: frame stacks are not public
        return make_vec_env(info, num_envs, simulator=simulator)  # state, so a resume starts afresh
    without_limit = dataclasses.replace(registered_spec(info.made_id), max_episode_steps=None)
    clock = functools.partial(EpisodeClock, max_episode_steps=info.max_episode_steps)
    wrappers: list[Callable[[gym.Env[Any, Any]], gym.Wrapper[Any, Any, Any, Any]]] = [
        clock
    ]  # where TimeLimit was,
    wrappers += [wrapper.wrap for wrapper in info.wrappers]  # below the env's own wrappers
    return gym.make_vec(without_limit, num_envs, vectorization_mode="sync", wrappers=wrappers, **info.kwargs)


def why_episodes_restart(env: EnvInfo) -> str | None:
    """Why a resume of a run on ``env`` (not CartPole, not pixels) starts fresh episodes rather than
    the ones in progress: its wrappers, or an env whose state is not public (Box2D's); None when it
    continues them."""
    if (env.is_cartpole and not env.wrappers) or env.pixels_of:
        return None
    if env.wrappers:
        return "wrappers may keep state of their own"
    made = make_env(env)
    try:
        made.reset(seed=0)
        state = getattr(made.unwrapped, "state", None)
    finally:
        made.close()
    return None if isinstance(state, np.ndarray | tuple) else f"{env.env_id} keeps no public state"


def vector_env_state(envs: gym.vector.VectorEnv) -> dict[str, Any] | None:
    """The per-env state of ``envs`` as plain data, or None when it is not reachable publicly."""
    base = envs.unwrapped
    snapshot = getattr(base, "snapshot", None)
    if snapshot is not None:  # our fast simulator
        return {"kind": "snapshot", "snapshot": snapshot()}
    sub_envs = getattr(base, "envs", None)
    if sub_envs is not None:  # SyncVectorEnv: one state per env, if every env has a clock and a state
        if not all(isinstance(env, EpisodeClock) for env in sub_envs):
            return None
        # Acrobot keeps an array, MountainCar a (position, velocity) tuple: both restore as an array.
        states = [getattr(env.unwrapped, "state", None) for env in sub_envs]
        arrays = [np.asarray(state) for state in states if isinstance(state, np.ndarray | tuple)]
        if len(arrays) != len(sub_envs):
            return None
        return {
            "kind": "per_env",
            "envs": [
                {"state": _array_data(state), "np_random": env.unwrapped.np_random.bit_generator.state}
                for env, state in zip(sub_envs, arrays, strict=True)
            ],
        }
    state = getattr(base, "state", None)
    if isinstance(state, np.ndarray) and hasattr(base, "prev_done"):  # Gymnasium's CartPoleVectorEnv
        return {
            "kind": "batched",
            "state": _array_data(state),
            "np_random": base.np_random.bit_generator.state,
        }
    return None


def restore_vector_env_state(
    envs: gym.vector.VectorEnv,
    saved: dict[str, Any] | None,
    episode_lengths: np.ndarray,
    reset_pending: np.ndarray,
) -> bool:
    """Put ``envs`` (freshly made and reset) back where :func:`vector_env_state` found them.

    ``episode_lengths`` (steps of each env's episode in progress) and ``reset_pending`` (envs whose
    last step ended an episode) are the learner's own counters. False when ``saved`` is None.
    """
    if saved is None or "kind" not in saved:  # not saved, or by a version that pickled other internals
        return False
    base = envs.unwrapped
    if saved["kind"] == "snapshot":
        base.restore(saved["snapshot"])  # type: ignore[attr-defined]
    elif saved["kind"] == "per_env":
        sub_envs = base.envs  # type: ignore[attr-defined]
        if len(sub_envs) != len(saved["envs"]):
            raise ValueError(f"a state of {len(saved['envs'])} envs cannot restore {len(sub_envs)} envs")
        for env, env_state, elapsed, pending in zip(
            sub_envs, saved["envs"], episode_lengths, reset_pending, strict=True
        ):
            env.unwrapped.state = _array(env_state["state"])
            env.unwrapped.np_random.bit_generator.state = env_state["np_random"]
            env.elapsed_steps, env.reset_pending = int(elapsed), bool(pending)
    elif saved["kind"] == "batched":
        base.state = _array(saved["state"])  # type: ignore[attr-defined]
        base.np_random.bit_generator.state = saved["np_random"]
        base.steps = np.asarray(episode_lengths, dtype=np.int32)  # type: ignore[attr-defined]
        base.prev_done = np.asarray(reset_pending, dtype=np.bool_)  # type: ignore[attr-defined]
    else:
        raise ValueError(f"unknown vector env state kind {saved['kind']!r}")
    return True


def _array_data(array: np.ndarray) -> dict[str, Any]:
    return {"values": array.tolist(), "dtype": str(array.dtype)}  # floats survive JSON exactly


def _array(data: dict[str, Any]) -> np.ndarray:
    return np.asarray(data["values"], dtype=data["dtype"])
