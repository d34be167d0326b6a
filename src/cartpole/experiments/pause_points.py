"""A test hook: stop a shared comparison's process at a named point, so that a test can kill it there.

``CARTPOLE_PAUSE_AT=POINT:FOLDER`` (read here only; ``tests/test_faults.py`` sets it) makes a process
that reaches POINT create the file FOLDER/POINT and wait while that file exists. The points:

- ``claim``: a claim's statement executed (one statement, committed as it ran), its rows not yet
  handed to a worker;
- ``finish``: a run's record written by its worker, its results not yet stored in the database.

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
    """Have ``engine`` pause at ``claim`` after the statement that claims rows (set only where
    ``CARTPOLE_PAUSE_AT`` is)."""
    import sqlalchemy as sa

    def after_execute(conn: Any, cursor: Any, statement: str, *rest: Any) -> None:
        if "UPDATE cartpole_comparison_runs" in statement and "claims=" in statement:
            pause_at("claim")

    if os.environ.get(PAUSE_AT, "").startswith("claim:"):
        sa.event.listen(engine, "after_cursor_execute", after_execute)


__all__ = ["PAUSE_AT", "pause_at", "pause_in_claims"]
