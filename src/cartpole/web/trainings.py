"""Trainings started from the web app: each one a ``cartpole train`` process of its own.

A training is the command :func:`~cartpole.training.request.train_command` gives for a checked
request, run as ``python -m cartpole train ...`` in the folder the server was started in: its run
folders record that command, so the same run starts from a terminal. Stop asks it to stop as Ctrl-C
does (:func:`stop_training_process`: every seed saves ``latest.pt``); Resume runs ``cartpole train
--resume RUN``. At most ``max_running`` run at once; later ones wait in a queue, in order.

What the server knows of a training is written to ``<runs>/trainings/<name>.json`` (its request,
command, run folders, the problem that ended it) and its output to ``<name>.log``; its state is read
from its process and its run folders' ``status.json``. So after a restart the server lists its
trainings again, and one stopped with the server can be resumed.

The processes train on the CPU time nothing else wants (Linux's ``SCHED_IDLE``; elsewhere a lower
priority, ``NICENESS``): the server must keep answering play steps within milliseconds while they
train (``benchmarks/web_latency.py --trainings 2``), and at nice 10 its p99 was 19 ms, not 5.
"""

from __future__ import annotations

import contextlib
import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import UTC, datetime
from enum import StrEnum
from pathlib import Path
from typing import Any

from cartpole.core.errors import InputError
from cartpole.core.file_names import portable_name
from cartpole.core.names import RunState
from cartpole.runs import RunDir, displayed_state
from cartpole.runs.atomic import write_json_atomic
from cartpole.runs.run_dir import read_json, utc_now
from cartpole.training.request import TrainRequest, train_command
from cartpole.training.session import population_members

TRAININGS = "trainings"
"""The folder of the runs folder that keeps the web app's records of its trainings."""
NICENESS = 10
"""Where Linux's idle scheduling class is missing: how much lower than the server's a training
process's CPU priority is (POSIX ``nice``)."""
TICK_SECONDS = 0.2
"""How often the queue is looked at: ended processes reaped, waiting trainings started."""
STOP_SECONDS = 60.0
"""How long closing the server waits for a stopped training to save before it is killed."""
NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,199}$")
RUN_LINE = re.compile(r"^run: (?P<path>.+)$|^runs: \d+ in .+ \(seeds .+\), the first (?P<first>.+)$", re.M)
"""The line ``cartpole train`` names its run folder(s) with as training starts."""
ERROR_PREFIX = re.compile(r"^cartpole \w+: error: ")


class TrainingState(StrEnum):
    QUEUED = "queued"
    RUNNING = "running"
    STOPPED = "stopped"
    FINISHED = "finished"
    FAILED = "failed"


class TrainingError(InputError):
    """A stop or resume that cannot be done now (the web app answers 409), or no such training (404)."""

    def __init__(self, message: str, missing: bool = False):
        super().__init__(message)
        self.missing = missing


@dataclass
class Training:
    """One training, as its record holds it, with the process the server runs it in."""

    name: str
    request: dict[str, Any]
    command: list[str]
    created: str
    runs: list[str] = field(default_factory=list)
    problem: str | None = None
    waiting: list[str] | None = None
    """The command it waits in the queue to run (its start, or a resume); None: not waiting."""
    process: subprocess.Popen[bytes] | None = None
    log_from: int = 0
    """Where its current process's output starts in the log."""

    def record(self) -> dict[str, Any]:
        keys = ("name", "request", "command", "created", "runs", "problem")
        return {key: getattr(self, key) for key in keys}

    def running_here(self) -> bool:
        return self.process is not None and self.process.poll() is None


class Trainings:
    """The web app's trainings in ``runs_dir``, their queue and their processes."""

    def __init__(self, runs_dir: Path, max_running: int, cwd: Path | None = None):
        self.runs_dir = Path(runs_dir)
        self.max_running = max_running
        self.cwd = Path.cwd() if cwd is None else cwd
        self.folder = self.runs_dir / TRAININGS
        self.lock = threading.RLock()
        self.trainings: dict[str, Training] = {}
        self.queue: list[str] = []
        self.closed = threading.Event()
        self.thread: threading.Thread | None = None
        self.load()

    # --- records -----------------------------------------------------------------------------

    def load(self) -> None:
        """The trainings recorded in the runs folder (those of an earlier server too)."""
        if not self.folder.is_dir():
            return
        for path in sorted(self.folder.glob("*.json")):
            try:
                data = read_json(path)
                training = Training(
                    name=str(data["name"]),
                    request=dict(data["request"]),
                    command=[str(part) for part in data["command"]],
                    created=str(data["created"]),
                    runs=[str(run) for run in data.get("runs", [])],
                    problem=data.get("problem"),
                )
            except (OSError, ValueError, KeyError, TypeError):
                continue  # not one of ours, or damaged: its run folders are still listed as runs
            if NAME.match(training.name) and path.stem == training.name:
                self.trainings[training.name] = training

    def save(self, training: Training) -> None:
        self.folder.mkdir(parents=True, exist_ok=True)
        write_json_atomic(self.folder / f"{training.name}.json", training.record())

    def log_path(self, training: Training) -> Path:
        return self.folder / f"{training.name}.log"

    # --- actions -----------------------------------------------------------------------------

    def start(self, request: TrainRequest) -> Training:
        """A new training of ``request`` (checked already), started now or queued."""
        with self.lock:
            training = Training(
                name=self.new_name(request),
                request=request_record(request),
                command=train_command(request),
                created=utc_now(),
            )
            self.trainings[training.name] = training
            self.save(training)
            self.enqueue(training, training.command)
            return training

    def stop(self, name: str) -> Training:
        """Stop a training: its process asked to stop (it saves, as after Ctrl-C), or out of the queue."""
        with self.lock:
            training = self.get(name)
            if training.waiting is not None:
                self.queue.remove(name)
                training.waiting = None
                return training
            if training.running_here():
                assert training.process is not None
                stop_training_process(training.process.pid)
                return training
            pid = self.other_process(training)
            if pid is None:
                raise TrainingError(f"training {name} is not running (it is {self.state(training)})")
            stop_training_process(pid)  # started by an earlier server, still training
            return training

    def resume(self, name: str) -> Training:
        """Go on with a stopped (or failed) training: ``cartpole train --resume`` of its runs, or, if it
        never made a run folder, its start again."""
        with self.lock:
            training = self.get(name)
            state = self.state(training)
            if state in (TrainingState.RUNNING, TrainingState.QUEUED, TrainingState.FINISHED):
                raise TrainingError(f"training {name} is {state}: only a stopped or failed one resumes")
            if training.runs:
                first = Path(training.request.get("runs_dir", "runs")) / training.runs[0]
                command = ["cartpole", "train", "--resume", str(first)]
            else:
                command = training.command
            training.problem = None
            self.save(training)
            self.enqueue(training, command)
            return training

    def enqueue(self, training: Training, command: list[str]) -> None:
        training.waiting = command
        self.queue.append(training.name)
        self.start_waiting()

    def get(self, name: str) -> Training:
        training = self.trainings.get(name)
        if training is None:
            raise TrainingError(f"no training named {name!r}", missing=True)
        return training

    def new_name(self, request: TrainRequest) -> str:
        stamp = datetime.now(UTC).strftime("%Y%m%d-%H%M%S")
        base = f"{portable_name(request.env_id)}__{portable_name(request.agent)}__{stamp}"
        name, n = base, 1
        while name in self.trainings or (self.folder / f"{name}.json").exists():
            n += 1
            name = f"{base}-{n}"
        return name

    # --- the queue ---------------------------------------------------------------------------

    def open(self) -> None:
        """Start watching the queue (a thread), as the server starts."""
        self.thread = threading.Thread(target=self.watch, name="cartpole-web-trainings", daemon=True)
        self.thread.start()

    def watch(self) -> None:
        while not self.closed.wait(TICK_SECONDS):
            self.tick()

    def tick(self) -> None:
        """Learn each new process's run folders, note each ended one's problem, start waiting ones."""
        with self.lock:
            for training in self.trainings.values():
                if training.process is None:
                    continue
                if not training.runs:
                    self.find_runs(training)
                code = training.process.poll()
                if code is not None:
                    self.ended(training, code)
            self.start_waiting()

    def start_waiting(self) -> None:
        while self.queue and self.running_count() < self.max_running and not self.closed.is_set():
            training = self.trainings[self.queue.pop(0)]
            command, training.waiting = training.waiting or training.command, None
            self.spawn(training, command)

    def running_count(self) -> int:
        return sum(t.running_here() for t in self.trainings.values())

    def spawn(self, training: Training, command: list[str]) -> None:
        """Run ``command`` (a ``cartpole ...`` command line) for ``training``, its output to the log."""
        self.folder.mkdir(parents=True, exist_ok=True)
        log = self.log_path(training)
        with open(log, "ab") as out:
            training.log_from = out.tell()
            training.process = subprocess.Popen(
                [sys.executable, "-m", "cartpole", *command[1:]],
                cwd=self.cwd,
                stdin=subprocess.DEVNULL,
                stdout=out,
                stderr=subprocess.STDOUT,
                **own_process_group(),
            )
        run_when_idle(training.process.pid)

    def find_runs(self, training: Training) -> None:
        """The run folders the process has named (``run: PATH`` or ``runs: ... the first PATH``)."""
        match = RUN_LINE.search(self.log_text(training))
        if not match:
            return
        first = self.runs_dir / Path(match.group("path") or match.group("first")).name
        try:
            training.runs = [run.name for run in population_members(first)]
        except InputError:
            return  # its config.json is being written: next tick
        self.save(training)

    def ended(self, training: Training, code: int) -> None:
        if not training.runs:
            self.find_runs(training)
        training.process = None
        if not ended_well(code):
            training.problem = ending_problem(code, self.log_text(training))
            self.save(training)

    def log_text(self, training: Training) -> str:
        try:
            with open(self.log_path(training), "rb") as log:
                log.seek(training.log_from)
                return log.read().decode("utf-8", errors="replace")
        except OSError:
            return ""

    def close(self, timeout: float = STOP_SECONDS) -> None:
        """Stop every training (each saves) and wait for them, as the server stops; waiting ones stay
        stopped (Resume starts them)."""
        self.closed.set()
        if self.thread is not None:
            self.thread.join(timeout=5)
        with self.lock:
            for name in self.queue:
                self.trainings[name].waiting = None
            self.queue.clear()
            running = [t for t in self.trainings.values() if t.running_here()]
            for training in running:
                assert training.process is not None
                stop_training_process(training.process.pid)
            deadline = time.monotonic() + timeout
            for training in running:
                assert training.process is not None
                try:
                    code = training.process.wait(max(0.0, deadline - time.monotonic()))
                except subprocess.TimeoutExpired:
                    training.process.kill()
                    code = training.process.wait()
                self.ended(training, code)

    # --- what the app shows ------------------------------------------------------------------

    def state(self, training: Training) -> TrainingState:
        if training.waiting is not None:
            return TrainingState.QUEUED
        if training.running_here():
            return TrainingState.RUNNING
        if training.problem:
            return TrainingState.FAILED
        states = [self.run_state(run) for run in training.runs]
        if not states:
            return TrainingState.STOPPED  # stopped before it made a run folder
        if all(state is RunState.FINISHED for state in states):
            return TrainingState.FINISHED
        if any(state is RunState.RUNNING for state in states):
            return TrainingState.RUNNING  # by a process an earlier server started
        if any(state in (RunState.FAILED, RunState.UNREADABLE) for state in states):
            return TrainingState.FAILED
        return TrainingState.STOPPED

    def run_state(self, run: str) -> RunState:
        try:
            return displayed_state(RunDir(self.runs_dir / run).status())
        except (InputError, OSError):
            return RunState.UNREADABLE

    def problem(self, training: Training) -> str | None:
        """Why a failed training failed, in one line."""
        if training.problem:
            return training.problem
        for run in training.runs:
            if self.run_state(run) is RunState.FAILED:
                with contextlib.suppress(InputError, OSError):
                    status = RunDir(self.runs_dir / run).status()
                    return f"{run}: {status.get('stop_detail') or 'failed'}"
        return None

    def other_process(self, training: Training) -> int | None:
        """The pid of a process on this machine still training one of ``training``'s runs."""
        for run in training.runs:
            with contextlib.suppress(InputError, OSError):
                status = RunDir(self.runs_dir / run).status()
                pid = status.get("pid")
                alive = displayed_state(status) is RunState.RUNNING
                if alive and status.get("host") == socket.gethostname() and isinstance(pid, int):
                    return pid
        return None

    def row(self, training: Training) -> dict[str, Any]:
        with self.lock:
            state = self.state(training)
            return {
                "name": training.name,
                "state": state.value,
                "runs": list(training.runs),
                "agent": training.request.get("agent"),
                "env_id": training.request.get("env_id"),
                "seeds": training.request.get("seeds"),
                "created": training.created,
                "command": training.command,
                "request": training.request,
                "problem": self.problem(training) if state is TrainingState.FAILED else None,
                "queue_position": self.queue_position(training),
            }

    def queue_position(self, training: Training) -> int | None:
        return self.queue.index(training.name) + 1 if training.name in self.queue else None

    def rows(self) -> list[dict[str, Any]]:
        """Every training: the running ones, then the queue in its order, then the others newest first."""
        with self.lock:
            newest = sorted(self.trainings.values(), key=lambda t: (t.created, t.name), reverse=True)
            rows = [self.row(t) for t in newest]
            order = {TrainingState.RUNNING: 0, TrainingState.QUEUED: 1}
            return sorted(rows, key=lambda r: (order.get(r["state"], 2), r["queue_position"] or 0))


WINDOWS = "win32"
"""``sys.platform`` on Windows. The functions that differ there take the platform, so that each
platform's branch is tested on any machine."""
CTRL_BREAK_EVENT = 1
"""``signal.CTRL_BREAK_EVENT`` (Windows' wincon.h; the name exists only on Windows)."""
SIGBREAK = 21
"""``signal.SIGBREAK`` (the C runtime's signal.h; only on Windows): the signal a Windows process's C
runtime raises for a Ctrl-Break event, which ``cartpole train`` handles as it does SIGINT and SIGTERM
(``training/engine.py: STOP_SIGNALS``)."""
STATUS_CONTROL_C_EXIT = 0xC000013A
"""A Windows process's exit code (ntstatus.h) when a Ctrl-C or Ctrl-Break event ended it: no handler
of its own took the event, so the console's default handler called ExitProcess."""


def stop_signal(platform: str = sys.platform) -> int:
    """What stops a training, which saves as after Ctrl-C: SIGTERM; on Windows Ctrl-Break to its process
    group. Not SIGINT: a process started with SIGINT ignored (a background job of a shell, a test
    runner's worker) keeps ignoring it until training installs its handler, so a Stop pressed as it
    starts was lost; SIGTERM's default, before then, ends it (as Ctrl-Break's does on Windows)."""
    return CTRL_BREAK_EVENT if platform == WINDOWS else signal.SIGTERM


def stop_training_process(
    pid: int, kill: Callable[[int, int], None] = os.kill, platform: str = sys.platform
) -> None:
    """Stop the ``cartpole train`` process ``pid`` cleanly: every seed saves ``latest.pt`` and it exits
    with a code :func:`ended_well` counts as a stop. The Stop button, the server's close, and a training
    an earlier server started all stop this way; ``kill`` is ``os.kill`` (a test's seam).

    On POSIX SIGTERM. On Windows ``os.kill(pid, SIGTERM)`` is TerminateProcess, which ends the process
    unsaved; ``os.kill(pid, CTRL_BREAK_EVENT)`` is GenerateConsoleCtrlEvent to the process group whose
    id is ``pid``: a training's own group (:func:`own_process_group`: CREATE_NEW_PROCESS_GROUP makes the
    new process's pid its group's id), which only the processes that share this one's console receive.
    A process already gone is nothing to stop."""
    with contextlib.suppress(ProcessLookupError):
        kill(pid, stop_signal(platform))


def own_process_group() -> dict[str, Any]:
    """Popen's options for a process group of its own: the terminal's Ctrl-C reaches the server alone,
    which stops its trainings itself. Not a session of its own: Linux shares CPU time fairly between
    sessions (autogroups) before it looks at scheduling classes, so a training in its own session took
    a core's share from the server whatever its class (play p50 4.0 ms instead of 0.5 ms)."""
    if os.name == "nt":
        return {"creationflags": subprocess.CREATE_NEW_PROCESS_GROUP}  # type: ignore[attr-defined]
    return {"process_group": 0}


def run_when_idle(pid: int) -> None:
    """Give process ``pid`` only the CPU time no other process wants (its threads to come too)."""
    try:
        os.sched_setscheduler(pid, os.SCHED_IDLE, os.sched_param(0))
    except (AttributeError, OSError):  # not Linux (or not allowed): a lower priority
        with contextlib.suppress(AttributeError, OSError):  # not on Windows
            os.setpriority(os.PRIO_PROCESS, pid, NICENESS)


def request_record(request: TrainRequest) -> dict[str, Any]:
    return {
        "agent": request.agent,
        "env_id": request.env_id,
        "preset": request.preset,
        "seeds": list(request.seeds),
        "budget": request.budget,
        "settings": dict(request.settings),
        "runs_dir": request.runs_dir,
    }


POSIX = "posix"
STOPPED_CODES = {
    POSIX: frozenset({0, 128 + signal.SIGINT, 128 + signal.SIGTERM, -signal.SIGINT, -signal.SIGTERM}),
    WINDOWS: frozenset({0, 128 + signal.SIGINT, 128 + SIGBREAK, STATUS_CONTROL_C_EXIT}),
}
"""Exit codes of a ``cartpole train`` that ended well, by platform: done (0), or stopped.

POSIX: 128 + the signal once training saved (SIGINT: Ctrl-C, 130; SIGTERM: Stop, 143), or the
signal's default ended it before training put up its handler, with nothing yet to save (``Popen``'s
-signal). Windows: 130 (Ctrl-C), 149 (128 + SIGBREAK: Stop's Ctrl-Break) once training saved, or
STATUS_CONTROL_C_EXIT for a Ctrl-Break before training's handler. A Windows process has no -signal,
and none of these codes stands for a kill there: TerminateProcess (``os.kill`` with any other signal:
its number; ``Popen.kill``: 1) ends it unsaved, a problem."""


def ended_well(code: int, platform: str = sys.platform) -> bool:
    """Whether a ``cartpole train`` process that exited with ``code`` on ``platform`` (``sys.platform``)
    finished or was stopped (it saved first), rather than failed or was killed."""
    return code in STOPPED_CODES[WINDOWS if platform == WINDOWS else POSIX]


def ending_problem(code: int, output: str) -> str:
    """Why a training process that exited with ``code`` failed, in one line."""
    if code < 0:
        try:
            name = signal.Signals(-code).name
        except ValueError:
            name = f"signal {-code}"
        return (
            f"its process was killed ({name}) before it could save: Resume goes on from its last checkpoint"
        )
    return last_problem(output) or f"cartpole train exited with status {code}"


def last_problem(output: str) -> str | None:
    """The one line a failed ``cartpole`` command ended with: its ``error:`` line, else its last line
    (a traceback's)."""
    lines = [line.strip() for line in output.splitlines() if line.strip()]
    for line in reversed(lines):
        if ERROR_PREFIX.match(line):
            return ERROR_PREFIX.sub("", line)
    return lines[-1][:300] if lines else None
