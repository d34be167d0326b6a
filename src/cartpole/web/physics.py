"""One cart-pole simulated on the server, a step at a time, for the Watch and Play pages.

The browser only draws: every state it shows comes from here. ``CartPoleSim`` steps its state with
our fast simulator's kernel (``cartpole.envs.fast.CartPoleStepper``: the same bits as its
``CartPoleEnv`` and as Gymnasium's equations, without an env's per-step checks and copies).
Physics overrides use the field names of ``CartPoleParams`` (``length`` is the pole's *half* length,
as in Gymnasium).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import lru_cache
from typing import Any

import numpy as np

from cartpole.envs import env_info
from cartpole.envs.fast import CartPoleParams, CartPoleStepper
from cartpole.evaluation import start_states

PHYSICS_LIMITS: dict[str, tuple[float, float]] = {
    "gravity": (0.0, 100.0),
    "length": (0.05, 5.0),
    "masspole": (0.01, 10.0),
    "masscart": (0.01, 50.0),
    "force_mag": (0.0, 100.0),
}
"""The physics a page may change, and the range each must stay in (inclusive)."""

PHYSICS_LABELS = {
    "gravity": "gravity (m/s²)",
    "length": "pole half-length (m)",
    "masspole": "pole mass (kg)",
    "masscart": "cart mass (kg)",
    "force_mag": "push force (N)",
}


class PhysicsError(ValueError):
    """A physics override is unknown or out of range."""


def check_overrides(overrides: dict[str, Any]) -> dict[str, float]:
    """Validated overrides (floats in range); PhysicsError with one clear line otherwise."""
    checked: dict[str, float] = {}
    for name, value in overrides.items():
        if name not in PHYSICS_LIMITS:
            raise PhysicsError(f"unknown physics field {name!r}; use {', '.join(PHYSICS_LIMITS)}")
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise PhysicsError(f"{name} must be a number, got {value!r}")
        low, high = PHYSICS_LIMITS[name]
        if not low <= float(value) <= high:  # also rejects NaN
            raise PhysicsError(f"{name} must be between {low:g} and {high:g}, got {value!r}")
        checked[name] = float(value)
    return checked


SCENES = {"Acrobot-v1": "acrobot", "MountainCar-v0": "mountaincar"}
"""The envs besides CartPole whose episodes the Watch page draws (by the name of its drawing)."""

ACTION_LABELS = {
    "cartpole": ["\u2190 push left", "push right \u2192"],
    "acrobot": ["torque \u22121", "no torque", "torque +1"],
    "mountaincar": ["\u2190 push left", "no push", "push right \u2192"],
}
"""What each action of a scene's env does, in its order."""


def scene_of(env_id: str) -> str | None:
    """Which drawing shows ``env_id`` ("cartpole", "acrobot", "mountaincar"), None if none does.
    A pixel env's scene is CartPole's: its episodes move through CartPole states."""
    return "cartpole" if is_cartpole(state_env_id(env_id)) else SCENES.get(env_id.removeprefix("cartpole/"))


def state_env_id(env_id: str) -> str:
    """The env whose states ``env_id``'s episodes move through: for a pixel env, the Gymnasium
    CartPole it shows (``cartpole/CartPolePixels-v1`` -> ``CartPole-v1``: its start states, limits
    and physics); else ``env_id`` itself."""
    try:
        return env_info(env_id).pixels_of or env_id
    except ValueError:
        return env_id


def is_cartpole(env_id: str) -> bool:
    """Watch and Play simulate CartPole only."""
    try:
        return env_info(env_id).is_cartpole
    except ValueError:
        return False


@lru_cache(maxsize=4096)
def _start_state(env_id: str, seed: int) -> tuple[float, ...]:
    return tuple(float(v) for v in start_states(env_id, [seed])[0])


def start_state(env_id: str, seed: int) -> np.ndarray:
    """Gymnasium's exact start state for ``reset(seed=seed)``, as ``evaluate()`` plays it (a pixel
    env's: that of the CartPole it shows)."""
    return np.array(_start_state(state_env_id(env_id), seed), dtype=np.float64)


def default_physics() -> dict[str, float]:
    """CartPole's own physics constants (``CartPoleParams``' defaults, never written here); every
    CartPole id shares them."""
    params = CartPoleParams()
    return {name: float(getattr(params, name)) for name in PHYSICS_LIMITS}


@dataclass
class StepResult:
    state: np.ndarray
    reward: float
    terminated: bool
    truncated: bool


class CartPoleSim:
    """A cart-pole whose state and physics can be set, stepped one action at a time."""

    def __init__(self, env_id: str, overrides: dict[str, float] | None = None):
        info = env_info(state_env_id(env_id))  # a pixel env's time limit is its CartPole's
        if not info.is_cartpole:
            raise PhysicsError(f"{env_id} is not CartPole: only CartPole can be watched or played")
        self.env_id = env_id
        self.max_steps = info.max_episode_steps
        self.stepper = CartPoleStepper()
        params = self.stepper.params
        self.x_threshold, self.theta_threshold = params.x_threshold, params.theta_threshold_radians
        self.tau = params.tau
        self.overrides: dict[str, float] = {}
        self.set_physics(overrides or {})
        self.state = np.zeros(4)
        self.steps = 0
        self.done = True

    def set_physics(self, overrides: dict[str, Any]) -> None:
        """Apply validated overrides on top of the env's defaults (an empty dict restores them)."""
        checked = check_overrides(overrides)
        # checked holds only float fields; mypy cannot tell which keys **checked has.
        self.stepper.set_params(replace(CartPoleParams(), **checked))  # type: ignore[arg-type]
        self.overrides = checked

    def physics(self) -> dict[str, float]:
        return {**default_physics(), **self.overrides}

    def reset(self, state: np.ndarray) -> np.ndarray:
        self.state = np.asarray(state, dtype=np.float64).copy()
        self.steps, self.done = 0, False
        return self.state

    def step(self, action: int) -> StepResult:
        if self.done:
            raise PhysicsError("the episode is over: reset first")
        if action not in (0, 1):
            raise PhysicsError(f"action must be 0 (push left) or 1 (push right), got {action!r}")
        next_state = np.empty(4)  # a new array each step: an earlier StepResult's state stays put
        terminated = self.stepper.step(self.state, action, out=next_state)
        self.state = next_state
        self.steps += 1
        truncated = self.max_steps is not None and self.steps >= self.max_steps  # as TimeLimit
        self.done = terminated or truncated
        return StepResult(self.state, 1.0, bool(terminated), truncated)


class GymSim:
    """Gymnasium's own env (Acrobot-v1, MountainCar-v0) stepped one action at a time, as a person
    plays it: the state is the env's own ``state`` (what its drawing needs)."""

    def __init__(self, env_id: str):
        import gymnasium as gym

        if env_id.removeprefix("cartpole/") not in SCENES:
            raise PhysicsError(f"{env_id} cannot be played here; play CartPole-v1, {', '.join(SCENES)}")
        self.env_id = env_id
        self.env = gym.make(env_id)
        self.n_actions = int(self.env.action_space.n)  # type: ignore[attr-defined]
        self.max_steps = self.env.spec.max_episode_steps if self.env.spec else None
        self.state = np.zeros(0)  # the env has no state before its first reset
        self.steps = 0
        self.done = True

    def limits(self) -> dict[str, float]:
        unwrapped = self.env.unwrapped
        limits = {
            "fps": float(self.env.metadata.get("render_fps") or 30),
            "max_steps": float(self.max_steps or 0),
        }
        for name in ("LINK_LENGTH_1", "LINK_LENGTH_2", "min_position", "max_position", "goal_position"):
            if hasattr(unwrapped, name):
                limits[name.lower()] = float(getattr(unwrapped, name))
        return limits

    def reset(self, seed: int) -> np.ndarray:
        """Gymnasium's ``reset(seed=seed)``, the start state ``evaluate()`` plays from."""
        observation, _ = self.env.reset(seed=seed)
        self.observation = np.asarray(observation, dtype=np.float32)
        self.state = np.asarray(self.env.unwrapped.state, dtype=np.float64).copy()  # type: ignore[attr-defined]
        self.steps, self.done = 0, False
        return self.state

    def step(self, action: int) -> StepResult:
        if self.done:
            raise PhysicsError("the episode is over: reset first")
        if not 0 <= action < self.n_actions:
            raise PhysicsError(f"action must be between 0 and {self.n_actions - 1}, got {action!r}")
        observation, reward, terminated, truncated, _ = self.env.step(action)
        self.observation = np.asarray(observation, dtype=np.float32)
        self.state = np.asarray(self.env.unwrapped.state, dtype=np.float64).copy()  # type: ignore[attr-defined]
        self.steps += 1
        self.done = bool(terminated or truncated)
        return StepResult(self.state, float(reward), bool(terminated), bool(truncated))

    def close(self) -> None:
        self.env.close()
