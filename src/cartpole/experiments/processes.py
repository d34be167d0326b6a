"""Worker processes, J at a time, that stop cleanly together, the same way on every OS.

Each worker is a fresh ``python -m ...`` process (so one run's imports and thread settings cannot
change another's) in its own session (its own process group on Windows), so that a Ctrl-C in the
terminal reaches only the parent. The parent holds the other end of each worker's stdin, a pipe, and
the worker reads it (:func:`follow_parent`): the parent asks a worker to stop by writing
:data:`STOP_REQUEST` to it and closing it (:func:`request_stop`), and a parent that dies however it
dies (SIGKILL, its machine lost) closes it too. Either way the worker's SIGINT handler is called, as a
Ctrl-C would call it: training saves ``checkpoints/latest.pt`` and the worker exits with 130, so no
orphan trains on for nobody. Signals could not do this everywhere: Windows cannot send SIGINT to
another process (``os.kill`` terminates it) and does not re-parent an orphan, which therefore cannot
notice. A second Ctrl-C, or a worker that has not exited within ``grace`` seconds of the request
(:data:`GRACE_SECONDS`), is killed (its run resumes from its last checkpoint).
"""

from __future__ import annotations

import _thread
import contextlib
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Collection, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from cartpole.experiments.slots import CPU, Slot

POLL_SECONDS = 0.2
GRACE_SECONDS = 10.0
"""Seconds a worker asked to stop has to save its run before it is killed: short enough that a
``cartpole compare`` sent SIGTERM by Slurm has stopped its workers, stored what finished, written its
report and exited well within Slurm's KillWait (30 s by default) before the SIGKILL. A worker killed
while it saves keeps its previous ``latest.pt`` (each checkpoint is written atomically)."""
STOP_REQUEST = b"stop\n"
"""What the parent writes to a worker's stdin to ask it to stop (closing the pipe asks it too)."""
FOLLOW_PARENT = "CARTPOLE_FOLLOW_PARENT"
"""Set to ``1`` in the environment of a process :func:`start` started: its stdin is the parent's pipe."""


@dataclass(frozen=True)
class Job:
    """A worker command, its log file and what the caller wants back when it ends."""

    args: list[str]
    log: Path
    key: Any = None


@contextlib.contextmanager
def sigterm_as_interrupt() -> Iterator[None]:
    """SIGTERM raises KeyboardInterrupt in the parent, so both stop the workers the same way."""

    def handler(signum: int, frame: Any) -> None:
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def python_module(module: str, *args: str) -> list[str]:
    """The command line that runs ``module`` with this interpreter."""
    return [sys.executable, "-m", module, *args]


def start(job: Job, slot: Slot | None = None) -> subprocess.Popen[bytes]:
    """Start the job's worker, its output appended to its log, its stdin a pipe from this process
    (the worker's :func:`follow_parent` reads it). In a ``slot``, its command ends with the slot's
    ``--device DEVICE`` and its environment has the slot's (a GPU slot's ``CUDA_VISIBLE_DEVICES``)."""
    job.log.parent.mkdir(parents=True, exist_ok=True)
    apart: dict[str, Any]
    if sys.platform == "win32":  # a process group of its own: the terminal's Ctrl-C passes it by
        apart = {"creationflags": subprocess.CREATE_NEW_PROCESS_GROUP}
    else:  # a session of its own: the terminal's Ctrl-C (to the foreground group) passes it by
        apart = {"start_new_session": True}
    with open(job.log, "ab") as log:
        return subprocess.Popen(
            job.args if slot is None else [*job.args, *slot.arguments],
            stdout=log,
            stderr=subprocess.STDOUT,
            stdin=subprocess.PIPE,
            bufsize=0,
            env={**os.environ, **(slot.environment if slot else {}), FOLLOW_PARENT: "1"},
            **apart,
        )


def request_stop(process: subprocess.Popen[bytes]) -> None:
    """Ask a worker :func:`start` started to stop as on Ctrl-C: :data:`STOP_REQUEST` to its stdin,
    which is then closed. A worker that has ended already is not asked."""
    if process.stdin is None or process.stdin.closed:
        return
    with contextlib.suppress(OSError):  # a broken pipe: the worker has ended
        process.stdin.write(STOP_REQUEST)
    close_pipe(process)


def close_pipe(process: subprocess.Popen[bytes]) -> None:
    """Close this end of a worker's stdin (the worker takes that for a stop request, if still there)."""
    if process.stdin is not None:
        with contextlib.suppress(OSError):
            process.stdin.close()


def stop_all(
    running: dict[subprocess.Popen[bytes], Job],
    grace: float = GRACE_SECONDS,
    meanwhile: Callable[[], None] | None = None,
) -> None:
    """Ask every worker to stop (:func:`request_stop`), call ``meanwhile()`` (a shared comparison gives
    its claims back), then wait; kill what is still there ``grace`` seconds after the request, or at a
    second Ctrl-C (a worker killed while it saves keeps its previous checkpoint: each is written
    atomically)."""
    for process in running:
        request_stop(process)
    deadline = time.monotonic() + grace
    try:
        if meanwhile is not None:
            meanwhile()
        for process in running:
            process.wait(timeout=max(0.1, deadline - time.monotonic()))
    except (subprocess.TimeoutExpired, KeyboardInterrupt):
        for process in running:
            with contextlib.suppress(OSError):  # it has ended meanwhile
                process.kill()
        for process in running:
            process.wait()


def run_jobs(
    jobs: Sequence[Job],
    workers: int | Sequence[Slot],
    on_done: Callable[[Job, int], None],
    tick: Callable[[], Collection[Job] | None] | None = None,
) -> None:
    """Run ``jobs``, ``workers`` at a time: a count of CPU slots, or the slots (each runs one job at a
    time, :func:`start`). Workers inherit this environment, PYTHONPATH included.

    ``on_done(job, exit code)`` is called in this process as each ends, ``tick()`` every poll (about
    five times a second): the running jobs it returns are killed at once, saving nothing (their work
    is no longer this process's), and end as any other. KeyboardInterrupt (Ctrl-C, SIGTERM) stops every
    worker cleanly, then propagates.
    """
    queue = list(jobs)
    run_job_source(lambda: queue.pop(0) if queue else None, workers, on_done, tick)


def run_job_source(
    next_job: Callable[[], Job | None],
    workers: int | Sequence[Slot],
    on_done: Callable[[Job, int], None],
    tick: Callable[[], Collection[Job] | None] | None = None,
    more: Callable[[], bool] = lambda: False,
    on_stop: Callable[[], None] | None = None,
) -> None:
    """:func:`run_jobs` over jobs made as slots free up: ``next_job()`` gives the next one, or None when
    it has none now; the loop ends when nothing runs, ``next_job()`` has none and ``more()`` says none
    will come (a shared comparison waits while other machines hold runs they may give up).
    ``on_stop()`` is called on Ctrl-C or SIGTERM as soon as every worker is asked to stop, before they
    have saved (a shared comparison gives its claims back at once)."""
    free = [CPU] * workers if isinstance(workers, int) else list(workers)
    running: dict[subprocess.Popen[bytes], Job] = {}
    slots: dict[subprocess.Popen[bytes], Slot] = {}
    with sigterm_as_interrupt():
        try:
            while True:
                exhausted = False
                while free:
                    job = next_job()
                    if job is None:
                        exhausted = True
                        break
                    slot = free.pop(0)
                    process = start(job, slot)
                    running[process], slots[process] = job, slot
                if not running and exhausted and not more():
                    return
                time.sleep(POLL_SECONDS)
                if tick:
                    kill_jobs(running, tick() or ())
                for process in [p for p in running if p.poll() is not None]:
                    close_pipe(process)
                    free.append(slots.pop(process))
                    on_done(running.pop(process), int(process.returncode))
        except KeyboardInterrupt:
            stop_all(running, meanwhile=on_stop)
            for process, job in running.items():
                on_done(job, int(process.returncode))
            raise
        except Exception:  # the caller failed (its database out of reach): every worker saves its run
            stop_all(running)
            raise


def kill_jobs(running: dict[subprocess.Popen[bytes], Job], jobs: Collection[Job]) -> None:
    """Kill the workers of ``jobs`` (the very objects) among ``running``, without a stop request: no
    checkpoint, no record written."""
    for process, job in running.items():
        if any(job is doomed for doomed in jobs):
            with contextlib.suppress(OSError):  # it has ended meanwhile
                process.kill()


def follow_parent() -> None:
    """In a worker, first (from the main thread): stop cleanly when the parent asks
    (:func:`request_stop`) or is gone, as on a Ctrl-C: a thread waits for a line on stdin, or its end,
    then has the main thread call its SIGINT handler (training's saves and stops; elsewhere Python's
    raises KeyboardInterrupt, which the worker turns into exit code 130). Does nothing in a process
    :func:`start` did not start, whose stdin is not its parent's pipe (a worker run by hand, a test)."""
    if os.environ.pop(FOLLOW_PARENT, None) != "1":  # popped: no process the worker starts takes it
        return
    # Python's own handler, even where SIGINT came ignored (a parent started as a background job).
    signal.signal(signal.SIGINT, signal.default_int_handler)
    threading.Thread(target=_interrupt_when_asked, name="follow-parent", daemon=True).start()


def _interrupt_when_asked() -> None:
    """Wait for a line on stdin (fd 0, read directly: no lock of ``sys.stdin`` is held at exit) or
    for its end, then interrupt the main thread with SIGINT."""
    while True:
        try:
            chunk = os.read(0, 256)
        except OSError:  # no stdin to read: the parent cannot be followed, so stop
            break
        if not chunk or b"\n" in chunk:
            break
    _thread.interrupt_main(signal.SIGINT)
