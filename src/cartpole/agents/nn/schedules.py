"""The schedules of a learning rate (and of PPO's clip range) over a seed's env steps: constant, or
decayed linearly to 0 (Stable-Baselines3's and the RL Zoo's ``lin_<value>``)."""

from __future__ import annotations

SCHEDULES = ("constant", "linear")


def schedule_value(start: float, schedule: str, env_steps: int, schedule_steps: int) -> float:
    """``start`` (constant), or ``start`` decayed linearly to 0 at ``schedule_steps`` env steps (linear)."""
    if schedule == "constant":
        return start
    return start * max(0.0, 1.0 - env_steps / schedule_steps)


__all__ = ["SCHEDULES", "schedule_value"]
