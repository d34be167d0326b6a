"""Training budgets: env steps, episodes, iterations (generations) or wall-clock time."""

from __future__ import annotations

import re
from dataclasses import asdict, dataclass
from typing import Any

_UNITS = {
    "": "env_steps",
    "k": "env_steps",
    "m": "env_steps",
    "ep": "episodes",
    "episodes": "episodes",
    "it": "iterations",
    "gen": "iterations",
    "generations": "iterations",
    "s": "seconds",
    "sec": "seconds",
    "min": "seconds",
}
_PATTERN = re.compile(r"^\s*(\d+(?:\.\d+)?(?:e\d+)?)\s*([a-z]*)\s*$", re.IGNORECASE)


@dataclass(frozen=True)
class Budget:
    """When training stops at the latest; any limit reached ends it. None means no limit."""

    env_steps: int | None = None
    episodes: int | None = None
    iterations: int | None = None
    seconds: float | None = None

    def to_dict(self) -> dict[str, Any]:
        return {k: v for k, v in asdict(self).items() if v is not None}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Budget:
        return cls(**{k: data[k] for k in ("env_steps", "episodes", "iterations", "seconds") if k in data})

    def describe(self) -> str:
        return ", ".join(f"{v:g} {k.replace('_', ' ')}" for k, v in self.to_dict().items()) or "none"


def parse_budget(text: str) -> Budget:
    """Parse ``50000``, ``50k``, ``1e5`` (env steps), ``300ep``, ``20gen``/``20it``, ``90s``, ``5min``."""
    match = _PATTERN.match(text)
    unit = match.group(2).lower() if match else None
    if not match or unit not in _UNITS:
        raise ValueError(
            f"bad budget {text!r}: use env steps (50000, 50k, 1e5), episodes (300ep), "
            "generations (20gen) or time (90s, 5min)"
        )
    value = float(match.group(1))
    value *= {"k": 1e3, "m": 1e6, "min": 60.0}.get(unit, 1.0)
    if value <= 0:
        raise ValueError(f"bad budget {text!r}: it must be positive")
    field = _UNITS[unit]
    return Budget(**{field: value if field == "seconds" else int(value)})
