"""Worker processes, J at a time, that stop cleanly together.

Each worker is a fresh ``python -m ...`` process (so one run's imports and thread settings cannot
change another's) in its own session: a Ctrl-C in the terminal reaches only the parent, which passes
SIGINT on to every running worker and waits for each to save and exit. A second Ctrl-C, or a worker that
has not exited within ``grace`` seconds, gets SIGKILL (its run resumes from its last checkpoint).
"""

from __future__ import annotations

import contextlib
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

POLL_SECONDS = 0.2
GRACE_SECONDS = 60.0


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


def start(job: Job) -> subprocess.Popen[bytes]:
    job.log.parent.mkdir(parents=True, exist_ok=True)
    with open(job.log, "ab") as log:
        return subprocess.Popen(
            job.args, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, start_new_session=True
        )


def stop_all(running: dict[subprocess.Popen[bytes], Job], grace: float = GRACE_SECONDS) -> None:
    """SIGINT to every worker, then wait; SIGKILL what is still there after ``grace`` or a 2nd Ctrl-C."""
    for process in running:
        with contextlib.suppress(ProcessLookupError):
            process.send_signal(signal.SIGINT)
    deadline = time.monotonic() + grace
    try:
        for process in running:
            process.wait(timeout=max(0.1, deadline - time.monotonic()))
    except (subprocess.TimeoutExpired, KeyboardInterrupt):
        for process in running:
            with contextlib.suppress(ProcessLookupError):
                process.kill()
        for process in running:
            process.wait()


def run_jobs(
    jobs: Sequence[Job],
    workers: int,
    on_done: Callable[[Job, int], None],
    tick: Callable[[], None] | None = None,
) -> None:
    """Run ``jobs``, ``workers`` at a time (workers inherit this environment, PYTHONPATH included).

    ``on_done(job, exit code)`` is called in this process as each ends, ``tick()`` every poll (about
    five times a second). KeyboardInterrupt (Ctrl-C, SIGTERM) stops every worker cleanly, then
    propagates.
    """
    queue = list(jobs)
    run_job_source(lambda: queue.pop(0) if queue else None, workers, on_done, tick)


def run_job_source(
    next_job: Callable[[], Job | None],
    workers: int,
    on_done: Callable[[Job, int], None],
    tick: Callable[[], None] | None = None,
    more: Callable[[], bool] = lambda: False,
) -> None:
    """:func:`run_jobs` over jobs made as slots free up: ``next_job()`` gives the next one, or None when
    it has none now; the loop ends when nothing runs, ``next_job()`` has none and ``more()`` says none
    will come (a shared comparison waits while other machines hold runs they may give up)."""
    running: dict[subprocess.Popen[bytes], Job] = {}
    with sigterm_as_interrupt():
        try:
            while True:
                exhausted = False
                while len(running) < workers:
                    job = next_job()
                    if job is None:
                        exhausted = True
                        break
                    running[start(job)] = job
                if not running and exhausted and not more():
                    return
                time.sleep(POLL_SECONDS)
                if tick:
                    tick()
                for process in [p for p in running if p.poll() is not None]:
                    on_done(running.pop(process), int(process.returncode))
        except KeyboardInterrupt:
            stop_all(running)
            for process, job in running.items():
                on_done(job, int(process.returncode))
            raise


def stop_when_orphaned(period: float = 1.0) -> None:
    """In a worker: stop cleanly (SIGTERM to itself, which training handles by saving and exiting) when
    the process that started it is gone, killed with SIGKILL or lost with its machine, so that no
    orphan trains on for nobody."""
    import os
    import threading

    parent = os.getppid()

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(period)
        os.kill(os.getpid(), signal.SIGTERM)

    threading.Thread(target=watch, name="stop-when-orphaned", daemon=True).start()
