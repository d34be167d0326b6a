"""Reports of comparisons shared through a database (``cartpole compare --storage URL``), built live.

An experiment folder whose ``experiment.json`` names a ``storage`` (written by a machine that took part
in the comparison, or ran ``--report`` for it) is shown from that database, every machine's finished
runs, while the comparison runs. A report and its figures are rebuilt only when the comparison's rows
changed since the last look; the figures go to a temporary folder of this server, never into the runs
folder. Answers name the database by backend, host and port only (a URL may hold a password).
"""

from __future__ import annotations

import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pydantic import BaseModel, Field

RETRY_SECONDS = 30.0


class SharedStatus(BaseModel):
    """Where a shared comparison stands in its database."""

    storage: str = Field(description='the database, as "backend at host:port"')
    total: int = Field(description="(entry, seed) runs asked for, by every machine")
    finished: int
    running: int = Field(description="runs claimed by a worker now")
    pending: int


@dataclass
class SharedReport:
    """A report built from the database, its figures' folder, and the status it was built at."""

    report: dict[str, Any]
    figures: Path
    status: SharedStatus


class SharedReports:
    """Live reports of shared comparisons, cached per (URL, name) until their rows change."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._folders: dict[tuple[str, str], tempfile.TemporaryDirectory[str]] = {}
        self._built: dict[tuple[str, str], tuple[Any, SharedReport]] = {}
        self._engines: dict[str, Any] = {}
        self._failed: dict[tuple[str, str], tuple[float, Exception]] = {}
        """The last failure to read each comparison: not retried for RETRY_SECONDS, so that a page
        polling a database that does not answer is not held up by every poll."""

    def report(self, url: str, name: str) -> SharedReport:
        """The comparison's report now. Raises ExperimentError (or a database error) if it cannot be read."""
        with self._lock:
            failed = self._failed.get((url, name))
            if failed and time.monotonic() - failed[0] < RETRY_SECONDS:
                raise failed[1]
            try:
                return self._build(url, name)
            except Exception as err:
                self._failed[(url, name)] = (time.monotonic(), err)
                raise

    def _build(self, url: str, name: str) -> SharedReport:
        from cartpole.experiments.report import Results, write_report
        from cartpole.experiments.shared import Progress
        from cartpole.experiments.storage import describe_url

        shared = self._open(url, name)
        rows = shared.rows()
        stamp = tuple((r.entry, r.seed, r.state) for r in rows)
        cached = self._built.get((url, name))
        if cached and cached[0] == stamp:
            return cached[1]
        folder = self._folders.get((url, name))
        if folder is None:
            folder = self._folders[(url, name)] = tempfile.TemporaryDirectory(prefix="cartpole-shared-")
        report, _ = write_report(Results.of_shared(shared), Path(folder.name))
        backend, where = describe_url(url)
        counts = Progress.of_rows(rows)
        status = SharedStatus(
            storage=f"{backend} at {where}",
            total=counts.total,
            finished=counts.finished,
            running=counts.claimed,
            pending=counts.pending,
        )
        built = SharedReport(report, Path(folder.name), status)
        self._built[(url, name)] = (stamp, built)
        return built

    def _open(self, url: str, name: str) -> Any:
        from cartpole.experiments.entries import ExperimentError
        from cartpole.experiments.shared import SharedComparison
        from cartpole.experiments.storage import describe_url

        if url not in self._engines:
            backend, where = describe_url(url)
            if backend == "sqlite" and not Path(where).is_file():  # SQLite would make the file
                raise ExperimentError(f"no database file {Path(where).name}")
            self._engines[url] = SharedComparison.connect(url, create=False)  # this server writes nothing
        return SharedComparison.open(url, name, engine=self._engines[url])


__all__ = ["SharedReport", "SharedReports", "SharedStatus"]
