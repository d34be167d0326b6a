"""A test hook: stop a shared comparison's process at a named point, so that a test can kill it there.

``CARTPOLE_PAUSE_AT=POINT:FOLDER`` (read here only; ``tests/test_faults.py`` sets it) makes a process
that reaches POINT create the file FOLDER/POINT and wait while that file exists. The points:

- ``claim``: a claim's statement executed (one statement, committed as it ran), its rows not yet
  handed to a worker;
- ``finish``: a run's record written by its worker, its results not yet stored in the database.

One point is a fault rather than a pause:

- ``claim-reply``: the first claim's statement that claims rows runs to its end (committed, as a
  claim's one statement is), then its reply is lost: the connection is closed and the driver's error
  raised, as a connection reset would have it; FOLDER/claim-reply is created then, and no later claim
  of the process is touched.

Unset (always, outside those tests), a point costs one look-up in ``os.environ``.
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any

PAUSE_AT = "CARTPOLE_PAUSE_AT"


def pause_at(point: str) -> None:
    """Wait here while FOLDER/``point`` exists, where ``CARTPOLE_PAUSE_AT`` names ``point``."""
    name, _, folder = os.environ.get(PAUSE_AT, "").partition(":")
    if name != point or not folder:
        return
    flag = Path(folder) / point
    flag.touch()
    while flag.exists():
        time.sleep(0.1)


def pause_in_claims(engine: Any) -> None:
    """Have ``engine`` pause at ``claim`` after the statement that claims rows, or lose that
    statement's reply at ``claim-reply`` (set only where ``CARTPOLE_PAUSE_AT`` is)."""
    import sqlalchemy as sa

    def claims(statement: str) -> bool:
        return "UPDATE cartpole_comparison_runs" in statement and "claims=" in statement

    def after_execute(conn: Any, cursor: Any, statement: str, *rest: Any) -> None:
        if claims(statement):
            pause_at("claim")

    lost: list[Path] = []

    def lose_reply(conn: Any, cursor: Any, statement: str, *rest: Any) -> None:
        if not claims(statement) or lost:
            return
        rows = cursor.fetchall()  # the statement run to its end: its rows claimed, committed
        if not rows:
            return
        lost.append(Path(os.environ[PAUSE_AT].partition(":")[2]) / "claim-reply")
        lost[0].touch()
        dbapi = conn.dialect.loaded_dbapi
        conn.connection.dbapi_connection.close()
        if conn.dialect.name == "sqlite":  # the error SQLAlchemy takes for a lost SQLite connection
            raise dbapi.ProgrammingError("Cannot operate on a closed database.")
        raise dbapi.OperationalError("server closed the connection unexpectedly (its reply lost)")

    point = os.environ.get(PAUSE_AT, "")
    if point.startswith("claim:"):
        sa.event.listen(engine, "after_cursor_execute", after_execute)
    elif point.startswith("claim-reply:"):
        sa.event.listen(engine, "after_cursor_execute", lose_reply)


__all__ = ["PAUSE_AT", "pause_at", "pause_in_claims"]
