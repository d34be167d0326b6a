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

Joining holds no lock across round trips (:meth:`SharedComparison.join`), so that a hundred workers
starting together each join in about one round trip. A worker never holds a row it does not run:
:meth:`SharedComparison.held` finds a claim whose reply was lost after its commit (the worker's new try
runs it), and :meth:`SharedComparison.release_rows` gives back what it holds without a job, and every
claim at once when it is stopped (``cartpole.experiments.compare.SharedRunner``).
"""

from __future__ import annotations

import os
import socket
import time
import uuid
from collections.abc import Iterator
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
JOIN_ATTEMPTS = 50
"""Reads of a comparison a join makes at most while other workers change its list of entries."""
INSERT_BATCH = 1000
"""Rows per INSERT statement where a join adds rows on SQLite."""
PING_AFTER_IDLE = 10.0
"""Seconds after which a pooled connection is checked before its next use (:func:`ping_when_idle`)."""


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
        write nothing passes False). ExperimentError, one line, if it cannot be had. A connection
        the pool hands out is checked first only where it has been idle (:func:`ping_when_idle`)."""
        import sqlalchemy as sa
        from sqlalchemy.exc import OperationalError, SQLAlchemyError

        try:
            options = engine_options(url) | {"pool_pre_ping": False}
            if url.startswith("postgresql"):  # no look-up of hstore's type as it connects: a round trip
                options["use_native_hstore"] = False
            engine = sa.create_engine(driver_url(url), **options)
        except ImportError as err:
            raise missing_driver(url, err) from None
        ping_when_idle(engine)
        pause_in_claims(engine)  # a test hook: nothing unless CARTPOLE_PAUSE_AT says so
        if not create:
            return engine
        for attempt in range(CREATE_ATTEMPTS):
            try:
                METADATA.create_all(engine)
                return engine
            except OperationalError as err:
                if "already exists" not in str(err) or attempt == CREATE_ATTEMPTS - 1:
                    raise unreachable(url, err) from None
                time.sleep(0.5 + attempt)  # SQLite: two processes creating the tables at the same moment
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
        """Create the comparison or join it (the same env and budget), adding its missing rows.

        Joining costs a worker about one round trip to the database however many join at the same
        moment: no lock is held across round trips. One statement reads the comparison's row with the
        count of the asked rows already there; a comparison with every entry and row asked for is
        joined (the common case: the tasks of a job array after the first). Otherwise only what is
        missing is written, each part a short transaction of its own:

        - a comparison not there yet is made with its entries and every row asked for, in one
          transaction (on PostgreSQL one statement, the rows made by the server); workers joining at
          the same moment wait for that one transaction, not for one another (on PostgreSQL an
          ``INSERT ... ON CONFLICT DO NOTHING`` waits for a conflicting uncommitted one; on SQLite for
          the write lock), then read the comparison again;
        - entries missing from the comparison's list are added by a compare-and-set of the list (an
          ``UPDATE`` that matches only the list as read), read again where another worker changed it;
        - missing rows (more seeds, another entry) are inserted in (entry, seed) order, ``ON CONFLICT
          DO NOTHING``, so that workers adding the same rows wait only for one another's statement,
          never in a cycle (on SQLite the rows there are read first).
        """
        if claim_timeout < MIN_CLAIM_TIMEOUT:
            raise ExperimentError(
                f"--claim-timeout must be >= {MIN_CLAIM_TIMEOUT:g} seconds, got {claim_timeout:g}"
            )
        engine = cls.connect(url, create=False)
        check_returning(engine)
        shared = cls(url, name, engine, claim_timeout, setup)
        from sqlalchemy.exc import OperationalError

        try:
            stored = shared._join(entries, seeds, claim_timeout)
        except OperationalError as err:  # no server there, a wrong user or database
            raise unreachable(url, err) from None
        shared.claim_timeout = float(stored.claim_timeout)
        return shared

    def _join(self, entries: list[Entry], seeds: list[int], claim_timeout: float) -> Any:
        """The comparison's row (its claim timeout) once it holds ``entries`` x ``seeds``."""
        from sqlalchemy.exc import SQLAlchemyError

        labels = [e.label for e in entries]
        created = False
        for attempt in range(JOIN_ATTEMPTS):
            try:
                row = self._joined_row(labels, seeds)
            except SQLAlchemyError as err:
                if created or not missing_table(err):
                    raise
                self.connect(self.url).dispose()  # a database without the tables: made, then read again
                created = True
                continue
            if row is None:
                self._create(entries, seeds, claim_timeout)
                continue  # made here, or by another worker meanwhile: read it
            check_setup(self.name, dict(row.setup), self.setup)
            known = list(row.entries)
            added = [label for label in labels if label not in known]
            if added and not self._add_entries(row.entries_text, known + added):
                time.sleep(0.05 * attempt)  # another worker changed the list: read it again
                continue
            if row.present < len(set(labels)) * len(set(seeds)):
                self._insert_missing_rows(entries, seeds)
            return row
        raise ExperimentError(
            f"comparison {self.name}: could not join it in {JOIN_ATTEMPTS} tries (other workers kept "
            "changing its entries); run the command again"
        )

    def _joined_row(self, labels: list[str], seeds: list[int]) -> Any:
        """The comparison's row (its list of entries also as stored text) and ``present``, the count of
        the rows of ``labels`` x ``seeds`` there: one statement. None where there is no comparison."""
        import sqlalchemy as sa

        present = sa.select(sa.func.count()).select_from(RUNS).where(self._asked(labels, seeds))
        statement = sa.select(
            COMPARISONS.c.setup,
            COMPARISONS.c.entries,
            sa.cast(COMPARISONS.c.entries, sa.Text).label("entries_text"),
            COMPARISONS.c.claim_timeout,
            present.scalar_subquery().label("present"),
        ).where(COMPARISONS.c.name == self.name)
        with self.statements.connect() as db:
            return db.execute(statement).one_or_none()

    def _create(self, entries: list[Entry], seeds: list[int], claim_timeout: float) -> None:
        """Make the comparison with its entries and rows, in one transaction; nothing where another
        worker made it first (this one waited for that worker's transaction). On PostgreSQL one
        statement, the rows made by the server (a round trip, whatever the seeds)."""
        labels = [e.label for e in entries]
        row = {"name": self.name, "setup": self.setup, "entries": labels, "claim_timeout": claim_timeout}
        if self.engine.dialect.name == "postgresql":
            from sqlalchemy.dialects import postgresql

            made = (
                postgresql.insert(COMPARISONS)
                .values(**row)
                .on_conflict_do_nothing()
                .returning(COMPARISONS.c.name)
                .cte("made")
            )
            with self.statements.connect() as db:
                db.execute(self._rows_made_by_the_server(entries, seeds, made).add_cte(made))
            return
        with self.engine.begin() as db:
            if _insert_missing(db, COMPARISONS, [row], returning=COMPARISONS.c.name):
                for batch in self._run_rows(entries, seeds):
                    _insert_missing(db, RUNS, batch)

    def _add_entries(self, stored_text: str, labels: list[str]) -> bool:
        """Set the comparison's entries to ``labels`` where they are still ``stored_text`` (one
        statement: a compare-and-set); False where another worker changed them meanwhile."""
        import sqlalchemy as sa

        with self.statements.connect() as db:
            result = db.execute(
                COMPARISONS.update()
                .where(
                    COMPARISONS.c.name == self.name, sa.cast(COMPARISONS.c.entries, sa.Text) == stored_text
                )
                .values(entries=labels)
            )
        return bool(result.rowcount)

    def _insert_missing_rows(self, entries: list[Entry], seeds: list[int]) -> None:
        """Insert the rows of ``entries`` x ``seeds`` not there yet, in (entry, seed) order, each
        statement a transaction of its own (on PostgreSQL one statement, the rows made by the server)."""
        import sqlalchemy as sa

        with self.statements.connect() as db:
            if db.dialect.name == "postgresql":
                db.execute(self._rows_made_by_the_server(entries, seeds))
                return
            labels = [e.label for e in entries]
            asked = sa.select(RUNS.c.entry, RUNS.c.seed).where(self._asked(labels, seeds))
            there = {(row.entry, row.seed) for row in db.execute(asked)}
            for batch in self._run_rows(entries, seeds, there):
                _insert_missing(db, RUNS, batch)

    def _rows_made_by_the_server(self, entries: list[Entry], seeds: list[int], made: Any = None) -> Any:
        """PostgreSQL's ``INSERT ... SELECT`` of the pending rows of ``entries`` x ``seeds`` (the seeds
        as ranges, each a ``generate_series``), in (entry, seed) order, ON CONFLICT DO NOTHING; with
        ``made`` (the CTE that makes the comparison) only where it made it."""
        import sqlalchemy as sa
        from sqlalchemy.dialects import postgresql

        asked_entries = sa.values(
            sa.column("entry", sa.String), sa.column("agent", sa.String), sa.column("preset", sa.String),
            name="asked_entries",
        ).data([(e.label, e.agent, e.preset) for e in dict.fromkeys(entries)])  # fmt: skip
        ranges = sa.values(sa.column("low", sa.Integer), sa.column("high", sa.Integer), name="asked_ranges")
        ranges = ranges.data(seed_ranges(seeds))
        seed = sa.func.generate_series(ranges.c.low, ranges.c.high).table_valued("seed")
        seed = seed.render_derived(name="asked_seeds")
        rows = sa.select(
            sa.literal(self.name), asked_entries.c.entry, seed.c.seed, asked_entries.c.agent,
            asked_entries.c.preset, sa.literal(str(RowState.PENDING)), sa.literal(0),
        )  # fmt: skip
        if made is not None:
            rows = rows.select_from(made).join(asked_entries, sa.true())
        else:
            rows = rows.select_from(asked_entries)
        rows = rows.join(ranges, sa.true()).join(seed, sa.true()).order_by(asked_entries.c.entry, seed.c.seed)
        columns = ["comparison", "entry", "seed", "agent", "preset", "state", "claims"]
        return postgresql.insert(RUNS).from_select(columns, rows).on_conflict_do_nothing()

    def _run_rows(
        self, entries: list[Entry], seeds: list[int], there: set[tuple[str, int]] | None = None
    ) -> Iterator[list[dict[str, Any]]]:
        """The pending rows of ``entries`` x ``seeds`` not in ``there``, in (entry, seed) order, in
        batches of :data:`INSERT_BATCH`."""
        rows = [
            {"comparison": self.name, "entry": e.label, "seed": s, "agent": e.agent, "preset": e.preset,
             "state": RowState.PENDING, "claims": 0}
            for e in sorted(dict.fromkeys(entries), key=lambda e: e.label) for s in sorted(set(seeds))
            if there is None or (e.label, s) not in there
        ]  # fmt: skip
        for start in range(0, len(rows), INSERT_BATCH):
            yield rows[start : start + INSERT_BATCH]

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

    def held(self, owner: str) -> list[Any]:
        """The rows ``owner`` holds claimed (entry, seed, agent, preset), in seed order: those of its
        jobs, and any of a claim whose reply it never had (the connection lost after the commit)."""
        import sqlalchemy as sa

        statement = (
            sa.select(RUNS.c.entry, RUNS.c.seed, RUNS.c.agent, RUNS.c.preset)
            .where(RUNS.c.comparison == self.name, RUNS.c.owner == owner, RUNS.c.state == RowState.CLAIMED)
            .order_by(RUNS.c.seed, RUNS.c.entry)
        )
        with self.statements.connect() as db:
            return list(db.execute(statement).all())

    def release_rows(self, owner: str, rows: set[tuple[str, int]] | None = None) -> set[tuple[str, int]]:
        """Give back, in one statement, ``owner``'s claims of ``rows`` (entry label, seed), or every
        claim it holds (None): pending again, for any worker. The rows given back."""
        import sqlalchemy as sa

        if rows is not None and not rows:
            return set()
        where = [RUNS.c.comparison == self.name, RUNS.c.owner == owner, RUNS.c.state == RowState.CLAIMED]
        if rows is not None:
            where.append(sa.tuple_(RUNS.c.entry, RUNS.c.seed).in_(sorted(rows)))
        statement = (
            RUNS.update()
            .where(*where)
            .values(state=RowState.PENDING, owner=None, heartbeat=None)
            .returning(RUNS.c.entry, RUNS.c.seed)
        )
        with self.statements.connect() as db:
            return {(row.entry, row.seed) for row in db.execute(statement)}

    def where_now(self, rows: set[tuple[str, int]]) -> dict[tuple[str, int], tuple[str, str | None]]:
        """(state, owner) of each of ``rows`` (entry label, seed) now."""
        import sqlalchemy as sa

        if not rows:
            return {}
        statement = sa.select(RUNS.c.entry, RUNS.c.seed, RUNS.c.state, RUNS.c.owner).where(
            RUNS.c.comparison == self.name, sa.tuple_(RUNS.c.entry, RUNS.c.seed).in_(sorted(rows))
        )
        with self.statements.connect() as db:
            return {(r.entry, r.seed): (r.state, r.owner) for r in db.execute(statement)}

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


def _insert_missing(db: Any, table: Any, rows: list[dict[str, Any]], returning: Any = None) -> list[Any]:
    """Insert the rows whose primary key is not there yet (ON CONFLICT DO NOTHING); with ``returning``
    (a column), that column of each row inserted."""
    if not rows:
        return []
    from sqlalchemy.dialects import postgresql, sqlite

    dialects: dict[str, Any] = {"postgresql": postgresql.insert, "sqlite": sqlite.insert}
    insert = dialects.get(db.dialect.name)
    if insert is None:
        raise ExperimentError(f"a shared comparison needs PostgreSQL (or SQLite), not {db.dialect.name}")
    statement = insert(table).on_conflict_do_nothing()
    if returning is None:
        db.execute(statement, rows)
        return []
    return list(db.execute(statement.values(rows).returning(returning)).scalars())


def missing_table(err: BaseException) -> bool:
    """Whether ``err`` says a table is not there (a database the comparison tables were never made in)."""
    orig = getattr(err, "orig", None)
    return getattr(orig, "sqlstate", None) == "42P01" or "no such table" in str(orig or err)


def ping_when_idle(engine: Any) -> None:
    """Have ``engine``'s pool check a connection before handing it out only where it has been idle for
    :data:`PING_AFTER_IDLE` seconds (SQLAlchemy's ``pool_pre_ping`` checks every time: a round trip
    more for every claim). A connection lost since its last use fails its next statement, which a
    worker's calls try again (:func:`~cartpole.experiments.storage.retry_lost_connection`)."""
    import sqlalchemy as sa

    def checkin(dbapi_connection: Any, record: Any) -> None:
        record.info["idle_since"] = time.monotonic()

    def checkout(dbapi_connection: Any, record: Any, proxy: Any) -> None:
        since = record.info.get("idle_since")
        if since is None or time.monotonic() - since < PING_AFTER_IDLE:
            return
        try:
            alive = engine.dialect.do_ping(dbapi_connection)
        except Exception:
            alive = False
        if not alive:  # the pool then opens a new connection
            raise sa.exc.DisconnectionError("the connection was lost while it was idle")

    sa.event.listen(engine, "checkin", checkin)
    sa.event.listen(engine, "checkout", checkout)


def seed_ranges(seeds: list[int]) -> list[tuple[int, int]]:
    """``seeds`` as (first, last) ranges of consecutive seeds, in order: [0, 1, 2, 5] -> [(0, 2), (5, 5)]."""
    ordered = sorted(set(seeds))
    if ordered and ordered[-1] - ordered[0] == len(ordered) - 1:  # one range (most requests): no loop
        return [(ordered[0], ordered[-1])]
    ranges: list[tuple[int, int]] = []
    for seed in ordered:
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
