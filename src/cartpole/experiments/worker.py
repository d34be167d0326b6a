"""One run of an experiment, in its own process: train (or resume) one seed of one entry.

``python -m cartpole.experiments.worker TASK.json`` trains the seed the task names and writes what it
measured to the task's ``record`` file (atomically). A record whose run is ``finished`` means the work is
done; an ``interrupted`` one names the run folder that a later worker resumes. SIGINT and SIGTERM stop
training at the next step with ``checkpoints/latest.pt`` saved (the training session's own handling).
"""

from __future__ import annotations

import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from cartpole.evaluation import EvalReport
from cartpole.runs.atomic import write_json_atomic
from cartpole.training import Callback, TrainingLoop, TrainOutcome

FINISHED = "finished"
INTERRUPTED = "interrupted"


class SolveClock(Callback):
    """CPU seconds of training (all threads), summed over resumed sessions, and at the first solve."""

    def __init__(self, cpu_before: float = 0.0, solve_cpu: float | None = None):
        self.cpu_before = cpu_before
        self.solve_cpu = solve_cpu
        self.cpu = cpu_before
        self._start = 0.0

    def on_start(self, loop: TrainingLoop) -> None:
        self._start = time.process_time()

    def on_eval(self, loop: TrainingLoop, report: EvalReport) -> bool:
        if report.solved and self.solve_cpu is None:
            self.solve_cpu = self.cpu_before + time.process_time() - self._start
        return True

    def on_end(self, loop: TrainingLoop) -> None:
        self.cpu = self.cpu_before + time.process_time() - self._start


@dataclass(frozen=True)
class Task:
    """One seed of one entry, and where its run folder and record go."""

    agent: str
    preset: str
    seed: int
    env_id: str
    budget: str | None
    runs_dir: str
    record: str
    command: list[str]
    """The command that asked for the run (recorded in its config.json)."""

    @classmethod
    def load(cls, path: Path) -> Task:
        return cls(**json.loads(path.read_text(encoding="utf-8")))


def read_record(path: Path) -> dict[str, Any] | None:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError):
        return None


def warm_up(env_id: str) -> None:
    """Load what a first use loads (numba's cached kernels, Gymnasium's env modules) before timing."""
    import numpy as np

    from cartpole.evaluation import evaluate

    class Left:
        def act(self, observations: np.ndarray) -> np.ndarray:
            return np.zeros(len(observations), dtype=np.int64)

    for simulator in ("fast", "gymnasium"):
        evaluate(Left(), env_id, 2, seed=0, simulator=simulator)


def resumable(record: dict[str, Any] | None) -> Path | None:
    """The run folder of an interrupted record, if it can be resumed (it has ``latest.pt``)."""
    if not record or record.get("state") != INTERRUPTED or not record.get("run"):
        return None
    run = Path(record["run"])
    return run if (run / "checkpoints" / "latest.pt").is_file() else None


def run_task(task: Task) -> dict[str, Any]:
    """Train or resume the task's run; write and return its record."""
    from cartpole.training import resume, train

    path = Path(task.record)
    record = read_record(path)
    if record and record.get("state") == FINISHED:
        return record
    warm_up(task.env_id)
    previous = resumable(record)
    if previous is not None and record is not None:
        clock = SolveClock(record.get("cpu_seconds", 0.0), record.get("solve_cpu_seconds"))
        outcome = resume(previous, quiet=True, device="cpu", callbacks=[clock])
    else:
        clock = SolveClock()
        outcome = train(
            task.agent,
            task.env_id,
            seed=task.seed,
            preset=task.preset,
            budget=task.budget,
            runs_dir=task.runs_dir,
            device="cpu",
            quiet=True,
            command=task.command,
            callbacks=[clock],
        )
    record = make_record(task, outcome, clock)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_json_atomic(path, record)
    return record


def make_record(task: Task, outcome: TrainOutcome, clock: SolveClock) -> dict[str, Any]:
    """What the report needs about one run: its folder, when it solved, what it used, its verdict."""
    state, report = outcome.state, outcome.report
    return {
        "agent": task.agent,
        "preset": task.preset,
        "seed": task.seed,
        "run": str(outcome.run.path),
        "state": INTERRUPTED if outcome.signal is not None else FINISHED,
        "solved_in_training": state.solved,
        "solve_steps": state.solved_at_step,
        "solve_wall_seconds": state.solved_at_seconds,
        "solve_cpu_seconds": clock.solve_cpu,
        "env_steps": state.env_steps,
        "wall_seconds": state.elapsed,
        "cpu_seconds": clock.cpu,
        "stop_reason": state.stop_reason,
        "final_mean": None if report is None else report.mean,
        "final_solved": None if report is None else report.solved,
        "final_verdict": None if report is None else report.verdict,
    }


def main(argv: list[str]) -> int:
    """Run the task in ``argv[0]``; exit 0 when finished, 130 when interrupted."""
    from cartpole.core.errors import InputError

    try:
        record = run_task(Task.load(Path(argv[0])))
    except InputError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    return 0 if record["state"] == FINISHED else 130


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
