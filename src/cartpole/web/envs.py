"""The envs the web app offers, the only ones a request may name.

Every route and WebSocket that takes an env from a request (``POST /api/trainings``,
``/api/training-options``, ``/ws/play``) looks it up in :data:`OFFERED_ENVS` before anything makes,
looks up or imports an env: an id such as ``mypkg:MyEnv-v0`` names a module that Gymnasium would
import, and a request must never make the server run code it names. Envs of one's own train with
``cartpole train --env``; their run folders are shown (and replayed) as any other.
"""

from __future__ import annotations

OFFERED_ENVS = (
    "CartPole-v1",
    "CartPole-v0",
    "Acrobot-v1",
    "MountainCar-v0",
    "cartpole/CartPolePixels-v1",
)
"""The envs the web app trains and plays (its pages list them); a request naming any other is refused."""


def offered(env_id: object) -> bool:
    """Whether a request may name ``env_id``: one of :data:`OFFERED_ENVS`, compared as text (nothing
    is looked up)."""
    return isinstance(env_id, str) and env_id in OFFERED_ENVS


def shown_env(env_id: str, limit: int = 40) -> str:
    """An env id a request gave, quoted and cut to ``limit`` characters, for a one-line refusal."""
    return repr(env_id if len(env_id) <= limit else env_id[: limit - 1] + "\u2026")


__all__ = ["OFFERED_ENVS", "offered", "shown_env"]
