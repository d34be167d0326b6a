"""Run folders: the record of one training run, which plots, ``cartpole eval`` and the web app read.

Layout (see docs/DESIGN.md): ``config.json``, ``status.json``, ``metrics.jsonl``, ``eval.json`` (the
final verdict, and nothing else), ``best_eval.json`` (the best in-training evaluation) and
``checkpoints/{latest,best,solved}.pt``. JSON files are replaced atomically; ``metrics.jsonl`` is only
appended to, and readers skip a last line that is still being written.

One process trains a run at a time: it holds :meth:`RunDir.lock` and keeps ``status.json`` current
through :class:`LiveStatus` (pid, host and a heartbeat), so :func:`displayed_state` can tell a run
whose process is gone ("crashed") from one still running.
"""

from __future__ import annotations

import json
import os
import re
import socket
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from types import TracebackType
from typing import Any

import psutil

from cartpole.core.errors import InputError
from cartpole.core.file_names import portable_name
from cartpole.core.names import CheckpointName, RunState
from cartpole.runs.atomic import (
    DISK_FULL,
    append_text,
    overwrite_in_place,
    write_json_atomic,
    write_text_atomic,
)

CONFIG = "config.json"
STATUS = "status.json"
METRICS = "metrics.jsonl"
EVAL = "eval.json"
BEST_EVAL = "best_eval.json"
LAST_EVAL = "last_eval.json"
LOCK = ".train.lock"
CHECKPOINTS = "checkpoints"
CHECKPOINT_NAMES = tuple(CheckpointName)
HEARTBEAT_SECONDS = 5.0
"""How often a training process refreshes the heartbeat in ``status.json``."""
STALE_SECONDS = 60.0
"""A "running" status whose heartbeat is older than this has lost its process: it shows as crashed."""
NOT_RUNS = ("experiments", "sweeps", "trainings")
"""Folders of a runs folder that are not one run: experiments and sweeps (their run folders inside),
and the web app's records of the trainings it started (``trainings/``)."""
RUN_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]*__[A-Za-z0-9._-]+__s\d+__\d{8}-\d{6}(-\d+)?$")


class RunError(InputError, ValueError):
    """A run folder is missing or unreadable."""


class RunBusy(RunError):
    """Another process is training this run folder."""


def utc_now() -> str:
    return datetime.now(UTC).isoformat(timespec="seconds")


def run_name(env_id: str, agent: str, seed: int, when: datetime | None = None) -> str:
    """``<env>__<agent>__s<seed>__<UTC YYYYmmdd-HHMMSS>``, a folder name on every OS: the env id and
    the agent through :func:`~cartpole.core.file_names.portable_name` (``ALE/Pong-v5`` and
    ``mypkg:MyEnv-v0`` hold characters Windows refuses)."""
    stamp = (when or datetime.now(UTC)).strftime("%Y%m%d-%H%M%S")
    return f"{portable_name(env_id)}__{portable_name(agent)}__s{seed}__{stamp}"


def read_json(path: Path) -> Any:
    with open(path, encoding="utf-8") as handle:
        return json.load(handle)


Kind = type | tuple[type, ...]
CONFIG_FIELDS: dict[str, Kind] = {"agent": str, "env_id": str, "seed": int}
"""What every ``config.json`` holds; the rest is typed when present (a resume needs it all)."""
CONFIG_OPTIONAL: dict[str, Kind] = {
    "config": dict,
    "settings": dict,
    "budget": dict,
    "preset": str,
    "created": str,
    "overrides": dict,
    "tensorboard": bool,
}
STATUS_FIELDS: dict[str, Kind] = {"state": str}
STATUS_OPTIONAL: dict[str, Kind] = {
    "env_steps": int,
    "episodes": int,
    "iterations": int,
    "elapsed": (int, float),
    "best_eval_mean": (int, float, type(None)),
    "solved": bool,
    "solved_at_step": (int, type(None)),
    "pid": int,
    "host": str,
    "heartbeat": (int, float),
    "stop_reason": (str, type(None)),
    "stop_detail": (str, type(None)),
}
EVAL_FIELDS: dict[str, Kind] = {"solved": bool, "verdict": str}
EVAL_OPTIONAL: dict[str, Kind] = {
    "mean": (int, float),
    "episodes": int,
    "env_id": str,
    "threshold": (int, float, type(None)),
}


def _is(value: Any, kind: Kind) -> bool:
    """isinstance, except that a bool is not an int (JSON ``true`` is no seed) and an int is a float."""
    kinds = kind if isinstance(kind, tuple) else (kind,)
    if isinstance(value, bool):
        return bool in kinds
    return isinstance(value, kinds) or (float in kinds and isinstance(value, int))


def _kind_name(kind: Kind) -> str:
    names = {str: "text", int: "a whole number", float: "a number", bool: "true or false", dict: "an object"}
    kinds = kind if isinstance(kind, tuple) else (kind,)
    return " or ".join("null" if k is type(None) else names.get(k, k.__name__) for k in kinds)


def read_record(path: Path, required: dict[str, Kind], optional: dict[str, Kind]) -> dict[str, Any]:
    """A JSON object with ``required`` keys of the given types (and ``optional`` ones, if present,
    of theirs); RunError naming the file and what is wrong otherwise (FileNotFoundError if absent)."""
    try:
        data = read_json(path)
    except FileNotFoundError:
        raise
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise RunError(f"{path} is unreadable: {err}") from err
    if not isinstance(data, dict):
        raise RunError(f"{path} is malformed: a JSON object was expected, found a {type(data).__name__}")
    for key, kind in {**optional, **required}.items():
        if key not in data:
            if key in required:
                raise RunError(f"{path} is malformed: no {key!r}")
        elif not _is(data[key], kind):
            raise RunError(
                f"{path} is malformed: {key!r} should be {_kind_name(kind)}, found {data[key]!r:.40}"
            )
    return data


@dataclass(frozen=True)
class RunDir:
    """One run folder on disk."""

    path: Path

    @classmethod
    def create(cls, runs_dir: Path, env_id: str, agent: str, seed: int) -> RunDir:
        """Make a new, uniquely named run folder under ``runs_dir``."""
        base = run_name(env_id, agent, seed)
        runs_dir.mkdir(parents=True, exist_ok=True)
        for attempt in range(1000):
            name = base if attempt == 0 else f"{base}-{attempt}"
            try:
                (runs_dir / name).mkdir()
            except FileExistsError:
                continue
            run = cls(runs_dir / name)
            run.checkpoint_dir.mkdir()
            return run
        raise RunError(f"cannot create a run folder under {runs_dir}")

    @classmethod
    def open(cls, path: Path) -> RunDir:
        """An existing run folder; RunError if ``path`` is not one."""
        path = Path(path)
        if not (path / CONFIG).is_file():
            raise RunError(f"{path} is not a run folder (no {CONFIG}); see `cartpole runs`")
        return cls(path)

    @property
    def name(self) -> str:
        return self.path.name

    @property
    def checkpoint_dir(self) -> Path:
        return self.path / CHECKPOINTS

    def checkpoint_path(self, name: str) -> Path:
        return self.checkpoint_dir / f"{name}.pt"

    def checkpoints(self) -> list[str]:
        """Names of the checkpoints present, in the order latest, best, solved, then others."""
        if not self.checkpoint_dir.is_dir():
            return []
        present = sorted(p.stem for p in self.checkpoint_dir.glob("*.pt"))
        known = [n for n in CHECKPOINT_NAMES if n in present]
        return known + [n for n in present if n not in CHECKPOINT_NAMES]

    # JSON records ---------------------------------------------------------------------------------
    def write_config(self, config: dict[str, Any]) -> None:
        write_json_atomic(self.path / CONFIG, config)

    def config(self) -> dict[str, Any]:
        """The run's ``config.json``; RunError if it is missing or malformed."""
        try:
            return read_record(self.path / CONFIG, CONFIG_FIELDS, CONFIG_OPTIONAL)
        except FileNotFoundError as err:
            raise RunError(f"{self.path / CONFIG} is unreadable: {err}") from err

    def write_status(self, status: dict[str, Any]) -> None:
        """Write ``status.json`` atomically; on a full disk, over the old file in place (its blocks are
        already there), so that a run that fails for want of space can still say so."""
        record = {**status, "updated": utc_now()}
        try:
            write_json_atomic(self.path / STATUS, record)
        except OSError as err:
            if err.errno not in DISK_FULL or not (self.path / STATUS).is_file():
                raise
            overwrite_in_place(self.path / STATUS, json.dumps(record, indent=2, allow_nan=False) + "\n")

    def status(self, strict: bool = False) -> dict[str, Any]:
        """The last written status, or ``{"state": "unknown"}`` if there is none yet (or, unless
        ``strict``, if it is malformed; ``strict`` raises RunError then)."""
        try:
            return read_record(self.path / STATUS, STATUS_FIELDS, STATUS_OPTIONAL)
        except FileNotFoundError:
            return {"state": RunState.UNKNOWN.value}
        except RunError:
            if strict:
                raise
            return {"state": RunState.UNKNOWN.value}

    def write_eval(self, report: dict[str, Any]) -> None:
        """Write the final verdict (only the session's last step does this)."""
        write_json_atomic(self.path / EVAL, report)

    def eval_report(self, strict: bool = False) -> dict[str, Any] | None:
        """The final verdict, or None if there is none yet (or, unless ``strict``, if it is
        malformed; ``strict`` raises RunError then)."""
        try:
            return read_record(self.path / EVAL, EVAL_FIELDS, EVAL_OPTIONAL)
        except FileNotFoundError:
            return None
        except RunError:
            if strict:
                raise
            return None

    def write_last_eval(self, report: dict[str, Any]) -> None:
        """Write the last policy's score on the verdict's own episodes (not a verdict: see eval.json)."""
        write_json_atomic(self.path / LAST_EVAL, report)

    def last_eval_report(self) -> dict[str, Any] | None:
        try:
            return read_json(self.path / LAST_EVAL)
        except (OSError, json.JSONDecodeError):
            return None

    def write_best_eval(self, report: dict[str, Any]) -> None:
        """Write the best evaluation made during training (not a verdict)."""
        write_json_atomic(self.path / BEST_EVAL, report)

    def best_eval_report(self) -> dict[str, Any] | None:
        try:
            return read_json(self.path / BEST_EVAL)
        except (OSError, json.JSONDecodeError):
            return None

    @contextmanager
    def lock(self) -> Iterator[None]:
        """Hold the run folder for this process; RunBusy at once if another process holds it.

        An OS lock (``flock``): it goes with the process, so a killed run leaves no stale lock.
        """
        from filelock import FileLock, Timeout

        lock = FileLock(self.path / LOCK, timeout=0)
        try:
            lock.acquire()
        except Timeout:
            status = self.status()
            holder = f" (pid {status['pid']} on {status['host']})" if {"pid", "host"} <= status.keys() else ""
            raise RunBusy(
                f"run {self.name} is being trained by another process{holder}; "
                "wait for it to end, or stop it, before resuming"
            ) from None
        try:
            yield
        finally:
            lock.release()

    # Metrics --------------------------------------------------------------------------------------
    @property
    def metrics_path(self) -> Path:
        return self.path / METRICS

    def append_metrics(self, rows: list[dict[str, Any]]) -> None:
        """Append rows as JSON lines (one write, then flush)."""
        if not rows:
            return
        append_text(self.metrics_path, "".join(json.dumps(row, allow_nan=False) + "\n" for row in rows))

    def metrics(self, offset: int = 0) -> list[dict[str, Any]]:
        """Complete rows from line ``offset`` on; a last line without its newline is not yet a row."""
        return self.read_metrics(offset)[0]

    def read_metrics(self, offset: int = 0) -> tuple[list[dict[str, Any]], int]:
        """Rows from line ``offset`` on, and the offset to ask for next (counts lines, not rows,
        so a corrupt line in the middle cannot make a follower see rows twice)."""
        try:
            text = self.metrics_path.read_text(encoding="utf-8")
        except FileNotFoundError:
            return [], offset
        lines = text.split("\n")[:-1]  # the part after the last newline is incomplete (or empty)
        rows = []
        for line in lines[offset:]:
            try:
                row = json.loads(line)
            except (json.JSONDecodeError, RecursionError):
                continue
            if isinstance(row, dict):  # a line that is valid JSON but not a row is skipped too
                rows.append(row)
        return rows, max(offset, len(lines))

    def truncate_metrics_after(self, step: int) -> None:
        """Drop rows logged after env step ``step`` (and any half-written line), for a resume."""
        kept = [row for row in self.metrics() if row.get("step", 0) <= step]
        text = "".join(json.dumps(row) + "\n" for row in kept)
        write_text_atomic(self.metrics_path, text, durable=True)


class LiveStatus:
    """``status.json`` of a run this process trains.

    Every write carries the pid, the host and a heartbeat (Unix seconds). While entered (``with``), a
    thread rewrites the last status with a fresh heartbeat every ``interval`` seconds, so a long
    evaluation or verdict still looks alive and a dead process is seen within :data:`STALE_SECONDS`.
    """

    def __init__(self, run: RunDir, interval: float = HEARTBEAT_SECONDS):
        self.run, self.interval = run, interval
        self.fields: dict[str, Any] | None = None
        self._guard = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def write(self, state: RunState, fields: dict[str, Any]) -> None:
        """Record ``state`` and ``fields`` (counters, stop reason) with a fresh heartbeat."""
        with self._guard:
            self.fields = {"state": RunState(state).value, **fields}
            self._write()

    def _write(self) -> None:
        assert self.fields is not None
        heartbeat = {"pid": os.getpid(), "host": socket.gethostname(), "heartbeat": round(time.time(), 3)}
        self.run.write_status({**self.fields, **heartbeat})

    def beat(self) -> None:
        """Rewrite the last status with a fresh heartbeat (a full disk only skips a beat)."""
        with self._guard:
            if self.fields is not None:
                with suppress(OSError):
                    self._write()

    def _beat_until_stopped(self) -> None:
        while not self._stop.wait(self.interval):
            self.beat()

    def __enter__(self) -> LiveStatus:
        self._stop.clear()
        self._thread = threading.Thread(target=self._beat_until_stopped, name="status-heartbeat", daemon=True)
        self._thread.start()
        return self

    def __exit__(
        self, kind: type[BaseException] | None, error: BaseException | None, trace: TracebackType | None
    ) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None


def process_alive(pid: int) -> bool:
    """Whether process ``pid`` exists on this machine (whoever owns it). Asked of psutil, never with
    ``os.kill(pid, 0)``: on Windows signal 0 is CTRL_C_EVENT, sent to a whole process group."""
    if pid <= 0:  # no training process: 0 and below name process groups for kill()
        return False
    try:
        return bool(psutil.pid_exists(pid))
    except (OSError, OverflowError, ValueError):
        return False


def last_heartbeat(status: dict[str, Any]) -> float | None:
    """Unix time of the status's heartbeat (or, for older runs, of its last update)."""
    heartbeat = status.get("heartbeat")
    if isinstance(heartbeat, int | float) and not isinstance(heartbeat, bool):
        return float(heartbeat)
    try:
        return datetime.fromisoformat(str(status["updated"])).timestamp()
    except (KeyError, ValueError):
        return None


def training_process_alive(status: dict[str, Any], now: float | None = None) -> bool:
    """Whether the process that wrote a "running" ``status`` is still training: its heartbeat is
    fresh and, when it ran on this host, its pid still exists."""
    beat = last_heartbeat(status)
    now = time.time() if now is None else now
    if beat is None or now - beat > STALE_SECONDS:
        return False
    pid = status.get("pid")
    if status.get("host") == socket.gethostname() and isinstance(pid, int):
        return process_alive(pid)
    return True


STOPPED_STATES = frozenset({RunState.FINISHED, RunState.INTERRUPTED, RunState.FAILED, RunState.CRASHED})
"""States in which no process writes to the run any more (until a ``--resume``)."""


def displayed_state(status: dict[str, Any], now: float | None = None) -> RunState:
    """The state to show for a run's ``status.json``: the written state, except that a run whose
    training process is gone shows as crashed (``--resume`` continues it). Everything that shows or
    acts on a run's state (``cartpole runs``, the web app, ``--resume``) asks this function."""
    try:
        state = RunState(str(status.get("state")))
    except ValueError:
        return RunState.UNKNOWN
    if state is RunState.RUNNING and not training_process_alive(status, now):
        return RunState.CRASHED
    return state


@dataclass(frozen=True)
class RunSummary:
    """One row of ``cartpole runs`` and of the web app's runs table."""

    name: str
    path: str
    agent: str | None
    env_id: str | None
    seed: int | None
    preset: str | None
    created: str | None
    state: str
    env_steps: int | None
    episodes: int | None
    best_eval_mean: float | None
    solved: bool
    verdict: str | None
    problem: str | None = None


def summarize_run(path: Path) -> RunSummary:
    """Summarize a run folder; a corrupt or half-written one is described ("unreadable", with the
    problem), never raised."""
    run = RunDir(path)
    if not (path / CONFIG).exists() and not (path / CONFIG).is_symlink():
        return _without_record(path, "incomplete", f"{CONFIG} not written yet")
    try:
        config = run.config()
        status = run.status(strict=True)
        report = run.eval_report(strict=True)
        check_checkpoint_files(run)
    except (RunError, OSError) as err:
        return _without_record(path, "unreadable", str(err))
    return RunSummary(
        name=path.name,
        path=str(path),
        agent=config["agent"],
        env_id=config["env_id"],
        seed=config["seed"],
        preset=config.get("preset"),
        created=config.get("created"),
        state=displayed_state(status).value,
        env_steps=status.get("env_steps"),
        episodes=status.get("episodes"),
        best_eval_mean=status.get("best_eval_mean"),
        solved=bool(report["solved"]) if report else False,  # only the final verdict says solved
        verdict=report["verdict"] if report else None,
    )


def _without_record(path: Path, state: str, problem: str) -> RunSummary:
    """The summary of a run whose files cannot be read: its name, its state and why."""
    return RunSummary(
        path.name, str(path), None, None, None, None, None, state, None, None, None, False, None, problem
    )


ZIP_MAGIC = b"PK\x03\x04"
"""torch.save writes zip files; anything else in checkpoints/ is not one of our checkpoints."""


def check_checkpoint_files(run: RunDir) -> None:
    """RunError if a checkpoint is a dangling link or not a torch file at all (a cheap look at its
    first bytes: listing runs must not load every checkpoint)."""
    if not run.checkpoint_dir.is_dir():
        return
    for path in sorted(run.checkpoint_dir.glob("*.pt")):
        if not path.exists():
            raise RunError(f"{path} is a dangling link (to {os.readlink(path)})")
        with open(path, "rb") as handle:
            if handle.read(len(ZIP_MAGIC)) != ZIP_MAGIC:
                raise RunError(f"{path} is not a checkpoint (not a torch file)")


def list_runs(runs_dir: Path) -> list[RunSummary]:
    """Every run folder directly under ``runs_dir``, newest first; [] if there is no such folder yet.

    RunError if ``runs_dir`` is not a folder (a file, a link loop) or cannot be listed."""
    try:
        if not runs_dir.exists():
            if runs_dir.is_symlink():
                raise RunError(f"{runs_dir} is a link that leads nowhere (dangling, or a loop)")
            return []
        if not runs_dir.is_dir():
            raise RunError(f"{runs_dir} is not a folder of runs: give the folder that holds run folders")
        folders = [
            p
            for p in runs_dir.iterdir()
            if p.is_dir() and not p.name.startswith(".") and p.name not in NOT_RUNS
        ]
    except OSError as err:
        raise RunError(f"cannot list {runs_dir}: {err.strerror or err}") from err
    summaries = [summarize_run(p) for p in folders]
    return sorted(summaries, key=lambda s: (s.created or "", s.name), reverse=True)
