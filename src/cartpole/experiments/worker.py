"""One job of an experiment, in its own process: train (or resume) one seed of one entry, or every
pending seed of an entry whose agent batches its seeds, as one population in one process.

``python -m cartpole.experiments.worker TASK.json [--device cpu|cuda]`` trains the seeds the task names
on that torch device (default: cpu; a GPU slot's worker sees one GPU, :mod:`~cartpole.experiments.slots`)
and writes what it measured, the device included, to each seed's ``record`` file (atomically). A record
whose run is ``finished`` means the work is done; an ``interrupted`` one names the run folder that a
later worker resumes. SIGINT and SIGTERM stop
training at the next step with ``checkpoints/latest.pt`` saved (the training session's own handling),
and so do the parent's stop request and the parent's end
(:func:`~cartpole.experiments.processes.follow_parent`). Stops that come together (Slurm signals every
process of a task, and the parent asks too) stop the worker once: :class:`StopRequests`.
"""

from __future__ import annotations

import _thread
import json
import signal
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from cartpole.evaluation import EvalReport
from cartpole.runs.atomic import write_json_atomic
from cartpole.training import Callback, TrainingLoop, TrainOutcome
from cartpole.training.engine import PopulationOutcome
from cartpole.training.loop import LoopState

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
    population: dict[int, str] | None = None
    """Seed -> record file of every seed trained as one population (``seed``/``record`` name the first)."""
    overrides: dict[str, Any] = field(default_factory=dict)
    """Settings over the preset's (the comparison's ``--env-kwargs``)."""
    tensorboard: bool = False
    """``--tensorboard``: new runs also log TensorBoard events (a resumed run keeps what it had)."""
    device: str = "cpu"
    """The torch device (the worker's ``--device``, its slot's), recorded in each seed's record."""

    @classmethod
    def load(cls, path: Path) -> Task:
        fields = json.loads(path.read_text(encoding="utf-8"))
        if fields.get("population") is not None:
            fields["population"] = {int(seed): record for seed, record in fields["population"].items()}
        return cls(**fields)


class StopRequests:
    """A worker's stop requests (SIGINT: the parent's, through
    :func:`~cartpole.experiments.processes.follow_parent`, or a Ctrl-C; SIGTERM: Slurm's, which signals
    every process of a task, so that both come at once) outside a training session's own handling:
    noted, never raised in the middle of a write.

    Before training the worker checks them (:meth:`check`: exit 130, nothing written). While a session
    runs (:meth:`session`), the engine takes them (it saves ``latest.pt`` and stops at the next step);
    one that comes while the session sets up or ends, when the engine's handler is not in place (it
    saves its runs after its loop, with the handlers before it back), is only noted, so that the
    record of what it saved is still written, and delivered again every :data:`REDELIVER_SECONDS`
    until the session returns, so that the engine hears it once its handler is there."""

    REDELIVER_SECONDS = 0.2

    def __init__(self) -> None:
        self.noted: list[int] = []

    @contextmanager
    def installed(self) -> Iterator[StopRequests]:
        """Note SIGINT and SIGTERM here (the handlers before are back after)."""
        signals = (signal.SIGINT, signal.SIGTERM)
        previous = {s: signal.signal(s, lambda signum, frame: self.noted.append(signum)) for s in signals}
        try:
            yield self
        finally:
            for s, handler in previous.items():
                signal.signal(s, handler)

    def check(self) -> None:
        """KeyboardInterrupt where a stop was asked for (before anything is trained or written)."""
        if self.noted:
            raise KeyboardInterrupt

    @contextmanager
    def session(self) -> Iterator[None]:
        """Around a training session: a stop noted meanwhile is delivered again (as SIGINT, to whatever
        handler is in place) every :data:`REDELIVER_SECONDS` until the session returns."""
        done = threading.Event()

        def redeliver() -> None:
            while not done.wait(self.REDELIVER_SECONDS):
                if self.noted:
                    _thread.interrupt_main(signal.SIGINT)

        thread = threading.Thread(target=redeliver, name="stop-requests", daemon=True)
        thread.start()
        try:
            yield
        finally:
            done.set()
            thread.join()


STOPS = StopRequests()
"""This worker's stop requests (installed by :func:`main`; a task run in a test's process has none)."""


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
    """Train or resume the task's run (or population); write and return its (first seed's) record."""
    if task.population is not None:
        return run_population_task(task, task.population)
    from cartpole.training import resume, train

    path = Path(task.record)
    record = read_record(path)
    if record and record.get("state") == FINISHED:
        return record
    warm_up(task.env_id)
    STOPS.check()
    previous = resumable(record)
    with STOPS.session():
        if previous is not None and record is not None:
            clock = SolveClock(record.get("cpu_seconds", 0.0), record.get("solve_cpu_seconds"))
            outcome = resume(previous, quiet=True, device=task.device, callbacks=[clock])
        else:
            clock = SolveClock()
            outcome = train(
                task.agent,
                task.env_id,
                seed=task.seed,
                preset=task.preset,
                overrides=task.overrides,
                budget=task.budget,
                runs_dir=task.runs_dir,
                device=task.device,
                quiet=True,
                command=task.command,
                tensorboard=task.tensorboard,
                callbacks=[clock],
            )
    record = make_record(task, outcome, clock)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_json_atomic(path, record)
    return record


def make_record(task: Task, outcome: TrainOutcome, clock: SolveClock) -> dict[str, Any]:
    """What the report needs about one run: its folder, when it solved, what it used, its verdict."""
    return {
        "agent": task.agent,
        "preset": task.preset,
        "seed": task.seed,
        "run": str(outcome.run.path),
        "state": INTERRUPTED if outcome.signal is not None else FINISHED,
        "device": task.device,
    } | run_fields(outcome.state, outcome.report, clock)


def run_fields(state: LoopState, report: EvalReport | None, clock: SolveClock) -> dict[str, Any]:
    """When a run solved, what it used, its verdict."""
    return {
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


def run_population_task(task: Task, records: dict[int, str]) -> dict[str, Any]:
    """Resume the interrupted members, then train the new seeds, each as one population; write every
    seed's record. A seed's CPU seconds are its population's CPU time divided by its seed count."""
    from cartpole.training.session import resume_population, train_population

    paths = {seed: Path(record) for seed, record in records.items()}
    found = {seed: read_record(path) for seed, path in paths.items()}
    todo = {seed for seed, record in found.items() if not record or record.get("state") != FINISHED}
    written = {seed: record for seed, record in found.items() if seed not in todo and record}
    if todo:
        warm_up(task.env_id)
    while todo:
        STOPS.check()
        previous = {seed: resumable(found[seed]) for seed in sorted(todo)}
        interrupted = [run for run in previous.values() if run is not None]
        cpu_start = time.process_time()
        with STOPS.session():
            if interrupted:
                outcome = resume_population(interrupted[0], quiet=True, device=task.device)
            else:
                outcome = train_population(
                    task.agent,
                    sorted(todo),
                    task.env_id,
                    preset=task.preset,
                    overrides=task.overrides,
                    budget=task.budget,
                    runs_dir=task.runs_dir,
                    device=task.device,
                    quiet=True,
                    command=task.command,
                    tensorboard=task.tensorboard,
                )
        cpu_share = (time.process_time() - cpu_start) / len(outcome.runs)
        owned = [seed for seed in outcome.runs if seed in todo]  # a resumed population may hold others
        if not owned:
            raise RuntimeError(f"resuming {interrupted[0]} trained none of seeds {sorted(todo)}")
        for seed in owned:
            record = make_population_record(task, seed, outcome, cpu_share, found[seed])
            paths[seed].parent.mkdir(parents=True, exist_ok=True)
            write_json_atomic(paths[seed], record)
            written[seed] = record
            todo.discard(seed)
        if outcome.signal is not None or STOPS.noted:
            break
    return written[min(written)] if written else {"state": INTERRUPTED}


def make_population_record(
    task: Task, seed: int, outcome: PopulationOutcome, cpu_share: float, before: dict[str, Any] | None
) -> dict[str, Any]:
    """:func:`make_record` for one seed of a population: CPU seconds are its share of the population's
    (summed over resumed sessions); at the first solve, that share times the fraction of the population's
    wall time the seed took to solve."""
    state, report = outcome.states[seed], outcome.reports.get(seed)
    cpu_before = (before or {}).get("cpu_seconds", 0.0) if resumable(before) else 0.0
    solve_cpu = (before or {}).get("solve_cpu_seconds") if resumable(before) else None
    cpu = cpu_before + cpu_share
    if solve_cpu is None and state.solved_at_seconds is not None:
        longest = max(s.elapsed for s in outcome.states.values())
        solve_cpu = cpu * min(1.0, state.solved_at_seconds / max(longest, 1e-9))
    clock = SolveClock(cpu_before, solve_cpu)
    clock.cpu = cpu
    fields = {
        "agent": task.agent,
        "preset": task.preset,
        "seed": seed,
        "run": str(outcome.runs[seed].path),
        "state": INTERRUPTED if outcome.signal is not None else FINISHED,
        "population": True,
        "device": task.device,
    }
    return fields | run_fields(state, report, clock)


def main(argv: list[str]) -> int:
    """Run the task in ``argv[0]`` (on ``--device DEVICE`` where ``argv`` ends with it) on ``cartpole
    train``'s default torch thread count; exit 0 when finished, 130 when interrupted (also when stopped
    before or between training sessions, where nothing is half-written: every write is atomic)."""
    from cartpole.core.errors import InputError
    from cartpole.experiments.processes import follow_parent
    from cartpole.training.threads import default_torch_threads, torch_threads

    try:
        follow_parent()  # inside: a stop asked for already interrupts as soon as it returns
        with STOPS.installed():
            task = Task.load(Path(argv[0]))
            if "--device" in argv:
                task = replace(task, device=argv[argv.index("--device") + 1])
            with torch_threads(default_torch_threads(task.env_id)):
                record = run_task(task)
        return 0 if record["state"] == FINISHED else 130
    except InputError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
