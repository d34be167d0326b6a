"""How much memory a new allocation can have: checked before a large one, so that a count given by a
person (seeds, episodes, video frames) gets one clear line instead of the out-of-memory killer."""

from __future__ import annotations

import psutil

MEMINFO = "/proc/meminfo"

SHARE = 0.8
"""The share of the available memory one command may plan to use."""


def available_memory() -> int | None:
    """Bytes of memory available to a new allocation, None if unknown: Linux's ``MemAvailable``, and
    where there is no :data:`MEMINFO` (macOS, Windows) psutil's estimate of the same."""
    try:
        with open(MEMINFO, encoding="ascii") as handle:
            for line in handle:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except FileNotFoundError:
        return int(psutil.virtual_memory().available)
    except (OSError, ValueError, IndexError):
        pass
    return None


def describe_bytes(count: float) -> str:
    """``1536`` -> ``"1.5 KiB"`` (at most TiB: ``"2,048.0 TiB"``)."""
    units = ["B", "KiB", "MiB", "GiB", "TiB"]
    while count >= 1024 and len(units) > 1:
        count /= 1024
        units.pop(0)
    return f"{count:.0f} B" if units[0] == "B" else f"{count:,.1f} {units[0]}"


def fits_in_memory(needed: int) -> tuple[bool, int | None]:
    """(whether ``needed`` bytes fit in :data:`SHARE` of the available memory, the bytes available);
    (True, None) where the available memory cannot be read."""
    free = available_memory()
    return (free is None or needed <= SHARE * free), free
