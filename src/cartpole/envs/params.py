"""The physical constants of the cart-pole (:class:`CartPoleParams`), apart from the simulator that
uses them (:mod:`cartpole.envs.fast`) so its numba kernels can read them without importing it."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

KinematicsIntegrator = Literal["euler", "semi-implicit euler"]


@dataclass(frozen=True)
class CartPoleParams:
    """Physical constants of the cart-pole; defaults are Gymnasium's CartPole-v1."""

    gravity: float = 9.8
    """Gravitational acceleration (m/s²), pulling the pole down; >= 0."""
    masscart: float = 1.0
    """Mass of the cart (kg); > 0."""
    masspole: float = 0.1
    """Mass of the pole (kg); > 0."""
    length: float = 0.5
    """Half the pole's length (m), as Gymnasium defines it; > 0."""
    force_mag: float = 10.0
    """Magnitude of the push of each action (N); >= 0."""
    tau: float = 0.02
    """Seconds between two states; > 0."""
    theta_threshold_radians: float = 12 * 2 * math.pi / 360
    """The episode terminates when the pole's angle leaves [-this, this]; > 0."""
    x_threshold: float = 2.4
    """The episode terminates when the cart's position leaves [-this, this]; > 0."""
    kinematics_integrator: KinematicsIntegrator = "euler"
    """"euler" (Gymnasium's default) or "semi-implicit euler"."""

    def __post_init__(self) -> None:
        positive = ("masscart", "masspole", "length", "tau", "theta_threshold_radians", "x_threshold")
        for f in fields(self):
            if f.name == "kinematics_integrator":
                continue
            value = getattr(self, f.name)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
                raise ValueError(f"CartPoleParams.{f.name} must be a number, got {value!r}")
            value = float(value)
            if not math.isfinite(value):
                raise ValueError(f"CartPoleParams.{f.name} must be finite, got {value}")
            if f.name in positive and value <= 0:
                raise ValueError(f"CartPoleParams.{f.name} must be > 0, got {value}")
            if value < 0:
                raise ValueError(f"CartPoleParams.{f.name} must be >= 0, got {value}")
            object.__setattr__(self, f.name, value)  # store plain floats, whatever came in
        if self.kinematics_integrator not in ("euler", "semi-implicit euler"):
            raise ValueError(
                "CartPoleParams.kinematics_integrator must be 'euler' or 'semi-implicit euler', "
                f"got {self.kinematics_integrator!r}"
            )

    @property
    def total_mass(self) -> float:
        """Cart plus pole (kg), summed as Gymnasium sums it."""
        return self.masspole + self.masscart

    @property
    def polemass_length(self) -> float:
        """Pole mass times half-length (kg·m)."""
        return self.masspole * self.length

    def observation_high(self) -> NDArray[np.float32]:
        """Upper bound of the observation space: twice the thresholds, so a failing state fits."""
        inf = np.inf
        return np.array([self.x_threshold * 2, inf, self.theta_threshold_radians * 2, inf], dtype=np.float32)


PHYSICS_KWARGS: tuple[str, ...] = tuple(f.name for f in fields(CartPoleParams))
"""The constants our CartPole envs take as keyword arguments (``--env-kwargs gravity=5``); Gymnasium's
own CartPole takes none of them."""


def with_physics(params: CartPoleParams | None, physics: Mapping[str, Any]) -> CartPoleParams | None:
    """``params`` (None: the defaults) with the constants named in ``physics`` changed; TypeError for a
    name that is not one (as a constructor refuses an unknown keyword), ValueError for a bad value."""
    if not physics:
        return params
    unknown = [name for name in physics if name not in PHYSICS_KWARGS]
    if unknown:
        raise TypeError(
            f"unexpected keyword argument {unknown[0]!r} (physics constants: {', '.join(PHYSICS_KWARGS)})"
        )
    return dataclasses.replace(params or CartPoleParams(), **physics)


__all__ = ["PHYSICS_KWARGS", "CartPoleParams", "KinematicsIntegrator", "with_physics"]
