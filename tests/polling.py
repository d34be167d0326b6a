"""Waiting in tests for what another process does: a poll with a deadline that names what it awaited."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import TypeVar

T = TypeVar("T")


def wait_for(condition: Callable[[], T], timeout: float, what: str, period: float = 0.1) -> T:
    """``condition()``'s first truthy value, asked every ``period`` seconds; AssertionError naming
    ``what`` once ``timeout`` seconds pass without one."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        found = condition()
        if found:
            return found
        time.sleep(period)
    raise AssertionError(f"timed out waiting for {what}")
