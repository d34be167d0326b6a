"""Checkpoint files: tensors plus JSON metadata, never pickled objects.

A checkpoint is ``torch.save({"meta": <JSON text>, "tensors": {name: Tensor}})`` and is read back with
``torch.load(..., weights_only=True)``, which refuses to build arbitrary Python objects. Writes are
atomic, so an interrupted save leaves the previous checkpoint intact.
"""

from __future__ import annotations

import json
import pickle
import warnings
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any, cast

from cartpole.core.errors import InputError
from cartpole.core.version import __version__
from cartpole.runs.atomic import write_atomic

if TYPE_CHECKING:
    import torch

FORMAT = "cartpole-checkpoint"
FORMAT_VERSION = 1
SUFFIX = ".pt"


class CheckpointError(InputError, ValueError):
    """A checkpoint file is missing, truncated, corrupt, foreign or from an unknown format version."""


class UnreadableCheckpoint(CheckpointError):
    """A file that torch cannot read as a checkpoint; ``reason`` says what the file is instead."""

    def __init__(self, path: Path, reason: str, hint: str) -> None:
        super().__init__(f"{path} {reason}; {hint}")
        self.path, self.reason = path, reason


DAMAGED_HINT = "use another of the run's checkpoints (`cartpole eval RUN` tries each) or train again"
FOREIGN_HINT = "use a checkpoint written by `cartpole train`"


@dataclass
class Checkpoint:
    """What a checkpoint holds: named tensors and plain metadata."""

    meta: dict[str, Any]
    tensors: dict[str, torch.Tensor] = field(default_factory=dict)

    @property
    def agent(self) -> str:
        return self._text("agent")

    @property
    def env_id(self) -> str:
        return self._text("env_id")

    @property
    def env_kwargs(self) -> dict[str, Any]:
        """The kwargs the agent's env was made with (none recorded: none)."""
        kwargs = self.meta.get("env_kwargs") or {}
        if not isinstance(kwargs, dict):
            raise CheckpointError("the checkpoint's metadata records env_kwargs that are not a table")
        return kwargs

    @property
    def wrappers(self) -> list[Any]:
        """The wrappers the agent's env was put in, as its preset listed them (none recorded: none)."""
        wrappers = self.meta.get("wrappers") or []
        if not isinstance(wrappers, list):
            raise CheckpointError("the checkpoint's metadata records wrappers that are not a list")
        return wrappers

    def _text(self, key: str) -> str:
        value = self.meta.get(key)
        if not isinstance(value, str):
            raise CheckpointError(f"the checkpoint's metadata records no {key} (it is damaged or foreign)")
        return value


def save_checkpoint(path: Path, checkpoint: Checkpoint) -> None:
    """Write ``checkpoint`` to ``path`` atomically, stamping format and package version."""
    import torch  # imported here: torch's import takes seconds and most commands never need it

    meta = {"format": FORMAT, "format_version": FORMAT_VERSION, "package_version": __version__}
    meta.update(checkpoint.meta)
    payload = {
        "meta": json.dumps(meta, allow_nan=False),
        "tensors": {k: v.detach().cpu().contiguous() for k, v in checkpoint.tensors.items()},
    }

    def stream(handle: IO[bytes]) -> None:  # straight into the file: no in-memory copy of a 600 MB replay
        writer = _KeepWriteError(handle)
        try:
            torch.save(payload, cast(IO[bytes], writer))  # torch calls only write and flush
        except RuntimeError:  # torch's zip writer may turn the file's OSError (a full disk) into this
            if writer.error is not None:
                raise writer.error from None
            raise

    write_atomic(path, stream, durable=True)


class _KeepWriteError:
    """A file's ``write`` for torch.save that keeps the OSError it raised, errno and all."""

    def __init__(self, handle: IO[bytes]):
        self.handle = handle
        self.error: OSError | None = None

    def write(self, data: bytes) -> int:
        try:
            return self.handle.write(data)
        except OSError as err:
            self.error = err
            raise

    def flush(self) -> None:
        self.handle.flush()


TORCH_ZIP_RECORD = "data.pkl"
"""Every checkpoint torch.save writes is a zip archive holding ``<name>/data.pkl``."""


def what_the_file_is(path: Path, err: BaseException) -> tuple[str, bool]:
    """What a file that torch could not load is, in words, and whether it looks like one of ours damaged
    (True) rather than a file of another kind (False). Reads only the file's first bytes and, for a zip
    archive, its list of members."""
    try:
        with open(path, "rb") as handle:
            head = handle.read(8)
    except OSError as read_error:
        return f"cannot be read ({read_error.strerror or read_error})", True
    if not head:
        return "is empty (0 bytes): its write was cut off", True
    if head.startswith(b"PK"):
        try:
            with zipfile.ZipFile(path) as archive:
                members = archive.namelist()
        except (zipfile.BadZipFile, OSError, ValueError):
            return "is truncated or damaged (a zip archive cut short)", True
        if not any(name.endswith(TORCH_ZIP_RECORD) for name in members):
            return "is a zip archive, not a torch checkpoint", False
        if not isinstance(err, pickle.UnpicklingError):
            return f"is a damaged torch checkpoint ({type(err).__name__})", True
    if head.startswith((b"PK", b"\x80")):  # a torch file, or a pickle, that weights_only refused
        return (
            "is not a cartpole checkpoint: it holds pickled Python objects, which we never load "
            "(they can run code)",
            False,
        )
    if head.lstrip()[:1] in (b"{", b"["):
        return "is a JSON or text file, not a checkpoint", False
    return "is not a checkpoint: neither a torch zip archive nor a pickle", False


def load_checkpoint(path: Path) -> Checkpoint:
    """Read a checkpoint; raise CheckpointError with a one-line, actionable message if unusable."""
    import torch

    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"no checkpoint at {path}: check the path (see `cartpole runs`)")
    try:
        with warnings.catch_warnings():  # torch warns of a foreign file's pickle protocol; we say more below
            warnings.simplefilter("ignore", UserWarning)
            payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # weights_only refuses pickled objects with UnpicklingError
        reason, damaged = what_the_file_is(path, err)
        raise UnreadableCheckpoint(path, reason, DAMAGED_HINT if damaged else FOREIGN_HINT) from err
    if not isinstance(payload, dict) or not isinstance(payload.get("meta"), str):
        raise CheckpointError(f"{path} is not a cartpole checkpoint (no metadata found)")
    try:
        meta = json.loads(payload["meta"])
    except (json.JSONDecodeError, RecursionError) as err:
        raise CheckpointError(f"{path} has corrupt metadata: {err}") from err
    if not isinstance(meta, dict):
        raise CheckpointError(f"{path} has corrupt metadata (a {type(meta).__name__}, not an object)")
    if meta.get("format") != FORMAT:
        raise CheckpointError(f"{path} is not a cartpole checkpoint (format {meta.get('format')!r})")
    if meta.get("format_version") != FORMAT_VERSION:
        raise CheckpointError(
            f"{path} uses checkpoint format {meta.get('format_version')} (written by cartpole "
            f"{meta.get('package_version')}); this is cartpole {__version__}, which reads format "
            f"{FORMAT_VERSION}: use that version to load it"
        )
    tensors = payload.get("tensors", {})
    if not isinstance(tensors, dict) or not all(isinstance(t, torch.Tensor) for t in tensors.values()):
        raise CheckpointError(f"{path} is corrupt (tensors are not a mapping of names to tensors)")
    return Checkpoint(meta=meta, tensors=tensors)
