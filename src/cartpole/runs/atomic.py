"""Atomic file writes: write a temp file beside the target, fsync, then ``os.replace``.

A crash or ``kill -9`` at any moment leaves either the old file or the new one, never half of one.
"""

from __future__ import annotations

import errno
import json
import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any


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
        os.replace(tmp, path)
    except OSError as err:  # named for the file being written, not its temp file: "disk full: latest.pt"
        Path(tmp).unlink(missing_ok=True)
        raise OSError(err.errno, err.strerror or str(err), str(path)) from err
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


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
