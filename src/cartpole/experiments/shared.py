"""A comparison shared by many machines through one database (``cartpole compare --storage URL``).

Two tables, made by SQLAlchemy where they are missing (the same database a sweep uses can hold them):

- ``cartpole_comparisons``: one row per comparison name: what every run shares (env, budget), its
  entries in order, and the claim timeout;
- ``cartpole_comparison_runs``: one row per (comparison, entry, seed), its primary key, so a re-run
  adds nothing twice. A row is ``pending``, ``claimed`` by one worker (its ``owner``, with a
  ``heartbeat`` in the database's own clock) or ``finished`` with the run's record and evaluation
  curve, written as the run ends.

A worker claims rows in one statement that locks only the rows it takes (``FOR UPDATE SKIP LOCKED``
with a ``LIMIT`` on PostgreSQL), so many workers claim at the same moment and every row is claimed by
exactly one worker. Rows of a claimed chunk share an entry, so that an agent that batches its seeds
trains them as one population. A worker renews the heartbeat of its claims while it runs them and
learns from it which it still holds; a claim whose heartbeat is older than the claim timeout (its
worker was killed, lost its machine or its network) is taken over by another worker, who resumes the
run where it has the run's folder and trains it again where not, and the first worker, if it comes
back, stops that run. Only the first finish of a row is kept.
"""

from __future__ import annotations

import os
import socket
import time
import uuid
from dataclasses import dataclass
from enum import StrEnum
from typing import Any

from cartpole.experiments.entries import Entry, ExperimentError
from cartpole.experiments.pause_points import pause_in_claims
from cartpole.experiments.storage import (
    DEFAULT_CLAIM_TIMEOUT,
    driver_url,
    engine_options,
    missing_driver,
    unreachable,
)

MIN_CLAIM_TIMEOUT = 2.0
CREATE_ATTEMPTS = 5


class RowState(StrEnum):
    """Where one (entry, seed) run of a shared comparison stands."""

    PENDING = "pending"
    CLAIMED = "claimed"
    FINISHED = "finished"


def _tables() -> tuple[Any, Any, Any]:
    import sqlalchemy as sa

    metadata = sa.MetaData()
    comparisons = sa.Table(
        "cartpole_comparisons",
        metadata,
        sa.Column("name", sa.String(200), primary_key=True),
        sa.Column("setup", sa.JSON, nullable=False),
        sa.Column("entries", sa.JSON, nullable=False),
        sa.Column("claim_timeout", sa.Float, nullable=False),
    )
    runs = sa.Table(
        "cartpole_comparison_runs",
        metadata,
        sa.Column("comparison", sa.String(200), primary_key=True),
        sa.Column("entry", sa.String(500), primary_key=True),
        sa.Column("seed", sa.Integer, primary_key=True),
        sa.Column("agent", sa.String(100), nullable=False),
        sa.Column("preset", sa.String(500), nullable=False),
        sa.Column("state", sa.String(16), nullable=False),
        sa.Column("owner", sa.String(300)),
        sa.Column("heartbeat", sa.Float),
        sa.Column("claims", sa.Integer, nullable=False, default=0),
        sa.Column("record", sa.JSON),
        sa.Column("curve", sa.JSON),
    )
    return metadata, comparisons, runs


METADATA, COMPARISONS, RUNS = _tables()


def new_owner() -> str:
    """This worker's name in claims: machine, process, and a random part (pids repeat)."""
    return f"{socket.gethostname()}:{os.getpid()}:{uuid.uuid4().hex[:8]}"


@dataclass(frozen=True)
class Claim:
    """Seeds of one entry that this worker owns until it finishes or releases them."""

    entry: Entry
    seeds: list[int]


@dataclass
class Progress:
    """Counts over every row of the comparison."""

    total: int = 0
    finished: int = 0
    solved: int = 0
    claimed: int = 0
    pending: int = 0

    @classmethod
    def of_rows(cls, rows: list[Any]) -> Progress:
        progress = cls(total=len(rows))
        for row in rows:
            if row.state == RowState.FINISHED:
                progress.finished += 1
                progress.solved += bool((row.record or {}).get("solved_in_training"))
            elif row.state == RowState.CLAIMED:
                progress.claimed += 1
            else:
                progress.pending += 1
        return progress


class SharedComparison:
    """One comparison's rows in the database at ``url``."""

    def __init__(self, url: str, name: str, engine: Any, claim_timeout: float, setup: dict[str, Any]):
        self.url, self.name, self.engine = url, name, engine
        self.claim_timeout, self.setup = claim_timeout, setup
        self.statements = engine.execution_options(isolation_level="AUTOCOMMIT")
        self._claim_statements: dict[tuple[Any, ...], Any] = {}
        """The engine for what one statement does (claim, heartbeat, finish, release): a transaction of
        its own, without BEGIN and COMMIT, each a round trip to the database."""

    # -- opening ---------------------------------------------------------------------------------------

    @staticmethod
    def connect(url: str, create: bool = True) -> Any:
        """An engine on ``url`` with the tables created where missing (``create``; a reader that must
        write nothing passes False). ExperimentError, one line, if it cannot be had."""
        import sqlalchemy as sa
        from sqlalchemy.exc import OperationalError, SQLAlchemyError

        try:
            engine = sa.create_engine(driver_url(url), **engine_options(url))
        except ImportError as err:
            raise missing_driver(url, err) from None
        pause_in_claims(engine)  # a test hook: nothing unless CARTPOLE_PAUSE_AT says so
        if not create:
            return engine
        for attempt in range(CREATE_ATTEMPTS):
            try:
                METADATA.create_all(engine)
                return engine
            except OperationalError as err:
                raise unreachable(url, err) from None
            except SQLAlchemyError as err:  # two machines creating the tables at the same moment
                if attempt == CREATE_ATTEMPTS - 1:
                    raise unreachable(url, err) from None
                time.sleep(0.5 + attempt)
        raise AssertionError("unreachable")

    @classmethod
    def join(
        cls,
        url: str,
        name: str,
        setup: dict[str, Any],
        entries: list[Entry],
        seeds: list[int],
        claim_timeout: float = DEFAULT_CLAIM_TIMEOUT,
    ) -> SharedComparison:
        """Create the comparison or join it (the same env and budget), adding its missing rows."""
        if claim_timeout < MIN_CLAIM_TIMEOUT:
            raise ExperimentError(
                f"--claim-timeout must be >= {MIN_CLAIM_TIMEOUT:g} seconds, got {claim_timeout:g}"
            )
        engine = cls.connect(url)
        check_returning(engine)
        with engine.begin() as db:
            _insert_missing(db, COMPARISONS, [{
                "name": name, "setup": setup, "entries": [], "claim_timeout": claim_timeout,
            }])  # fmt: skip
            row = db.execute(COMPARISONS.select().where(COMPARISONS.c.name == name).with_for_update()).one()
            check_setup(name, dict(row.setup), setup)
            known = list(row.entries)
            added = [e.label for e in entries if e.label not in known]
            if added:
                db.execute(
                    COMPARISONS.update().where(COMPARISONS.c.name == name).values(entries=known + added)
                )
            _insert_missing(db, RUNS, [
                {"comparison": name, "entry": e.label, "seed": s, "agent": e.agent, "preset": e.preset,
                 "state": RowState.PENDING, "claims": 0}
                for s in seeds for e in entries
            ])  # fmt: skip
        return cls(url, name, engine, float(row.claim_timeout), setup)

    @classmethod
    def open(cls, url: str, name: str, engine: Any = None) -> SharedComparison:
        """An existing comparison (for its report); ExperimentError if the database has none of that name.
        ``engine``: one from :meth:`connect` to reuse (a server reading many times)."""
        engine = engine or cls.connect(url)
        with engine.connect() as db:
            row = db.execute(COMPARISONS.select().where(COMPARISONS.c.name == name)).one_or_none()
        if row is None:
            raise ExperimentError(f"no comparison named {name!r} in the storage; check --name and --storage")
        return cls(url, name, engine, float(row.claim_timeout), dict(row.setup))

    # -- claims ----------------------------------------------------------------------------------------

    def claim(
        self,
        owner: str,
        chunk: int,
        batches: dict[str, bool],
        skip: set[tuple[str, int]],
        labels: list[str],
        seeds: list[int],
    ) -> Claim | None:
        """Claim up to ``chunk`` runs of one entry (one run where the entry does not batch its seeds)
        among ``labels`` x ``seeds``, but not those in ``skip``: pending ones, or claims whose heartbeat
        is older than the claim timeout. None if there are none free.

        One statement: the first claimable row (in seed order) names the entry, and up to the chunk's
        size of that entry's claimable rows are claimed. On PostgreSQL both look-ups lock only the rows
        they return and skip those other claims lock (``FOR UPDATE SKIP LOCKED``, each with its
        ``LIMIT``), so many workers claim at the same moment, each other rows; on SQLite the statement
        holds the database's write lock. Either way the update checks again that each row is claimable,
        so no row is claimed twice."""
        statement = self.claim_statement(chunk, batches, skip, labels, seeds)
        with self.statements.connect() as db:
            rows = sorted(db.execute(statement, {"claimant": owner}).all(), key=lambda row: row.seed)
        if not rows:
            return None
        return Claim(Entry(rows[0].agent, rows[0].preset), [row.seed for row in rows])

    def claim_statement(
        self,
        chunk: int,
        batches: dict[str, bool],
        skip: set[tuple[str, int]],
        labels: list[str],
        seeds: list[int],
    ) -> Any:
        """The statement :meth:`claim` runs with these arguments, built once and kept: a worker claims
        with the same arguments again and again, and builds it ahead (as it joins), so that its first
        claim costs no more than the next."""
        batching = tuple(label for label in labels if batches.get(label, False))
        key = (chunk, batching, tuple(labels), tuple(seeds), frozenset(skip))
        statement = self._claim_statements.get(key)
        if statement is None:
            statement = self._claim_statement(*key)
            self._claim_statements = {key: statement}
        return statement

    def _claim_statement(
        self,
        chunk: int,
        batching: tuple[str, ...],
        labels: tuple[str, ...],
        seeds: tuple[int, ...],
        skip: frozenset[tuple[str, int]],
    ) -> Any:
        """The UPDATE of :meth:`claim` (its owner a bound parameter, ``claimant``)."""
        import sqlalchemy as sa

        now = database_clock(self.engine.dialect.name)
        claimable = self._claimable(list(labels), list(seeds), set(skip), now)
        first = (
            sa.select(RUNS.c.entry)
            .where(claimable)
            .order_by(RUNS.c.seed, RUNS.c.entry)
            .limit(1)
            .with_for_update(skip_locked=True)
            .cte("first_claimable")
            .prefix_with("MATERIALIZED", dialect="postgresql")  # evaluated (and locked) once
        )
        entry = sa.select(first.c.entry).scalar_subquery()
        size = sa.case((entry.in_(list(batching)), chunk), else_=1) if batching and chunk > 1 else 1
        picked = (
            sa.select(RUNS.c.entry, RUNS.c.seed)
            .where(claimable, RUNS.c.entry == entry)
            .order_by(RUNS.c.seed)
            .limit(size)
            .with_for_update(skip_locked=True)
            .cte("picked")
            .prefix_with("MATERIALIZED", dialect="postgresql")
        )
        return (
            RUNS.update()
            .where(
                RUNS.c.comparison == self.name,
                RUNS.c.entry == picked.c.entry,
                RUNS.c.seed == picked.c.seed,
                self._free(now),  # again: on SQLite nothing was locked
            )
            .values(
                state=RowState.CLAIMED,
                owner=sa.bindparam("claimant"),
                heartbeat=now,
                claims=RUNS.c.claims + 1,
            )
            .returning(RUNS.c.entry, RUNS.c.seed, RUNS.c.agent, RUNS.c.preset)
        )

    def heartbeat(self, owner: str) -> set[tuple[str, int]]:
        """Renew every claim of ``owner``; the (entry label, seed) of each claim it still holds (one
        another worker took over, or finished, is no longer its)."""
        statement = (
            RUNS.update()
            .where(RUNS.c.comparison == self.name, RUNS.c.owner == owner, RUNS.c.state == RowState.CLAIMED)
            .values(heartbeat=database_clock(self.engine.dialect.name))
            .returning(RUNS.c.entry, RUNS.c.seed)
        )
        with self.statements.connect() as db:
            return {(row.entry, row.seed) for row in db.execute(statement)}

    def finish(
        self, owner: str, entry: Entry, seed: int, record: dict[str, Any], curve: dict[str, Any]
    ) -> bool:
        """Store a finished run's record and curve; False if another worker finished it first."""
        with self.statements.connect() as db:
            result = db.execute(
                RUNS.update()
                .where(self._row(entry, seed), RUNS.c.state != RowState.FINISHED)
                .values(state=RowState.FINISHED, owner=owner, record=record, curve=curve)
            )
        return bool(result.rowcount)

    def release(self, owner: str, entry: Entry, seed: int) -> None:
        """Give a claim back (the run was interrupted here): pending again, for any worker."""
        with self.statements.connect() as db:
            db.execute(
                RUNS.update()
                .where(self._row(entry, seed), RUNS.c.owner == owner, RUNS.c.state == RowState.CLAIMED)
                .values(state=RowState.PENDING, owner=None, heartbeat=None)
            )

    def _claimable(self, labels: list[str], seeds: list[int], skip: set[tuple[str, int]], now: Any) -> Any:
        """Rows of ``labels`` x ``seeds`` not in ``skip`` that a worker may claim at ``now`` (an SQL
        expression): pending, or claimed with a heartbeat older than the claim timeout."""
        import sqlalchemy as sa

        if not skip:
            return sa.and_(self._asked(labels, seeds), self._free(now))
        skipped = sa.tuple_(RUNS.c.entry, RUNS.c.seed).in_(sorted(skip))
        return sa.and_(self._asked(labels, seeds), self._free(now), sa.not_(skipped))

    def _free(self, now: Any) -> Any:
        """Rows a worker may claim at ``now`` (an SQL expression): pending, or claimed with a heartbeat
        older than the claim timeout."""
        import sqlalchemy as sa

        return sa.or_(
            RUNS.c.state == RowState.PENDING,
            sa.and_(RUNS.c.state == RowState.CLAIMED, RUNS.c.heartbeat < now - self.claim_timeout),
        )

    def _asked(self, labels: list[str], seeds: list[int]) -> Any:
        """The rows of ``labels`` x ``seeds`` in this comparison (the seeds as ranges: a thousand seeds
        are one condition, not a thousand values for the database to parse and test each row against)."""
        import sqlalchemy as sa

        ranges = [RUNS.c.seed.between(low, high) for low, high in seed_ranges(seeds)]
        return sa.and_(RUNS.c.comparison == self.name, RUNS.c.entry.in_(labels), sa.or_(sa.false(), *ranges))

    def _row(self, entry: Entry, seed: int) -> Any:
        import sqlalchemy as sa

        return sa.and_(RUNS.c.comparison == self.name, RUNS.c.entry == entry.label, RUNS.c.seed == seed)

    # -- reading ---------------------------------------------------------------------------------------

    def rows(self, labels: list[str] | None = None, seeds: list[int] | None = None) -> list[Any]:
        """The comparison's rows (those of ``labels`` x ``seeds`` where given), in seed order."""
        import sqlalchemy as sa

        where = RUNS.c.comparison == self.name
        if labels is not None and seeds is not None:
            where = sa.and_(where, self._asked(labels, seeds))
        with self.engine.connect() as db:
            return list(db.execute(RUNS.select().where(where).order_by(RUNS.c.seed, RUNS.c.entry)).all())

    def entries(self) -> list[Entry]:
        """The comparison's entries, in the order they were first asked for."""
        import sqlalchemy as sa

        with self.engine.connect() as db:
            labels = db.execute(
                sa.select(COMPARISONS.c.entries).where(COMPARISONS.c.name == self.name)
            ).scalar_one()
            query = sa.select(RUNS.c.entry, RUNS.c.agent, RUNS.c.preset).where(RUNS.c.comparison == self.name)
            agents = {r.entry: (r.agent, r.preset) for r in db.execute(query.distinct())}
        return [Entry(*agents[label]) for label in labels if label in agents]

    def progress(self, labels: list[str] | None = None, seeds: list[int] | None = None) -> Progress:
        """Counts over the comparison's rows (those of ``labels`` x ``seeds`` where given)."""
        return Progress.of_rows(self.rows(labels, seeds))

    def finished(self) -> tuple[dict[Entry, list[dict[str, Any]]], dict[Entry, list[dict[str, Any]]]]:
        """(records, curves) of the finished runs, per entry, in seed order."""
        entries = {e.label: e for e in self.entries()}
        records: dict[Entry, list[dict[str, Any]]] = {e: [] for e in entries.values()}
        curves: dict[Entry, list[dict[str, Any]]] = {e: [] for e in entries.values()}
        for row in self.rows():
            if row.state == RowState.FINISHED and row.entry in entries:
                records[entries[row.entry]].append(dict(row.record))
                curves[entries[row.entry]].append(dict(row.curve or {}))
        return records, curves

    def seeds(self) -> list[int]:
        return sorted({row.seed for row in self.rows()})


SETUP_FLAGS = {"env_id": "--env", "budget": "--budget", "env_kwargs": "--env-kwargs"}
"""The flag that sets each value of a comparison's setup, for the message that refuses another."""


def check_setup(name: str, stored: dict[str, Any], asked: dict[str, Any]) -> None:
    """A comparison joined with another env, its kwargs or budget would mix results: refuse, naming
    the flag (kwargs none and kwargs absent are the same)."""
    for key, value in (asked | {"env_kwargs": asked.get("env_kwargs") or {}}).items():
        if (stored.get(key) or ({} if key == "env_kwargs" else None)) != value:
            flag = SETUP_FLAGS.get(key, key)
            raise ExperimentError(
                f"comparison {name} in the storage was run with {flag} {stored.get(key)}, not {value}; "
                "use the same value or another --name"
            )


def check_returning(engine: Any) -> None:
    """Claims and heartbeats read the rows they update (``UPDATE ... RETURNING``), which SQLite has from
    3.35 on: ExperimentError, one line, with an older one."""
    if engine.dialect.name == "sqlite" and not engine.dialect.update_returning:
        version = ".".join(map(str, engine.dialect.dbapi.sqlite_version_info))
        raise ExperimentError(
            f"a shared comparison on SQLite needs SQLite >= 3.35, and this Python's is {version}; "
            "use PostgreSQL, or a Python built with a newer SQLite"
        )


def _insert_missing(db: Any, table: Any, rows: list[dict[str, Any]]) -> None:
    """Insert the rows whose primary key is not there yet (ON CONFLICT DO NOTHING)."""
    if not rows:
        return
    from sqlalchemy.dialects import postgresql, sqlite

    dialects: dict[str, Any] = {"postgresql": postgresql.insert, "sqlite": sqlite.insert}
    insert = dialects.get(db.dialect.name)
    if insert is None:
        raise ExperimentError(f"a shared comparison needs PostgreSQL (or SQLite), not {db.dialect.name}")
    db.execute(insert(table).on_conflict_do_nothing(), rows)


def seed_ranges(seeds: list[int]) -> list[tuple[int, int]]:
    """``seeds`` as (first, last) ranges of consecutive seeds, in order: [0, 1, 2, 5] -> [(0, 2), (5, 5)]."""
    ranges: list[tuple[int, int]] = []
    for seed in sorted(set(seeds)):
        if ranges and seed == ranges[-1][1] + 1:
            ranges[-1] = (ranges[-1][0], seed)
        else:
            ranges.append((seed, seed))
    return ranges


def database_clock(dialect: str) -> Any:
    """The database server's clock in seconds since the epoch, as an SQL expression: one clock for every
    machine's claims, read in the statement that uses it."""
    import sqlalchemy as sa

    if dialect == "postgresql":
        return sa.func.extract("epoch", sa.func.statement_timestamp())
    return (sa.func.julianday("now") - 2440587.5) * 86400.0


__all__ = [
    "DEFAULT_CLAIM_TIMEOUT",
    "SETUP_FLAGS",
    "Claim",
    "Progress",
    "RowState",
    "SharedComparison",
    "new_owner",
]
