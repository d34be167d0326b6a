"""One name for each thing: run states, stop reasons and checkpoint names, used everywhere."""

from __future__ import annotations

from enum import StrEnum


class RunState(StrEnum):
    """What a run folder says about its training (``status.json``'s ``state``), as shown to people."""

    RUNNING = "running"
    FINISHED = "finished"
    INTERRUPTED = "interrupted"
    FAILED = "failed"
    CRASHED = "crashed"
    """Its process is gone without saying so (killed, power lost): ``--resume`` continues it."""
    UNREADABLE = "unreadable"
    """A file of the run cannot be read; the summary says which and why."""
    INCOMPLETE = "incomplete"
    """Being created: ``config.json`` is not written yet."""
    UNKNOWN = "unknown"


class StopReason(StrEnum):
    """Why the training loop stopped (the machine value; a human detail is kept beside it)."""

    SOLVED = "solved"
    BUDGET = "budget"
    INTERRUPTED = "interrupted"
    FAILED = "failed"
    CALLBACK = "callback"


class CheckpointName(StrEnum):
    """The checkpoints a run keeps, as ``checkpoints/<name>.pt``."""

    LATEST = "latest"
    """Everything needed to resume, written periodically and at exit."""
    BEST = "best"
    """The policy with the best evaluation so far."""
    SOLVED = "solved"
    """The policy of the first verified solve."""
