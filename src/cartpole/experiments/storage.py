"""Database URLs of shared experiments (``--storage``): checked once, opened the same way by the
sweep (through Optuna's RDBStorage) and by shared comparisons (through SQLAlchemy)."""

from __future__ import annotations

from typing import Any

from cartpole.experiments.entries import ExperimentError

SUPPORTED = ("postgresql", "sqlite", "mysql")
CONNECT_TIMEOUT_SECONDS = 10
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


__all__ = ["describe_url", "driver_url", "engine_options", "missing_driver", "missing_module", "unreachable"]
