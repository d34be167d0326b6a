"""Run folders: the record of one training run, which plots, ``cartpole eval`` and the web app read.

Layout (see docs/DESIGN.md): ``config.json``, ``status.json``, ``metrics.jsonl``, ``eval.json`` and
``checkpoints/{latest,best,solved}.pt``. JSON files are replaced atomically; ``metrics.jsonl`` is only
appended to, and readers skip a last line that is still being written.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from cartpole.core.errors import InputError
from cartpole.runs.atomic import write_json_atomic, write_text_atomic

CONFIG = "config.json"
STATUS = "status.json"
METRICS = "metrics.jsonl"
EVAL = "eval.json"
CHECKPOINTS = "checkpoints"
CHECKPOINT_NAMES = ("latest", "best", "solved")
NOT_RUNS = ("experiments", "sweeps")
"""Folders of a runs folder that hold experiments and sweeps (their run folders inside), not one run."""
RUN_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]*__[A-Za-z0-9._-]+__s\d+__\d{8}-\d{6}(-\d+)?$")


class RunError(InputError, ValueError):
    """A run folder is missing or unreadable."""


def utc_now() -> str:
    return datetime.now(UTC).isoformat(timespec="seconds")


def run_name(env_id: str, agent: str, seed: int, when: datetime | None = None) -> str:
    """``<env>__<agent>__s<seed>__<UTC YYYYmmdd-HHMMSS>``, safe as a folder name."""
    stamp = (when or datetime.now(UTC)).strftime("%Y%m%d-%H%M%S")
    return f"{env_id.replace('/', '-')}__{agent}__s{seed}__{stamp}"


def read_json(path: Path) -> Any:
    with open(path, encoding="utf-8") as handle:
        return json.load(handle)


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
        try:
            return read_json(self.path / CONFIG)
        except (OSError, json.JSONDecodeError) as err:
            raise RunError(f"{self.path / CONFIG} is unreadable: {err}") from err

    def write_status(self, status: dict[str, Any]) -> None:
        write_json_atomic(self.path / STATUS, {**status, "updated": utc_now()})

    def status(self) -> dict[str, Any]:
        """The last written status, or ``{"state": "unknown"}`` if there is none yet."""
        try:
            return read_json(self.path / STATUS)
        except (OSError, json.JSONDecodeError):
            return {"state": "unknown"}

    def write_eval(self, report: dict[str, Any]) -> None:
        write_json_atomic(self.path / EVAL, report)

    def eval_report(self) -> dict[str, Any] | None:
        try:
            return read_json(self.path / EVAL)
        except (OSError, json.JSONDecodeError):
            return None

    # Metrics --------------------------------------------------------------------------------------
    @property
    def metrics_path(self) -> Path:
        return self.path / METRICS

    def append_metrics(self, rows: list[dict[str, Any]]) -> None:
        """Append rows as JSON lines (one write, then flush)."""
        if not rows:
            return
        text = "".join(json.dumps(row, allow_nan=False) + "\n" for row in rows)
        with open(self.metrics_path, "a", encoding="utf-8") as handle:
            handle.write(text)
            handle.flush()

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
                rows.append(json.loads(line))
            except json.JSONDecodeError:
                continue
        return rows, max(offset, len(lines))

    def truncate_metrics_after(self, step: int) -> None:
        """Drop rows logged after env step ``step`` (and any half-written line), for a resume."""
        kept = [row for row in self.metrics() if row.get("step", 0) <= step]
        text = "".join(json.dumps(row) + "\n" for row in kept)
        write_text_atomic(self.metrics_path, text, durable=True)


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
    """Summarize a run folder; a corrupt or half-written one is described, not raised."""
    run = RunDir(path)
    try:
        config = run.config()
    except RunError as err:
        return RunSummary(
            path.name,
            str(path),
            None,
            None,
            None,
            None,
            None,
            "corrupt" if (path / CONFIG).exists() else "incomplete",
            None,
            None,
            None,
            False,
            None,
            problem=str(err) if (path / CONFIG).exists() else f"{CONFIG} not written yet",
        )
    status = run.status()
    report = run.eval_report()
    return RunSummary(
        name=path.name,
        path=str(path),
        agent=config.get("agent"),
        env_id=config.get("env_id"),
        seed=config.get("seed"),
        preset=config.get("preset"),
        created=config.get("created"),
        state=status.get("state", "unknown"),
        env_steps=status.get("env_steps"),
        episodes=status.get("episodes"),
        best_eval_mean=status.get("best_eval_mean"),
        solved=bool(report["solved"]) if report else bool(status.get("solved", False)),
        verdict=report.get("verdict") if report else None,
    )


def list_runs(runs_dir: Path) -> list[RunSummary]:
    """Every run folder directly under ``runs_dir``, newest first."""
    if not runs_dir.is_dir():
        return []
    folders = [
        p for p in runs_dir.iterdir() if p.is_dir() and not p.name.startswith(".") and p.name not in NOT_RUNS
    ]
    summaries = [summarize_run(p) for p in folders]
    return sorted(summaries, key=lambda s: (s.created or "", s.name), reverse=True)
