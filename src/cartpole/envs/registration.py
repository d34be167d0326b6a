"""Our envs in Gymnasium's registry: ``cartpole/CartPole-v1`` and ``cartpole/CartPole-v0`` (the fast
state simulator), ``cartpole/CartPolePixels-v1`` and ``cartpole/CartPolePixels-v0`` (the same seen as
stacks of gray frames, :mod:`cartpole.envs.pixels`).

``import cartpole`` registers them (entry points are strings: nothing is compiled or imported until an
env is made), so after the import ``gym.make_vec("cartpole/CartPole-v1", num_envs=8)`` works, and
``gym.make("cartpole:cartpole/CartPole-v1")`` works with no import at all, as third-party envs do.
"""

from __future__ import annotations

import gymnasium as gym

REFERENCE_IDS: tuple[str, ...] = ("CartPole-v0", "CartPole-v1")
"""Gymnasium's envs that our fast simulator reproduces."""
_NAMESPACE = "cartpole"


def fast_env_id(env_id: str) -> str:
    """The id under which our fast simulator registers the CartPole env ``env_id``."""
    return f"{_NAMESPACE}/" + env_id.removeprefix(f"{_NAMESPACE}/")


def pixel_env_id(reference_id: str) -> str:
    """The id of the pixel env that shows Gymnasium's ``reference_id`` (``CartPole-v1`` ->
    ``cartpole/CartPolePixels-v1``)."""
    return f"{_NAMESPACE}/{reference_id.replace('CartPole', 'CartPolePixels')}"


PIXEL_REFERENCE_IDS: dict[str, str] = {pixel_env_id(r): r for r in REFERENCE_IDS}
"""Pixel env id -> the Gymnasium env it shows: the state env its verdicts are played on (through
:class:`~cartpole.envs.pixels.GymnasiumPixels`)."""


def _register(env_id: str, reference_id: str, module: str, single: str, vector: str) -> None:
    """Register ``env_id`` with the time limit and reward threshold of Gymnasium's ``reference_id``."""
    if env_id in gym.registry:
        return
    reference = gym.spec(reference_id)
    gym.register(
        id=env_id,
        entry_point=f"{module}:{single}",
        vector_entry_point=f"{module}:{vector}",
        max_episode_steps=reference.max_episode_steps,
        reward_threshold=reference.reward_threshold,
    )


def register_fast_envs() -> None:
    """Register ``cartpole/CartPole-v0`` and ``cartpole/CartPole-v1`` with Gymnasium (idempotent).

    Time limits and reward thresholds are copied from Gymnasium's own registrations at runtime, so
    ``gymnasium.make`` and ``gymnasium.make_vec`` give our envs the same limits as the originals.
    """
    for reference_id in REFERENCE_IDS:
        _register(
            f"{_NAMESPACE}/{reference_id}",
            reference_id,
            "cartpole.envs.fast",
            "CartPoleEnv",
            "CartPoleVectorEnv",
        )


def register_pixel_envs() -> None:
    """Register ``cartpole/CartPolePixels-v0`` and ``-v1`` with Gymnasium (idempotent): the fast
    simulator seen as frame stacks, with the time limits and thresholds of CartPole-v0 and -v1."""
    for reference_id in REFERENCE_IDS:
        _register(
            pixel_env_id(reference_id),
            reference_id,
            "cartpole.envs.pixels",
            "CartPolePixelsEnv",
            "CartPolePixelsVectorEnv",
        )
