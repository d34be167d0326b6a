"""Run folders and checkpoints: the record of every training run."""

from cartpole.runs.checkpoint import (
    Checkpoint,
    CheckpointError,
    UnreadableCheckpoint,
    load_checkpoint,
    save_checkpoint,
)
from cartpole.runs.run_dir import (
    LiveStatus,
    RunBusy,
    RunDir,
    RunError,
    RunSummary,
    displayed_state,
    list_runs,
    summarize_run,
)

__all__ = [
    "Checkpoint",
    "CheckpointError",
    "LiveStatus",
    "RunBusy",
    "RunDir",
    "RunError",
    "RunSummary",
    "UnreadableCheckpoint",
    "displayed_state",
    "list_runs",
    "load_checkpoint",
    "save_checkpoint",
    "summarize_run",
]
