"""One name for each thing a run folder records: run states, stop reasons, checkpoint names.

Each is a ``StrEnum``: its members compare equal to (and serialize as) the plain strings written in
``status.json`` and in checkpoint file names, so the JSON files and the web pages keep their values.
"""

from __future__ import annotations

from enum import StrEnum


class RunState(StrEnum):
    """The state of a run as written in ``status.json`` and as displayed."""

    RUNNING = "running"
    """A process is training it (or judging its final verdict)."""
    FINISHED = "finished"
    """Training ended and the final verdict (``eval.json``) is on disk."""
    INTERRUPTED = "interrupted"
    """Stopped by a signal (Ctrl-C, SIGTERM); ``--resume`` continues it."""
    FAILED = "failed"
    """Stopped by an error; ``--resume`` continues it from its last checkpoint."""
    CRASHED = "crashed"
    """Displayed only: status says running, but its process is gone (kill -9, power loss)."""
    UNKNOWN = "unknown"
    """No ``status.json`` yet, or a state this version does not know."""
    UNREADABLE = "unreadable"
    """A file of the run cannot be read; the reason is given beside it."""
    CORRUPT = "corrupt"
    INCOMPLETE = "incomplete"

    @property
    def stopped(self) -> bool:
        """No process will write to the run any more (until a ``--resume``)."""
        return self in (RunState.FINISHED, RunState.INTERRUPTED, RunState.FAILED, RunState.CRASHED)


class StopReason(StrEnum):
    """Why training stopped (the machine value; a human detail is kept beside it)."""

    BUDGET = "budget"
    SOLVED = "solved"
    CALLBACK = "callback"
    """A callback said stop."""
    INTERRUPTED = "interrupted"
    FAILED = "failed"


class CheckpointName(StrEnum):
    """The checkpoints a run keeps in ``checkpoints/<name>.pt``."""

    LATEST = "latest"
    """Everything needed to resume; written periodically and at the end."""
    BEST = "best"
    """The policy of the best evaluation (what the final verdict judges)."""
    SOLVED = "solved"
    """The policy of the first verified solve."""
