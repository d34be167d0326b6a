"""Training budgets: env steps, episodes, iterations (generations) or wall-clock time."""

from __future__ import annotations

import re
from dataclasses import asdict, dataclass
from typing import Any

from cartpole.core.errors import ConfigError

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
_PATTERN = re.compile(r"^\s*(\d+(?:\.\d+)?(?:e\+?\d+)?)\s*([a-z]*)\s*$", re.IGNORECASE)
_SCALE = {"k": 1e3, "m": 1e6, "min": 60.0}
MAX_COUNT = 10**15
"""The largest step, episode or generation count a budget may name (far past any real run)."""
MAX_SECONDS = 10 * 365 * 24 * 3600.0
"""Ten years: the largest time budget."""
HOW = "use env steps (50000, 50k, 1e5), episodes (300ep), generations (20gen) or time (90s, 5min)"


class BudgetError(ConfigError):
    """A budget that cannot be parsed, or one that no run could have (0.5 steps, 1e400 steps)."""


@dataclass(frozen=True)
class Budget:
    """When training stops at the latest; any limit reached ends it. None means no limit."""

    env_steps: int | None = None
    episodes: int | None = None
    iterations: int | None = None
    seconds: float | None = None

    def __post_init__(self) -> None:
        for name, value in asdict(self).items():
            if value is not None:
                _check_limit(name, value)

    def to_dict(self) -> dict[str, Any]:
        return {k: v for k, v in asdict(self).items() if v is not None}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Budget:
        """The budget recorded in a run's config.json; BudgetError if it is not one."""
        unknown = sorted(set(data) - set(LIMITS))
        if unknown:
            raise BudgetError(
                f"recorded budget has an unknown limit {unknown[0]!r}; known: {', '.join(LIMITS)}"
            )
        return cls(**data)

    def describe(self) -> str:
        return ", ".join(f"{v:g} {k.replace('_', ' ')}" for k, v in self.to_dict().items()) or "none"


LIMITS = ("env_steps", "episodes", "iterations", "seconds")
_WORDS = {"env_steps": "env steps", "episodes": "episodes", "iterations": "generations"}


def _check_limit(name: str, value: Any) -> None:
    """BudgetError unless ``value`` is a usable limit: a whole count >= 1, or a time > 0 s."""
    words = _WORDS.get(name, name)
    if name == "seconds":
        if isinstance(value, bool) or not isinstance(value, int | float) or not 0 < value <= MAX_SECONDS:
            raise BudgetError(f"a time budget must be between 0 and {MAX_SECONDS:g} s, got {value!r}")
    elif isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= MAX_COUNT:
        raise BudgetError(
            f"a budget of {words} must be a whole number from 1 to {MAX_COUNT:.0e}, got {value!r}"
        )


def check_budget_unit(budget: Budget, agent: str, iteration: str) -> None:
    """BudgetError unless ``agent``, whose ``learn()`` is one ``iteration`` ("generation" or "step"),
    can spend ``budget``: generations mean something only to an agent that learns in generations."""
    if budget.iterations is not None and iteration != "generation":
        raise BudgetError(
            f"a budget of {budget.iterations} generations means nothing to {agent}, which learns in "
            "gradient steps, not generations; give env steps (50k), episodes (300ep) or time (90s)"
        )


def parse_budget(text: str) -> Budget:
    """Parse ``50000``, ``50k``, ``1e5`` (env steps), ``300ep``, ``20gen``/``20it``, ``90s``, ``5min``.

    Counts must come out whole (``1.5k`` is 1500 steps; ``0.5`` and ``1.5gen`` are refused)."""
    match = _PATTERN.match(text)
    unit = match.group(2).lower() if match else None
    if not match or unit not in _UNITS:
        raise BudgetError(f"bad budget {text!r}: {HOW}")
    value = float(match.group(1)) * _SCALE.get(unit, 1.0)
    field = _UNITS[unit]
    if field == "seconds":
        if not 0 < value <= MAX_SECONDS:
            raise BudgetError(f"bad budget {text!r}: a time must be more than 0 s and at most ten years")
        return Budget(seconds=value)
    if not (value.is_integer() and 1 <= value <= MAX_COUNT):
        raise BudgetError(
            f"bad budget {text!r}: {_WORDS[field]} must be a whole number from 1 to {MAX_COUNT:.0e}"
        )
    return Budget(**{field: int(value)})
