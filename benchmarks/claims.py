"""Joins and claims of a shared comparison (``cartpole compare --storage``) with many workers across a
network.

Usage (from the repository root, against a PostgreSQL server; ``source .ci/postgres.sh`` starts one)::

    python benchmarks/claims.py --workers 64 --delay-ms 20 --storage postgresql://USER@HOST:PORT/DB
    python benchmarks/claims.py --workers 1,64,256 --delay-ms 20 --join current,legacy \\
        --storage URL --table claims --json claims.json

Each worker is a thread with its own engine and connection, as each machine has its own. The workers
start together, as the tasks of a job array that Slurm starts at one moment: each worker's clock starts
before it connects and joins a comparison that is not there yet (every worker asks for the same entries
and seeds, so that the first to get there makes the comparison and the others join it), then it builds
its claim statement and claims once, as a task that then trains for a while. Once every worker holds
its first claim, the throughput phase: each renews its heartbeat and finishes what it claimed without
training, and claims again, for ``--seconds`` (or until no row is pending), over ``--rows-per-worker``
rows per worker (two entries, as many seeds as that takes), so that no worker runs dry. A claim that
gets nothing waits the look period of ``cartpole compare`` (2 s with the default claim timeout) before it
looks again. Every connection goes through a TCP proxy in a process of its own that delays each byte
``--delay-ms`` each way, as a network would. Before the workers start, a comparison of the same size is
made, the table analyzed and that comparison deleted, so that the planner knows the table's size, as in
a database in use (autovacuum analyzes a table within a minute of its rows being added; on a table
never analyzed a claim costs the database about 4x more).

``--join current`` is :meth:`~cartpole.experiments.shared.SharedComparison.join`; ``--join legacy`` is the
join before it (commit 09036a6), kept here only for contrast: it holds the comparison's row locked
(``SELECT ... FOR UPDATE``) while it inserts every row, so that the workers join one after the other.
``--claim current`` is :meth:`~cartpole.experiments.shared.SharedComparison.claim`; ``--claim legacy``
is the claim before it (commit 4df9b38), also for contrast: it locks every claimable row of the
comparison (``FOR UPDATE SKIP LOCKED`` without a limit) and picks a chunk in Python, so that while one
worker claims, every other one finds nothing and waits.

The table, a row per (join, claim, workers, delay): each worker's join (connect and join: median and
longest), its first claim from its start (the longest: what a task of a job array waits before it
trains), then for the throughput phase claims per second, the share of worker time spent idle while rows
were pending (from a claim that got nothing, though rows were pending, to the next claim that got some),
and rows claimed twice (the ``claims`` column of the database: every row once, or the claim is wrong).
``--json FILE`` writes the same figures (an object for one combination, a list for several):
``join_median_s``, ``join_max_s``, ``first_claim_from_start_max_s`` (from the start, its join included)
and ``first_claim_wait_max_s`` (from the worker's join to its first claim).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import multiprocessing
import os
import statistics
import sys
import threading
import time
import uuid
from dataclasses import asdict, dataclass, field
from typing import Any

from table_file import Measurement, Table, add_table_arguments

from cartpole.experiments.entries import Entry
from cartpole.experiments.shared import (
    COMPARISONS,
    RUNS,
    Claim,
    RowState,
    SharedComparison,
    _insert_missing,
    check_returning,
    check_setup,
    new_owner,
)

ENTRIES = [Entry("cem"), Entry("random-search")]
SETUP = {"env_id": "CartPole-v1", "budget": "1gen", "benchmark": "claims"}
CLAIM_TIMEOUT = 120.0
LOOK_PERIOD = min(2.0, min(30.0, CLAIM_TIMEOUT / 4))
"""What ``cartpole compare`` waits after a claim that got nothing (its SharedRunner's look period)."""
RECORD = {"simulated": True}


# -- a network's delay: a TCP proxy ------------------------------------------------------------------


async def _pipe(reader: asyncio.StreamReader, writer: asyncio.StreamWriter, delay: float) -> None:
    """Copy ``reader`` to ``writer``, each chunk ``delay`` seconds late (latency, not bandwidth: a chunk
    read while another waits is not held up by it)."""
    queue: asyncio.Queue[tuple[float, bytes]] = asyncio.Queue()
    loop = asyncio.get_running_loop()

    async def send() -> None:
        while True:
            due, data = await queue.get()
            if not data:
                break
            await asyncio.sleep(max(0.0, due - loop.time()))
            writer.write(data)
            await writer.drain()
        writer.close()

    sender = asyncio.ensure_future(send())
    try:
        while data := await reader.read(65536):
            queue.put_nowait((loop.time() + delay, data))
    except ConnectionError:
        pass
    queue.put_nowait((loop.time() + delay, b""))
    await sender


async def _serve(target: tuple[str, int], delay: float, ready: Any) -> None:
    async def handle(client_reader: asyncio.StreamReader, client_writer: asyncio.StreamWriter) -> None:
        try:
            server_reader, server_writer = await asyncio.open_connection(*target)
        except OSError:
            client_writer.close()
            return
        await asyncio.gather(
            _pipe(client_reader, server_writer, delay),
            _pipe(server_reader, client_writer, delay),
            return_exceptions=True,
        )

    server = await asyncio.start_server(handle, "127.0.0.1", 0, backlog=1024)
    ready.send(server.sockets[0].getsockname()[1])
    async with server:
        await server.serve_forever()


def _proxy_process(target: tuple[str, int], delay: float, ready: Any) -> None:
    asyncio.run(_serve(target, delay, ready))


class DelayProxy:
    """A TCP proxy on 127.0.0.1 to ``target``, ``delay`` seconds each way, in a process of its own (so
    that the workers' threads do not slow it)."""

    def __init__(self, target: tuple[str, int], delay: float):
        receive, send = multiprocessing.Pipe(duplex=False)
        self.process = multiprocessing.Process(target=_proxy_process, args=(target, delay, send), daemon=True)
        self.process.start()
        self.port = int(receive.recv())

    def close(self) -> None:
        self.process.terminate()
        self.process.join()


def through(url: str, port: int) -> str:
    """``url`` with its host and port those of the proxy."""
    from sqlalchemy.engine import make_url

    return make_url(url).set(host="127.0.0.1", port=port).render_as_string(hide_password=False)


# -- the join and the claim before these, for contrast -----------------------------------------------


def legacy_join(
    url: str, name: str, setup: dict[str, Any], entries: list[Entry], seeds: list[int], claim_timeout: float
) -> SharedComparison:
    """``SharedComparison.join`` at commit 09036a6: the comparison's row locked while every row is
    inserted, so that joins queue."""
    engine = SharedComparison.connect(url)
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
            db.execute(COMPARISONS.update().where(COMPARISONS.c.name == name).values(entries=known + added))
        _insert_missing(db, RUNS, [
            {"comparison": name, "entry": e.label, "seed": s, "agent": e.agent, "preset": e.preset,
             "state": RowState.PENDING, "claims": 0}
            for s in seeds for e in entries
        ])  # fmt: skip
    return SharedComparison(url, name, engine, float(row.claim_timeout), setup)


JOINS = {"current": SharedComparison.join, "legacy": legacy_join}


def legacy_claim(
    shared: SharedComparison,
    owner: str,
    chunk: int,
    batches: dict[str, bool],
    skip: set[tuple[str, int]],
    labels: list[str],
    seeds: list[int],
) -> Claim | None:
    """``SharedComparison.claim`` at commit 4df9b38: every claimable row locked, a chunk picked here."""
    import sqlalchemy as sa

    with shared.engine.begin() as db:
        now = float(db.execute(sa.select(sa.func.extract("epoch", sa.func.clock_timestamp()))).scalar_one())
        claimable = sa.and_(
            RUNS.c.comparison == shared.name,
            RUNS.c.entry.in_(labels),
            RUNS.c.seed.in_(seeds),
            sa.or_(
                RUNS.c.state == RowState.PENDING,
                sa.and_(RUNS.c.state == RowState.CLAIMED, RUNS.c.heartbeat < now - shared.claim_timeout),
            ),
        )
        rows = db.execute(
            sa.select(RUNS.c.entry, RUNS.c.seed, RUNS.c.agent, RUNS.c.preset)
            .where(claimable)
            .order_by(RUNS.c.seed, RUNS.c.entry)
            .with_for_update(skip_locked=True)
        ).all()
        rows = [r for r in rows if (r.entry, r.seed) not in skip]
        if not rows:
            return None
        first = rows[0]
        size = chunk if batches.get(first.entry, False) else 1
        taken = [r.seed for r in rows if r.entry == first.entry][:size]
        db.execute(
            RUNS.update()
            .where(RUNS.c.comparison == shared.name, RUNS.c.entry == first.entry, RUNS.c.seed.in_(taken))
            .values(state=RowState.CLAIMED, owner=owner, heartbeat=now, claims=RUNS.c.claims + 1)
        )
    return Claim(Entry(first.agent, first.preset), taken)


def current_claim(
    shared: SharedComparison,
    owner: str,
    chunk: int,
    batches: dict[str, bool],
    skip: set[tuple[str, int]],
    labels: list[str],
    seeds: list[int],
) -> Claim | None:
    return shared.claim(owner, chunk, batches, skip, labels, seeds)


CLAIMS = {"current": current_claim, "legacy": legacy_claim}


# -- the simulated workers ---------------------------------------------------------------------------


@dataclass
class WorkerLog:
    """What one simulated worker did, in seconds since the common start."""

    joined: float | None = None
    """When its join ended (connected, the comparison and its rows there)."""
    first_claim: float | None = None
    claims: int = 0
    """Claims of the throughput phase (its times from that phase's start, as ``last_claim``)."""
    rows: int = 0
    last_claim: float = 0.0
    idle: float = 0.0
    """Seconds from a claim that got nothing, while rows were pending, to the next that got some."""
    throughput_start: float | None = None
    """When its throughput phase began (``time.monotonic``, one clock for every process)."""
    taken: list[tuple[str, int]] = field(default_factory=list)
    error: str | None = None


class Pool:
    """Rows pending, as the workers of every process see them (none is ever taken over: the claim
    timeout is long)."""

    def __init__(self, total: int, claimed: Any):
        self.total, self.claimed = total, claimed
        """``claimed``: a ``multiprocessing.Value`` shared by the processes."""

    def take(self, count: int) -> None:
        with self.claimed.get_lock():
            self.claimed.value += count

    def pending(self) -> bool:
        return bool(self.claimed.value < self.total)


@dataclass(frozen=True)
class Plan:
    """What every simulated worker of one combination does."""

    url: str
    name: str
    join: Any
    claim: Any
    chunk: int
    seeds: list[int]
    seconds: float


FIRST_CLAIM_LIMIT = 300.0
"""Seconds a simulated worker tries for its first claim before it gives up (an error in the table)."""
BARRIER_SECONDS = 900.0
"""The longest wait at a barrier (a process lost: the combination ends with an error)."""


def run_share(
    plan: Plan, count: int, total: int, claimed: Any, barriers: tuple[Any, Any], clock: Any, out: Any
) -> None:
    """In a process of its own: ``count`` simulated workers, a thread each; their logs to ``out``."""
    pool = Pool(total, claimed)
    logs = [WorkerLog() for _ in range(count)]
    threads = [
        threading.Thread(target=simulate_worker, args=(plan, pool, barriers, clock, log), daemon=True)
        for log in logs
    ]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    out.put([asdict(log) for log in logs])


def simulate_worker(plan: Plan, pool: Pool, barriers: tuple[Any, Any], clock: Any, log: WorkerLog) -> None:
    """From the common start: join and claim once, as a task of a job array that then trains for a
    while. Once every worker holds its first claim (the second barrier), the throughput phase: renew
    the heartbeat, finish what was claimed, claim again, for ``plan.seconds`` or until no row is
    pending."""
    start, all_claimed = barriers
    shared: SharedComparison | None = None
    start.wait(timeout=BARRIER_SECONDS)
    t0 = clock.value  # the common start, set just before the last party came
    try:
        shared = plan.join(plan.url, plan.name, SETUP, ENTRIES, plan.seeds, CLAIM_TIMEOUT)
        owner, labels = new_owner(), [e.label for e in ENTRIES]
        batches = {label: True for label in labels}
        shared.claim_statement(plan.chunk, batches, set(), labels, plan.seeds)  # as its SharedRunner does
        log.joined = time.monotonic() - t0

        def claim() -> Claim | None:
            found = plan.claim(shared, owner, plan.chunk, batches, set(), labels, plan.seeds)
            if found is not None:
                pool.take(len(found.seeds))
                log.taken.extend((found.entry.label, seed) for seed in found.seeds)
            return found

        found = claim()
        while found is None:  # as `cartpole compare` looks again after its look period
            if time.monotonic() - t0 > FIRST_CLAIM_LIMIT:
                raise TimeoutError(f"no first claim within {FIRST_CLAIM_LIMIT:g} s")
            time.sleep(LOOK_PERIOD)
            found = claim()
        log.first_claim = time.monotonic() - t0
        all_claimed.wait(timeout=BARRIER_SECONDS)
        t1 = time.monotonic()
        log.throughput_start = t1
        deadline = t1 + plan.seconds
        turned_away: float | None = None
        while True:
            held = shared.heartbeat(owner)
            assert held == {(found.entry.label, seed) for seed in found.seeds}, (held, found)
            for seed in found.seeds:
                shared.finish(owner, found.entry, seed, RECORD, {})
            found = None
            while found is None and time.monotonic() < deadline and pool.pending():
                asked = time.monotonic() - t1
                found = claim()
                if found is None:
                    if turned_away is None and pool.pending():
                        turned_away = asked
                    time.sleep(max(0.0, min(LOOK_PERIOD, deadline - time.monotonic())))
            if found is None:
                break
            got = time.monotonic() - t1
            if turned_away is not None:
                log.idle += got - turned_away
                turned_away = None
            log.claims, log.rows, log.last_claim = log.claims + 1, log.rows + len(found.seeds), got
        if turned_away is not None:
            log.idle += min(time.monotonic(), deadline) - t1 - turned_away
    except Exception as err:  # reported in the table, not lost in a thread
        log.error = f"{type(err).__name__}: {err}"
        all_claimed.abort()  # the others go on without this one
    except threading.BrokenBarrierError:
        pass  # another worker failed: its error is in the table
    finally:
        if shared is not None:
            shared.engine.dispose()


@dataclass
class Result:
    join: str
    claim: str
    workers: int
    delay_ms: float
    rows: int
    claims: int
    claims_per_s: float
    rows_per_s: float
    join_median_s: float | None
    join_max_s: float | None
    first_claim_from_start_max_s: float | None
    """The longest time from a worker's start (before it connects and joins) to its first claim."""
    first_claim_wait_max_s: float | None
    """The longest time from a worker's join to its first claim."""
    idle_share: float
    double_claims: int
    workers_without_claim: int
    """Workers that got no first claim (within :data:`FIRST_CLAIM_LIMIT`)."""
    window_s: float
    """The throughput phase: from the moment every worker held its first claim to the last one's end."""
    errors: list[str]


def warm_up(url: str, rows: int) -> None:
    """Make and delete a comparison of ``rows`` rows, the table analyzed in between: the planner then
    knows the table's size, as autovacuum would have told it in a database in use."""
    import sqlalchemy as sa

    name = f"claims-bench-warm-{uuid.uuid4().hex[:8]}"
    seeds = list(range(-(-rows // len(ENTRIES))))
    shared = SharedComparison.join(url, name, SETUP, ENTRIES, seeds, CLAIM_TIMEOUT)
    with shared.engine.begin() as db:
        db.execute(sa.text(f"ANALYZE {RUNS.name}"))
        db.execute(RUNS.delete().where(RUNS.c.comparison == name))
        db.execute(COMPARISONS.delete().where(COMPARISONS.c.name == name))
    shared.engine.dispose()


def check_connections(url: str, workers: int) -> None:
    """SystemExit, in one line, where the server takes fewer connections than the workers need."""
    import sqlalchemy as sa

    engine = SharedComparison.connect(url, create=False)
    with engine.connect() as db:
        allowed = int(db.execute(sa.text("SHOW max_connections")).scalar_one())
    engine.dispose()
    if allowed < workers + 10:
        raise SystemExit(
            f"error: the server takes {allowed} connections (max_connections) and {workers} workers need "
            f"{workers + 10}: start it with -c max_connections={workers + 50} (.ci/postgres.sh does 400)"
        )


def measure(
    url: str, join: str, claim: str, workers: int, delay_ms: float, args: argparse.Namespace
) -> Result:
    """One (join, claim, workers, delay) combination on a fresh comparison, deleted afterwards."""
    import sqlalchemy as sa
    from sqlalchemy.engine import make_url

    parsed = make_url(url)
    name = f"claims-bench-{uuid.uuid4().hex[:8]}"
    seed_count = -(-args.rows_per_worker * workers // len(ENTRIES))
    seeds = list(range(seed_count))
    warm_up(url, len(ENTRIES) * seed_count)
    proxy = DelayProxy((parsed.host or "127.0.0.1", parsed.port or 5432), delay_ms / 1000)
    context = multiprocessing.get_context("spawn")
    claimed, clock = context.Value("q", 0), context.Value("d", 0.0)
    start, all_claimed = context.Barrier(workers + 1), context.Barrier(workers)
    out = context.Queue()
    plan = Plan(through(url, proxy.port), name, JOINS[join], CLAIMS[claim], args.chunk, seeds, args.seconds)
    processes = min(args.processes, workers)
    shares = [workers // processes + (i < workers % processes) for i in range(processes)]
    children = [
        context.Process(
            target=run_share,
            args=(plan, count, len(ENTRIES) * seed_count, claimed, (start, all_claimed), clock, out),
            daemon=True,
        )
        for count in shares
    ]
    logs: list[WorkerLog] = []
    try:
        for child in children:
            child.start()
        deadline = time.monotonic() + BARRIER_SECONDS
        while start.n_waiting < workers:  # every worker connected nothing yet and waits
            if time.monotonic() > deadline or not all(child.is_alive() for child in children):
                raise SystemExit("error: a process of simulated workers did not start")
            time.sleep(0.05)
        clock.value = time.monotonic()
        start.wait(timeout=BARRIER_SECONDS)
        for _ in children:
            found = out.get(timeout=BARRIER_SECONDS)
            logs += [WorkerLog(**{**log, "taken": [tuple(row) for row in log["taken"]]}) for log in found]
        for child in children:
            child.join()
        starts = [log.throughput_start for log in logs if log.throughput_start is not None]
        window = time.monotonic() - (min(starts) if starts else clock.value)
    finally:
        for child in children:
            if child.is_alive():
                child.terminate()
        proxy.close()
    pool = Pool(len(ENTRIES) * seed_count, claimed)
    engine = SharedComparison.connect(url, create=False)
    with engine.begin() as db:
        twice = db.execute(
            sa.select(sa.func.count()).where(RUNS.c.comparison == name, RUNS.c.claims > 1)
        ).scalar_one()
        rows = db.execute(sa.select(sa.func.count()).where(RUNS.c.comparison == name)).scalar_one()
        db.execute(RUNS.delete().where(RUNS.c.comparison == name))
        db.execute(COMPARISONS.delete().where(COMPARISONS.c.name == name))
    engine.dispose()
    taken = [row for log in logs for row in log.taken]
    claims = sum(log.claims for log in logs)
    joins = sorted(log.joined for log in logs if log.joined is not None)
    firsts = [log.first_claim for log in logs]
    span = max((log.last_claim for log in logs), default=0.0)
    errors = sorted({log.error for log in logs if log.error})
    if rows != len(ENTRIES) * seed_count:
        errors.append(f"the comparison holds {rows} rows, not {len(ENTRIES) * seed_count}")
    return Result(
        join=join,
        claim=claim,
        workers=workers,
        delay_ms=delay_ms,
        rows=pool.total,
        claims=claims,
        claims_per_s=claims / max(span, 1e-9),
        rows_per_s=sum(log.rows for log in logs) / max(span, 1e-9),
        join_median_s=statistics.median(joins) if joins else None,
        join_max_s=joins[-1] if len(joins) == workers else None,
        first_claim_from_start_max_s=None if None in firsts else max(f for f in firsts if f is not None),
        first_claim_wait_max_s=None
        if None in firsts
        else max(
            log.first_claim - log.joined
            for log in logs
            if log.first_claim is not None and log.joined is not None
        ),
        idle_share=sum(log.idle for log in logs) / (workers * window),
        double_claims=int(twice) + len(taken) - len(set(taken)),
        workers_without_claim=sum(f is None for f in firsts),
        window_s=window,
        errors=errors,
    )


# -- the table ---------------------------------------------------------------------------------------

TARGETS = {64: 2.0, 256: 5.0}
"""Workers -> seconds within which each must hold its first claim from its start, 20 ms each way."""


def make_table(results: list[Result]) -> Table:
    columns = ["join", "claim", "workers", "delay each way (ms)", "join: median, longest (s)",
               "first claim from start: longest (s)", "claims", "claims/s", "x one worker",
               "idle while rows pending", "rows claimed twice"]  # fmt: skip
    alone = {(r.join, r.claim, r.delay_ms): r.claims_per_s for r in results if r.workers == 1}
    rows, notes = [], []
    for r in results:
        base = alone.get((r.join, r.claim, r.delay_ms))
        if r.workers_without_claim:
            first = f"- ({r.workers_without_claim} of {r.workers} got none)"
        else:
            first = f"{r.first_claim_from_start_max_s:.2f}"
        joined = (
            "-"
            if r.join_median_s is None
            else f"{r.join_median_s:.2f}, " + ("-" if r.join_max_s is None else f"{r.join_max_s:.2f}")
        )
        rows.append([
            r.join, r.claim, str(r.workers), f"{r.delay_ms:g}", joined, first, str(r.claims),
            f"{r.claims_per_s:,.1f}",
            "-" if base is None or r.workers == 1 else f"{r.claims_per_s / base:.1f}x",
            f"{r.idle_share:.0%}", str(r.double_claims),
        ])  # fmt: skip
        notes += [
            f"{r.join} join, {r.claim} claim, {r.workers} workers, {r.delay_ms:g} ms: {e}" for e in r.errors
        ]
    for r in results:
        limit = TARGETS.get(r.workers)
        if r.join == r.claim == "current" and limit is not None and r.delay_ms == 20:
            met = (
                r.first_claim_from_start_max_s is not None
                and r.first_claim_from_start_max_s <= limit
                and r.double_claims == 0
                and not r.errors
            )
            notes.append(
                f"Target ({r.workers} workers joining at one moment, 20 ms each way: each holds a claim "
                f"within {limit:g} s of its start, no row claimed twice): {'met' if met else 'NOT met'}."
            )
    return Table(columns, rows, summary={"results": [asdict(r) for r in results]}, results=None, notes=notes)


def numbers(text: str, kind: type) -> list[Any]:
    try:
        return [kind(part) for part in text.split(",") if part]
    except ValueError:
        raise SystemExit(f"error: {text!r} is not a comma-separated list of numbers") from None


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workers", default="64", help="simulated workers, e.g. 64 or 1,64,256")
    parser.add_argument("--delay-ms", default="20", help="added delay each way in ms, e.g. 20 or 0,5,20,50")
    parser.add_argument(
        "--storage",
        default=os.environ.get("CARTPOLE_TEST_POSTGRES_URL"),
        help="postgresql://USER@HOST:PORT/DB (default: $CARTPOLE_TEST_POSTGRES_URL, which "
        ".ci/postgres.sh sets)",
    )
    parser.add_argument("--join", default="current", help="current, legacy (the join at 09036a6), or both")
    parser.add_argument("--claim", default="current", help="current, legacy (the claim at 4df9b38), or both")
    parser.add_argument("--chunk", type=int, default=1, help="--chunk of cartpole compare")
    parser.add_argument("--rows-per-worker", type=int, default=40, help="rows per worker (>= 20)")
    parser.add_argument(
        "--seconds", type=float, default=3.0, help="the throughput phase, once every worker holds a claim"
    )
    parser.add_argument(
        "--processes",
        type=int,
        default=os.cpu_count() or 1,
        help="processes the simulated workers are spread over, each a thread per worker (default: one "
        "per CPU, so that they do not queue for one Python's lock as machines would not)",
    )
    parser.add_argument("--json", metavar="FILE", help="also write the figures as JSON to FILE")
    add_table_arguments(parser)
    args = parser.parse_args(argv)
    joins, claims = [j for j in args.join.split(",") if j], [c for c in args.claim.split(",") if c]
    if not joins or any(j not in JOINS for j in joins):
        raise SystemExit(f"error: --join takes {', '.join(JOINS)} (comma-separated), not {args.join!r}")
    if not claims or any(c not in CLAIMS for c in claims):
        raise SystemExit(f"error: --claim takes {', '.join(CLAIMS)} (comma-separated), not {args.claim!r}")
    if not args.storage:
        raise SystemExit("error: name a PostgreSQL server: --storage URL (or source .ci/postgres.sh)")
    if not args.storage.startswith("postgresql"):
        raise SystemExit("error: --storage must be a postgresql:// URL (the proxy delays a TCP connection)")
    if args.rows_per_worker < 20:
        raise SystemExit("error: --rows-per-worker must be >= 20, so that no worker runs dry")
    workers = numbers(args.workers, int)
    check_connections(args.storage, max(workers, default=1))
    measurement = Measurement(args, [sys.argv[0], *(argv if argv is not None else sys.argv[1:])])
    results = []
    for join in joins:
        for claim in claims:
            for delay in numbers(args.delay_ms, float):
                for count in workers:
                    result = measure(args.storage, join, claim, count, delay, args)
                    print(json.dumps(asdict(result)), flush=True)
                    results.append(result)
    table = make_table(results)
    print(table.markdown())
    measurement.finish(table)
    if args.json:
        found = [asdict(r) for r in results]
        with open(args.json, "w", encoding="utf-8") as out:
            json.dump(found[0] if len(found) == 1 else found, out, indent=1)
    return 1 if any(r.errors or r.double_claims for r in results) else 0


if __name__ == "__main__":
    sys.exit(main())
