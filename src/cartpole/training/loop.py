"""Each seed's training loop: its counters (:class:`LoopState`) and its callbacks.

The engine (:mod:`cartpole.training.engine`) steps a population and hands each seed's loop its
result (:meth:`TrainingLoop.advance`); the loop counts it and tells its callbacks about every step,
every finished episode and every evaluation, until one of them says stop. Progress, metrics,
periodic evaluation, checkpoints, stop-when-solved and budgets are all callbacks
(:mod:`cartpole.training.callbacks`), so no agent re-implements them.
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from cartpole.agents.learner import Learner, LearnResult
from cartpole.core.names import StopReason
from cartpole.evaluation import EvalReport
from cartpole.runs.atomic import DISK_FULL


def failure_detail(error: BaseException) -> str:
    """What a run's status says of the error that ended it: "failed: disk full (writing FILE)" for a
    full disk, else the error's type and message."""
    if isinstance(error, OSError) and error.errno in DISK_FULL:
        return f"failed: disk full (writing {error.filename})" if error.filename else "failed: disk full"
    return f"failed: {type(error).__name__}: {error}"


@dataclass
class LoopState:
    """Counters the loop keeps and callbacks read; saved in checkpoints so a resume continues."""

    env_steps: int = 0
    episodes: int = 0
    iterations: int = 0
    elapsed: float = 0.0
    """Seconds of training so far, summed over resumed sessions."""
    evaluations: int = 0
    last_eval_step: int = 0
    """Env steps at the last evaluation, so a resumed run keeps the evaluation schedule."""
    best_eval_mean: float | None = None
    solved: bool = False
    solved_at_step: int | None = None
    solved_at_seconds: float | None = None
    recent_returns: deque[float] = field(default_factory=lambda: deque(maxlen=100))
    scalars: dict[str, float] = field(default_factory=dict)
    last_eval: EvalReport | None = None
    stop_reason: StopReason | None = None
    """Why training stopped (None while it goes on); saved, so a resume knows training was complete."""
    stop_detail: str | None = None
    """The same for people, e.g. "budget reached (50000 env steps)"."""

    @property
    def mean_recent_return(self) -> float | None:
        return float(np.mean(self.recent_returns)) if self.recent_returns else None

    def stop(self, reason: StopReason, detail: str) -> None:
        """Record why training stops (the first reason given wins)."""
        if self.stop_reason is None:
            self.stop_reason, self.stop_detail = reason, detail

    def clear_stop(self) -> None:
        """Forget an interruption or failure: a resumed session trains on."""
        self.stop_reason = self.stop_detail = None

    def to_dict(self) -> dict[str, Any]:
        keys = (
            "env_steps",
            "episodes",
            "iterations",
            "last_eval_step",
            "elapsed",
            "evaluations",
            "best_eval_mean",
            "solved",
            "solved_at_step",
            "solved_at_seconds",
        )
        return {k: getattr(self, k) for k in keys} | {
            "recent_returns": list(self.recent_returns),
            "stop_reason": self.stop_reason.value if self.stop_reason else None,
            "stop_detail": self.stop_detail,
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> LoopState:
        state = cls(**{k: v for k, v in data.items() if k not in ("recent_returns", "stop_reason")})
        state.recent_returns.extend(data.get("recent_returns", []))
        reason = data.get("stop_reason")
        state.stop_reason = StopReason(reason) if reason else None
        return state


class Callback:
    """Hooks of the loop. ``on_step``/``on_episode``/``on_eval`` return False to stop training."""

    def on_start(self, loop: TrainingLoop) -> None:
        """Training (or a resumed session) begins."""

    def on_step(self, loop: TrainingLoop, result: LearnResult) -> bool:
        """After each ``learn()``, once the counters are updated."""
        return True

    def on_episode(self, loop: TrainingLoop, episode_return: float, length: int) -> bool:
        """For each finished training episode."""
        return True

    def on_eval(self, loop: TrainingLoop, report: EvalReport) -> bool:
        """After each evaluation (see ``TrainingLoop.record_eval``)."""
        return True

    def on_end(self, loop: TrainingLoop) -> None:
        """Training ends, whatever the reason (``loop.state.stop_reason``)."""


class TrainingLoop:
    """One seed's counters and callbacks, from :meth:`start` through each :meth:`advance` to
    :meth:`end`; ``learner`` is the seed, as its callbacks see it."""

    def __init__(self, learner: Learner, callbacks: list[Callback], state: LoopState | None = None):
        self.learner = learner
        self.callbacks = callbacks
        self.state = state or LoopState()
        self._stop_requested: tuple[StopReason, str] | None = None
        self.clock_start = time.perf_counter()

    def request_stop(self, reason: StopReason, detail: str) -> None:
        """Stop after the current step (safe to call from a signal handler)."""
        self._stop_requested = (reason, detail)

    def record_eval(self, report: EvalReport) -> bool:
        """Note an evaluation in the counters and tell every callback; False if one says stop."""
        state = self.state
        state.evaluations += 1
        state.last_eval = report
        if state.best_eval_mean is None or report.mean > state.best_eval_mean:
            state.best_eval_mean = report.mean
        if report.solved and not state.solved:
            state.solved = True
            state.solved_at_step = state.env_steps
            state.solved_at_seconds = state.elapsed
        return all([cb.on_eval(self, report) for cb in self.callbacks])

    def count_result(self, result: LearnResult, elapsed: float) -> bool:
        """Add one ``learn()`` result to the counters and show its episodes, then the step, to the
        callbacks; False if one of them asks to stop."""
        state = self.state
        state.env_steps += result.env_steps
        state.iterations += 1
        state.elapsed = elapsed
        state.scalars.update(result.scalars)
        state.episodes += result.summarized_episodes
        keep_going = True
        for ret, length in zip(result.episode_returns, result.episode_lengths, strict=True):
            state.episodes += 1
            state.recent_returns.append(ret)
            keep_going &= all([cb.on_episode(self, ret, length) for cb in self.callbacks])
        keep_going &= all([cb.on_step(self, result) for cb in self.callbacks])
        return keep_going

    def start(self, clock_start: float) -> None:
        """Training (or a resumed session) begins; ``clock_start`` is ``time.perf_counter()`` now."""
        self.clock_start = clock_start - self.state.elapsed
        for cb in self.callbacks:
            cb.on_start(self)

    def advance(self, result: LearnResult, now: float) -> None:
        """Count one ``learn()`` result (the engine steps every seed's learner at once and hands each
        loop its seed's result); a callback's or a signal's stop is recorded in the state."""
        keep_going = self.count_result(result, now - self.clock_start)
        if self._stop_requested:
            self.state.stop(*self._stop_requested)
        elif not keep_going:
            self.state.stop(StopReason.CALLBACK, "stopped by a callback")

    def end(self, now: float) -> None:
        """Training ends, whatever the reason: the callbacks save what they keep."""
        self.state.elapsed = now - self.clock_start
        for cb in self.callbacks:
            cb.on_end(self)
