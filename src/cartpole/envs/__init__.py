"""Environments: Gymnasium's registry, and our fast batched CartPole simulator.

``make_vec_env`` is the one place that decides which simulator steps an env id:
``simulator="gymnasium"`` always uses Gymnasium's own implementation (the reference, used for every
"solved" verdict by default); ``simulator="fast"`` uses :mod:`cartpole.envs.fast` for CartPole ids and
falls back to Gymnasium for any other env. Our pixel envs (``cartpole/CartPolePixels-v1``, -v0) are
drawn by our fast renderer on ``"fast"``, and on ``"gymnasium"`` are Gymnasium's own CartPole seen
through :class:`~cartpole.envs.pixels.GymnasiumPixels` (its ``rgb_array`` pictures, preprocessed the
same way), so their verdicts rest on Gymnasium's physics and drawing too.

Each function takes an env id or an :class:`EnvInfo` (an env as configured: its kwargs and wrappers,
:func:`env_info`); a configured env runs on Gymnasium's implementation, with its wrappers around
each single env, except CartPole with kwargs that only our simulator takes (its physics constants,
:attr:`EnvInfo.simulator_only`), which runs on ours everywhere, verdicts included.
"""

from __future__ import annotations

from functools import partial
from typing import TYPE_CHECKING, Any, Literal

import gymnasium as gym
import numpy as np

from cartpole.core.errors import ConfigError
from cartpole.envs.registration import fast_env_id, register_fast_envs, register_pixel_envs
from cartpole.envs.spec import (
    EnvInfo,
    UnsupportedEnvError,
    WrapperSpec,
    as_env_info,
    check_kwargs,
    check_wrappers,
    describe_kwargs,
    env_info,
    judged_env,
    make_env,
    registered_spec,
)

if TYPE_CHECKING:
    from cartpole.envs.shards import ShardedEnvs

register_fast_envs()  # cheap: string entry points, nothing compiled until an env is made
register_pixel_envs()

Simulator = Literal["fast", "gymnasium"]
SIMULATORS: tuple[Simulator, ...] = ("fast", "gymnasium")
FAST_DTYPE = np.float32
"""The float type our fast simulator steps in for training (its envs default to float64, Gymnasium's
bits; float32 is several times faster at many envs: :mod:`cartpole.envs.fast`)."""
EVAL_DTYPE = np.float64
"""The float type of our fast simulator's CartPole in evaluations: float64, so that an evaluation on
it plays Gymnasium's own episodes bit for bit (its equations, its start states, the C library's sine
and cosine), at the speed of our simulator."""


def check_simulator(name: str, setting: str = "simulator") -> Simulator:
    """``name`` as a :data:`Simulator`: the one check of simulator names (configs and envs use it).

    ConfigError naming ``setting`` and the choices when it is not one.
    """
    if name not in SIMULATORS:
        raise ConfigError(f"{setting} must be one of {', '.join(SIMULATORS)}, got {name!r}")
    return name  # narrowed to Simulator by the check above


def resolve_simulator(env: str | EnvInfo, simulator: str) -> Simulator:
    """The simulator that will really run ``env``: "fast" only exists for CartPole (and its pixels),
    as registered (no kwargs, no wrappers); and CartPole with kwargs only our simulator takes
    (:attr:`EnvInfo.simulator_only`) runs on it whatever ``simulator`` asks."""
    checked = check_simulator(simulator)
    info = as_env_info(env)
    if info.simulator_only:
        return "fast"
    fast = (info.is_cartpole or info.pixels_of) and not info.configured
    return "fast" if checked == "fast" and fast else "gymnasium"


def make_vec_env(
    env: str | EnvInfo,
    num_envs: int,
    *,
    simulator: str = "gymnasium",
    dtype: type[np.floating[Any]] = FAST_DTYPE,
) -> gym.vector.VectorEnv:
    """A vector env of ``num_envs`` copies of ``env`` with Gymnasium's next-step autoreset; ``dtype``:
    what our fast simulator steps in."""
    info = as_env_info(env)  # validates the id and its spaces with a clear message
    used = resolve_simulator(info, simulator)
    if info.pixels_of and info.configured:
        raise UnsupportedEnvError(f"{info.env_id} takes no env kwargs or wrappers: {info.label}")
    if info.wrappers:
        return gym.vector.SyncVectorEnv([partial(make_env, info)] * num_envs)
    if used == "fast":
        return gym.make_vec(
            fast_env_id(info.env_id),
            num_envs=num_envs,
            vectorization_mode="vector_entry_point",
            dtype=dtype,
            **info.kwargs,
        )
    if info.pixels_of:
        return gymnasium_pixels_vec_env(info.pixels_of, num_envs, info.obs_shape)
    return gym.make_vec(registered_spec(info.env_id), num_envs=num_envs, **info.kwargs)


def gymnasium_pixels_vec_env(
    reference_id: str, num_envs: int, obs_shape: tuple[int, ...]
) -> gym.vector.VectorEnv:
    """``num_envs`` of Gymnasium's own ``reference_id`` (CartPole) seen as frame stacks of
    ``obs_shape`` through :class:`~cartpole.envs.pixels.GymnasiumPixels`, stepped in turn (each
    draws Gymnasium's 600x400 picture every step: the honest reference, not a fast one)."""
    return gym.vector.SyncVectorEnv([partial(make_gymnasium_pixels, reference_id, obs_shape)] * num_envs)


def make_gymnasium_pixels(reference_id: str, obs_shape: tuple[int, ...]) -> gym.Env[Any, Any]:
    """One of Gymnasium's own ``reference_id`` envs seen as frame stacks of ``obs_shape``."""
    from cartpole.envs.pixels import GymnasiumPixels  # numba kernels: only when pixels are asked for

    stack, height, width = obs_shape
    env = gym.make(reference_id, render_mode="rgb_array")
    return GymnasiumPixels(env, frame_size=(height, width), stack=stack)


def make_eval_envs(
    env: str | EnvInfo, num_envs: int, *, simulator: str = "gymnasium", workers: int = 1
) -> gym.vector.VectorEnv | ShardedEnvs:
    """The envs an evaluation plays: :func:`make_vec_env`'s, except that Gymnasium's pictures (a
    pixel env on ``simulator="gymnasium"``) are drawn by ``workers`` processes when ``workers`` > 1
    (:class:`~cartpole.envs.shards.ShardedEnvs`: the same episodes, sooner), that our fast
    CartPole steps in :data:`EVAL_DTYPE` (Gymnasium's bits), and that an env with wrappers reports
    the env's own reward over its own episodes (:mod:`cartpole.envs.judged`), with the registry's time
    limit (:func:`~cartpole.envs.spec.judged_env`)."""
    info = judged_env(as_env_info(env))
    if workers > 1 and info.pixels_of and resolve_simulator(info, simulator) == "gymnasium":
        from cartpole.envs.shards import ShardedEnvs

        return ShardedEnvs(partial(make_gymnasium_pixels, info.pixels_of, info.obs_shape), num_envs, workers)
    if info.wrappers:
        from cartpole.envs.judged import make_judged_env

        return gym.vector.SyncVectorEnv([partial(make_judged_env, info)] * num_envs)
    return make_vec_env(
        info, num_envs, simulator=simulator, dtype=EVAL_DTYPE if info.is_cartpole else FAST_DTYPE
    )


__all__ = [
    "SIMULATORS",
    "EnvInfo",
    "Simulator",
    "UnsupportedEnvError",
    "WrapperSpec",
    "as_env_info",
    "check_kwargs",
    "check_simulator",
    "check_wrappers",
    "describe_kwargs",
    "env_info",
    "fast_env_id",
    "judged_env",
    "make_env",
    "make_eval_envs",
    "make_vec_env",
    "registered_spec",
    "resolve_simulator",
]
