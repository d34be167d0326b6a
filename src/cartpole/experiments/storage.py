"""Database URLs of shared experiments (``--storage``): checked once, opened the same way by the
sweep (through Optuna's RDBStorage) and by shared comparisons (through SQLAlchemy)."""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Sequence
from typing import Any, TypeVar

from cartpole.experiments.entries import ExperimentError

SUPPORTED = ("postgresql", "sqlite", "mysql")
CONNECT_TIMEOUT_SECONDS = 10
RETRY_WAITS = (1.0, 2.0, 4.0, 8.0, 15.0, 30.0, 30.0, 30.0, 30.0, 30.0)
"""Seconds before each new try of a database call that lost its connection (a server restarting, a
network cut): about three minutes in all, then the call fails (:func:`retry_lost_connection`)."""
T = TypeVar("T")
DEFAULT_CLAIM_TIMEOUT = 120.0
"""Seconds without a heartbeat after which another worker takes a shared comparison's claim over (here,
not in :mod:`cartpole.experiments.shared`, so that the CLI's parser has it without SQLAlchemy)."""


def describe_url(url: str) -> tuple[str, str]:
    """(backend, "host:port") of a database URL, for messages; ExperimentError if it is malformed."""
    from sqlalchemy.engine import make_url
    from sqlalchemy.exc import ArgumentError

    try:
        parsed = make_url(url)
    except (ArgumentError, ValueError):  # ValueError: a port that is not a number
        raise ExperimentError(
            f"malformed --storage URL {url!r}; use postgresql://USER@HOST:PORT/DB (or sqlite:///FILE.db)"
        ) from None
    backend = parsed.get_backend_name()
    if backend not in SUPPORTED:
        raise ExperimentError(
            f"--storage {backend}:// is not supported; use postgresql://USER@HOST:PORT/DB or sqlite:///FILE.db"
        )
    if backend == "sqlite":
        return backend, parsed.database or ":memory:"
    if not parsed.host:
        raise ExperimentError(f"--storage URL {url!r} names no host; use postgresql://USER@HOST:PORT/DB")
    port = parsed.port or {"postgresql": 5432, "mysql": 3306}[backend]
    return backend, f"{parsed.host}:{port}"


def driver_url(url: str) -> str:
    """``url`` with the driver we install: psycopg 3 (the postgres extra) for ``postgresql://``, also
    where SQLAlchemy < 2.1 would pick psycopg2."""
    if url.startswith("postgresql://"):
        return "postgresql+psycopg://" + url.removeprefix("postgresql://")
    return url


def engine_options(url: str) -> dict[str, Any]:
    """SQLAlchemy engine options: connections checked before use, a bounded connect time."""
    backend, _ = describe_url(url)
    options: dict[str, Any] = {"pool_pre_ping": True}
    if backend == "postgresql":
        options["connect_args"] = {"connect_timeout": CONNECT_TIMEOUT_SECONDS}
    return options


def missing_module(err: ImportError) -> str:
    """The name of the module whose import failed, looking through Optuna's re-raise."""
    cause = err.__cause__ if isinstance(err.__cause__, ImportError) else err
    return cause.name or str(cause)


def missing_driver(url: str, err: ImportError) -> ExperimentError:
    """The one-line error for a database URL whose driver is not installed."""
    backend, _ = describe_url(url)
    hint = (
        "; use postgresql://USER@HOST:PORT/DB and pip install 'cartpole[postgres]'"
        if backend == "postgresql"
        else ""
    )
    return ExperimentError(
        f"--storage {backend}:// needs its driver ({missing_module(err)}), which is not installed{hint}"
    )


def unreachable(url: str, err: Exception) -> ExperimentError:
    """The one-line error for a database that cannot be reached (no server, wrong user or database)."""
    backend, where = describe_url(url)
    reason = str(getattr(err, "orig", None) or err).strip().splitlines()[0]
    return ExperimentError(f"cannot reach the {backend} storage at {where}: {reason}")


def lost_connection(err: BaseException) -> bool:
    """Whether ``err``, or an error it was raised from or while handling, is a lost or refused
    connection, or a server that is not ready (starting up, shutting down): worth a new try."""
    return connection_error_in(err) is not None


def connection_error_in(err: BaseException) -> BaseException | None:
    """The lost-connection error in ``err``'s chain, or None. The chain follows ``__cause__`` (Optuna
    wraps SQLAlchemy's errors in its own) and ``__context__``: after a lost connection, the next query
    in the same session fails with SQLAlchemy's PendingRollbackError, which Optuna then wraps."""
    from sqlalchemy.exc import DBAPIError, InterfaceError, OperationalError

    seen: set[int] = set()
    link: BaseException | None = err
    while link is not None and id(link) not in seen:
        seen.add(id(link))
        if isinstance(link, (OperationalError, InterfaceError)) or (
            isinstance(link, DBAPIError) and link.connection_invalidated
        ):
            return link
        link = link.__cause__ or (None if link.__suppress_context__ else link.__context__)
    return None


def reason_of(err: BaseException) -> str:
    """The first line of what the database driver said."""
    err = connection_error_in(err) or err
    while err.__cause__ is not None and not hasattr(err, "orig"):
        err = err.__cause__
    lines = str(getattr(err, "orig", None) or err).strip().splitlines()
    return lines[0] if lines else type(err).__name__


class StorageLost(ExperimentError):
    """The database stayed out of reach for longer than its calls are tried again."""

    @classmethod
    def of(cls, err: BaseException, what: str) -> StorageLost:
        return cls(
            f"lost the database connection ({reason_of(err)}) for good while trying to {what}: what "
            "finished is stored; re-run the same command to resume"
        )


def retry_lost_connection(what: str, call: Callable[[], T], waits: Sequence[float] | None = None) -> T:
    """``call()``, tried again after each of ``waits`` (default :data:`RETRY_WAITS`) while it loses its
    database connection, with one line on stderr each time; then the last error is raised. Every call
    given is one transaction (or none), so a new try does again only what the database rolled back."""
    waits = RETRY_WAITS if waits is None else waits
    for attempt, wait in enumerate(waits, start=1):
        try:
            return call()
        except Exception as err:
            if not lost_connection(err):
                raise
            print(
                f"lost the database connection ({reason_of(err)}) while trying to {what}: retrying in "
                f"{wait:g} s ({attempt}/{len(waits)})",
                file=sys.stderr,
                flush=True,
            )
            time.sleep(wait)
    return call()


__all__ = [
    "StorageLost",
    "describe_url",
    "driver_url",
    "engine_options",
    "missing_driver",
    "missing_module",
    "retry_lost_connection",
    "unreachable",
]  # fmt: skip
