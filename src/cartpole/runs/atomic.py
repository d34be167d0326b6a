"""Atomic file writes: write a temp file beside the target, fsync, then ``os.replace``.

A crash or ``kill -9`` at any moment leaves either the old file or the new one, never half of one.
Windows refuses to replace a file another process has open (the web app reading ``status.json``, a
viewer showing a figure), so the replace is tried again for a moment (:data:`REPLACE_RETRY_SECONDS`).
"""

from __future__ import annotations

import errno
import json
import os
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any

REPLACE_RETRY_SECONDS = 2.0
"""How long a replace refused with PermissionError is tried again (every 0.05 s at first, then up to
every 0.25 s) before the error stands. On Windows that is another process holding the target open for a
moment, as readers here do (they read a file whole, then close it); elsewhere a replace is refused only
for good, and is reported this much later."""
REPLACE_RETRY_DELAYS = (0.05, 0.25)
"""The first pause between tries, and the longest (each pause doubles up to it)."""


def write_atomic(path: Path, write: Callable[[IO[bytes]], None], durable: bool = True) -> None:
    """Call ``write`` on a temp file in ``path``'s folder, then move it over ``path``.

    ``os.replace`` alone is atomic against a killed process; ``durable`` also fsyncs the data so a
    power loss cannot leave an empty file (checkpoints want that; frequent status files do not).
    """

    def write_file(tmp: Path) -> None:
        with open(tmp, "wb") as handle:
            write(handle)
            handle.flush()
            if durable:
                os.fsync(handle.fileno())

    replace_atomically(path, write_file)


def replace_atomically(path: Path, write_file: Callable[[Path], None], suffix: str = ".tmp") -> None:
    """Call ``write_file`` on a fresh temp path beside ``path`` (ending in ``suffix``, for writers that
    choose a format by extension), then move it over ``path``; on any error the temp file goes."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix, dir=path.parent)
    except OSError as err:  # named for the file being written, not its folder or temp file
        raise OSError(err.errno, err.strerror or str(err), str(path)) from err
    os.close(fd)
    try:
        write_file(Path(tmp))
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600 files; give the usual mode
        replace_retrying(tmp, path)
    except OSError as err:  # named for the file being written, not its temp file: "disk full: latest.pt"
        Path(tmp).unlink(missing_ok=True)
        raise OSError(err.errno, err.strerror or str(err), str(path)) from err
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def replace_retrying(source: str | Path, target: Path) -> None:
    """``os.replace(source, target)``, tried again while it is refused with PermissionError, for up to
    :data:`REPLACE_RETRY_SECONDS`; any other error at once."""
    deadline = time.monotonic() + REPLACE_RETRY_SECONDS
    delay, longest = REPLACE_RETRY_DELAYS
    while True:
        try:
            os.replace(source, target)
            return
        except PermissionError:
            if time.monotonic() + delay > deadline:
                raise
        time.sleep(delay)
        delay = min(2 * delay, longest)


def append_text(path: Path, text: str) -> None:
    """Append ``text`` (one write, then flush); an OS error is named for ``path``, as every other
    write of a run is (:func:`replace_atomically`), so a full disk says which file it stopped."""
    try:
        with open(path, "a", encoding="utf-8") as handle:
            handle.write(text)
            handle.flush()
    except OSError as err:
        if err.filename:
            raise
        raise OSError(err.errno, err.strerror or str(err), str(path)) from err


DISK_FULL = (errno.ENOSPC, errno.EDQUOT)
"""The errors of a write that found no space: the disk is full, or the user's quota is spent."""


def overwrite_in_place(path: Path, text: str) -> None:
    """Rewrite an existing small file over its own bytes (not atomic): on a full disk, where a temp file
    cannot be made, a file whose blocks exist can still be rewritten as long as the text fits them."""
    with open(path, "r+b") as handle:
        handle.write(text.encode())
        handle.truncate()


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def write_bytes_atomic(path: Path, data: bytes | memoryview, durable: bool = False) -> None:
    """Write ``data``, atomically."""

    def write(handle: IO[bytes]) -> None:
        handle.write(data)

    write_atomic(path, write, durable)


def write_text_atomic(path: Path, text: str, durable: bool = False) -> None:
    """Write ``text`` as UTF-8, atomically."""
    write_bytes_atomic(path, text.encode(), durable)


def write_json_atomic(path: Path, data: Any, durable: bool = False) -> None:
    """Write ``data`` as indented JSON, atomically."""
    text = json.dumps(data, indent=2, sort_keys=False, allow_nan=False) + "\n"
    write_text_atomic(path, text, durable)
