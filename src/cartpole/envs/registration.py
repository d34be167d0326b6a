"""Our envs in Gymnasium's registry: ``cartpole/CartPole-v1`` and ``cartpole/CartPole-v0``.

``import cartpole`` registers them (entry points are strings: nothing is compiled or imported until an
env is made), so after the import ``gym.make_vec("cartpole/CartPole-v1", num_envs=8)`` works, and
``gym.make("cartpole:cartpole/CartPole-v1")`` works with no import at all, as third-party envs do.
"""

from __future__ import annotations

import gymnasium as gym

REFERENCE_IDS: tuple[str, ...] = ("CartPole-v0", "CartPole-v1")
"""Gymnasium's envs that our fast simulator reproduces."""
_NAMESPACE = "cartpole"


def register_fast_envs() -> None:
    """Register ``cartpole/CartPole-v0`` and ``cartpole/CartPole-v1`` with Gymnasium (idempotent).

    Time limits and reward thresholds are copied from Gymnasium's own registrations at runtime, so
    ``gymnasium.make`` and ``gymnasium.make_vec`` give our envs the same limits as the originals.
    """
    for reference_id in REFERENCE_IDS:
        env_id = f"{_NAMESPACE}/{reference_id}"
        if env_id in gym.registry:
            continue
        reference = gym.spec(reference_id)
        gym.register(
            id=env_id,
            entry_point="cartpole.envs.fast:CartPoleEnv",
            vector_entry_point="cartpole.envs.fast:CartPoleVectorEnv",
            max_episode_steps=reference.max_episode_steps,
            reward_threshold=reference.reward_threshold,
        )
