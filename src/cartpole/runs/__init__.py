"""Run folders and checkpoints: the record of every training run."""

from cartpole.runs.checkpoint import Checkpoint, CheckpointError, load_checkpoint, save_checkpoint
from cartpole.runs.names import CheckpointName, RunState, StopReason
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
    "CheckpointName",
    "LiveStatus",
    "RunBusy",
    "RunDir",
    "RunError",
    "RunState",
    "RunSummary",
    "StopReason",
    "displayed_state",
    "list_runs",
    "load_checkpoint",
    "save_checkpoint",
    "summarize_run",
]
