"""Claims of a shared comparison (``cartpole compare --storage``) with many workers across a network.

Usage (from the repository root, against a PostgreSQL server; ``source .ci/postgres.sh`` starts one)::

    python benchmarks/claims.py --workers 64 --delay-ms 20 --storage postgresql://USER@HOST:PORT/DB
    python benchmarks/claims.py --workers 1,64 --delay-ms 0,5,20,50 --claim current,legacy \\
        --storage URL --table claims --json claims.json

Each worker is a thread with its own connection, as each machine has its own. Connected (as ``cartpole
compare`` is once it has joined the comparison), the workers start together: each claims, renews its
heartbeat and finishes what it claimed without training, then claims again, for ``--seconds`` (or
until no row is pending), over ``--rows-per-worker`` rows per worker (two entries, as many seeds as
that takes), so that no worker runs dry. A claim that gets nothing waits the look period of
``cartpole compare`` (2 s with the default claim timeout) before it looks again. Every connection goes
through a TCP proxy in a process of its own that delays each byte ``--delay-ms`` each way, as a network
would. The table is analyzed before the workers start, as autovacuum does within a minute of a
comparison's rows being added (before, the planner takes the table for empty: a claim costs the
database about 4x more).

``--claim current`` is :meth:`~cartpole.experiments.shared.SharedComparison.claim`; ``--claim legacy``
is the claim before it (commit 4df9b38), kept here only for contrast: it locks every claimable row of
the comparison (``FOR UPDATE SKIP LOCKED`` without a limit) and picks a chunk in Python, so that while one
worker claims, every other one finds nothing and waits.

The table, a row per (claim, workers, delay): claims per second (claims / time from the start to the
last claim), each worker's wait for its first claim (the largest), the share of worker time spent idle
while rows were pending (from a claim that got nothing, though rows were pending, to the next claim that
got some), and rows claimed twice (the ``claims`` column of the database: every row once, or the claim
is wrong). ``--json FILE`` writes the same figures (an object for one combination, a list for several).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import multiprocessing
import os
import sys
import threading
import time
import uuid
from dataclasses import asdict, dataclass, field
from typing import Any

from table_file import Measurement, Table, add_table_arguments

from cartpole.experiments.entries import Entry
from cartpole.experiments.shared import (
    RUNS,
    Claim,
    RowState,
    SharedComparison,
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


# -- the claim before this one, for contrast ---------------------------------------------------------


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

    first_claim: float | None = None
    claims: int = 0
    rows: int = 0
    last_claim: float = 0.0
    idle: float = 0.0
    """Seconds from a claim that got nothing, while rows were pending, to the next that got some."""
    taken: list[tuple[str, int]] = field(default_factory=list)
    error: str | None = None


class Pool:
    """Rows pending, as the workers see them (none is ever taken over: the claim timeout is long)."""

    def __init__(self, total: int):
        self.total, self.claimed = total, 0
        self.lock = threading.Lock()

    def take(self, count: int) -> None:
        with self.lock:
            self.claimed += count

    def pending(self) -> bool:
        with self.lock:
            return self.claimed < self.total


def simulate_worker(
    url: str,
    name: str,
    claim: Any,
    chunk: int,
    seeds: list[int],
    pool: Pool,
    start: threading.Barrier,
    clock: dict[str, float],
    seconds: float,
    log: WorkerLog,
) -> None:
    """Claim, renew the heartbeat, finish what was claimed; again, until ``deadline`` or no row pending."""
    import sqlalchemy as sa

    engine = SharedComparison.connect(url, create=False)
    shared = SharedComparison(url, name, engine, CLAIM_TIMEOUT, SETUP)
    owner, labels = new_owner(), [e.label for e in ENTRIES]
    batches = {label: True for label in labels}
    with shared.statements.connect() as db:  # connected, as `cartpole compare` is once it has joined
        db.execute(sa.select(1))
    shared.claim_statement(chunk, batches, set(), labels, seeds)  # built ahead, as its SharedRunner does
    start.wait()
    t0 = clock["start"]
    deadline = t0 + seconds
    turned_away: float | None = None
    try:
        while time.monotonic() < deadline and pool.pending():
            asked = time.monotonic() - t0
            found = claim(shared, owner, chunk, batches, set(), labels, seeds)
            if found is None:
                if turned_away is None and pool.pending():
                    turned_away = asked
                time.sleep(max(0.0, min(LOOK_PERIOD, deadline - time.monotonic())))
                continue
            got = time.monotonic() - t0
            pool.take(len(found.seeds))
            if turned_away is not None:
                log.idle += asked - turned_away
                turned_away = None
            if log.first_claim is None:
                log.first_claim = got
            log.claims, log.rows, log.last_claim = log.claims + 1, log.rows + len(found.seeds), got
            log.taken += [(found.entry.label, seed) for seed in found.seeds]
            held = shared.heartbeat(owner)
            assert held == {(found.entry.label, seed) for seed in found.seeds}, (held, found)
            for seed in found.seeds:
                shared.finish(owner, found.entry, seed, RECORD, {})
        if turned_away is not None:
            log.idle += min(time.monotonic(), deadline) - t0 - turned_away
    except Exception as err:  # reported in the table, not lost in a thread
        log.error = f"{type(err).__name__}: {err}"
    finally:
        engine.dispose()


@dataclass
class Result:
    claim: str
    workers: int
    delay_ms: float
    rows: int
    claims: int
    claims_per_s: float
    rows_per_s: float
    first_claim_wait_max_s: float | None
    idle_share: float
    double_claims: int
    workers_without_claim: int
    """Workers that got no claim within the window (their wait: longer than it)."""
    window_s: float
    errors: list[str]


def measure(url: str, claim: str, workers: int, delay_ms: float, args: argparse.Namespace) -> Result:
    """One (claim, workers, delay) combination on a fresh comparison, deleted afterwards."""
    import sqlalchemy as sa
    from sqlalchemy.engine import make_url

    parsed = make_url(url)
    name = f"claims-bench-{uuid.uuid4().hex[:8]}"
    seed_count = -(-args.rows_per_worker * workers // len(ENTRIES))
    seeds = list(range(seed_count))
    shared = SharedComparison.join(url, name, SETUP, ENTRIES, seeds, CLAIM_TIMEOUT)
    with shared.engine.begin() as db:  # as autovacuum does within a minute of the rows' insert
        db.execute(sa.text(f"ANALYZE {RUNS.name}"))
    proxy = DelayProxy((parsed.host or "127.0.0.1", parsed.port or 5432), delay_ms / 1000)
    logs = [WorkerLog() for _ in range(workers)]
    pool = Pool(len(ENTRIES) * seed_count)
    clock: dict[str, float] = {}

    def started() -> None:
        clock["start"] = time.monotonic()

    barrier = threading.Barrier(workers + 1, action=started)
    proxied = through(url, proxy.port)
    threads = [
        threading.Thread(
            target=simulate_worker,
            args=(proxied, name, CLAIMS[claim], args.chunk, seeds, pool, barrier, clock, args.seconds, log),
            daemon=True,
        )
        for log in logs
    ]
    try:
        for thread in threads:
            thread.start()
        barrier.wait()
        for thread in threads:
            thread.join()
        window = min(args.seconds, time.monotonic() - clock["start"])
    finally:
        proxy.close()
    with shared.engine.begin() as db:
        twice = db.execute(
            sa.select(sa.func.count()).where(RUNS.c.comparison == name, RUNS.c.claims > 1)
        ).scalar_one()
        db.execute(RUNS.delete().where(RUNS.c.comparison == name))
    shared.engine.dispose()
    taken = [row for log in logs for row in log.taken]
    claims = sum(log.claims for log in logs)
    span = max((log.last_claim for log in logs), default=0.0) or 1e-9
    firsts = [log.first_claim for log in logs]
    return Result(
        claim=claim,
        workers=workers,
        delay_ms=delay_ms,
        rows=pool.total,
        claims=claims,
        claims_per_s=claims / span,
        rows_per_s=len(taken) / span,
        first_claim_wait_max_s=None if None in firsts else max(f for f in firsts if f is not None),
        idle_share=sum(log.idle for log in logs) / (workers * window),
        double_claims=int(twice) + len(taken) - len(set(taken)),
        workers_without_claim=sum(f is None for f in firsts),
        window_s=window,
        errors=sorted({log.error for log in logs if log.error}),
    )


# -- the table ---------------------------------------------------------------------------------------


def make_table(results: list[Result]) -> Table:
    columns = ["claim", "workers", "delay each way (ms)", "claims", "claims/s", "x one worker",
               "first claim: longest wait (s)", "idle while rows pending", "rows claimed twice"]  # fmt: skip
    alone = {(r.claim, r.delay_ms): r.claims_per_s for r in results if r.workers == 1}
    rows, notes = [], []
    for r in results:
        base = alone.get((r.claim, r.delay_ms))
        if r.workers_without_claim:
            wait = f"> {r.window_s:.1f} ({r.workers_without_claim} of {r.workers} got none)"
        else:
            wait = f"{r.first_claim_wait_max_s:.2f}"
        rows.append([
            r.claim, str(r.workers), f"{r.delay_ms:g}", str(r.claims), f"{r.claims_per_s:,.1f}",
            "-" if base is None or r.workers == 1 else f"{r.claims_per_s / base:.1f}x",
            wait, f"{r.idle_share:.0%}", str(r.double_claims),
        ])  # fmt: skip
        notes += [f"{r.claim}, {r.workers} workers, {r.delay_ms:g} ms: {error}" for error in r.errors]
    for r in results:
        base = alone.get((r.claim, r.delay_ms))
        if r.claim == "current" and r.workers == 64 and r.delay_ms == 20 and base:
            met = (
                r.first_claim_wait_max_s is not None
                and r.first_claim_wait_max_s <= 1.0
                and r.double_claims == 0
                and r.claims_per_s >= 10 * base
            )
            notes.append(
                f"Target (64 workers, 20 ms each way: every first claim within 1 s, no row claimed twice, "
                f"claims/s at least 10x one worker's): {'met' if met else 'NOT met'}."
            )
    return Table(columns, rows, summary={"results": [asdict(r) for r in results]}, results=None, notes=notes)


def numbers(text: str, kind: type) -> list[Any]:
    try:
        return [kind(part) for part in text.split(",") if part]
    except ValueError:
        raise SystemExit(f"error: {text!r} is not a comma-separated list of numbers") from None


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workers", default="64", help="simulated workers, e.g. 64 or 1,64")
    parser.add_argument("--delay-ms", default="20", help="added delay each way in ms, e.g. 20 or 0,5,20,50")
    parser.add_argument(
        "--storage",
        default=os.environ.get("CARTPOLE_TEST_POSTGRES_URL"),
        help="postgresql://USER@HOST:PORT/DB (default: $CARTPOLE_TEST_POSTGRES_URL, which "
        ".ci/postgres.sh sets)",
    )
    parser.add_argument("--claim", default="current", help="current, legacy (the claim at 4df9b38), or both")
    parser.add_argument("--chunk", type=int, default=1, help="--chunk of cartpole compare")
    parser.add_argument("--rows-per-worker", type=int, default=40, help="rows per worker (>= 20)")
    parser.add_argument("--seconds", type=float, default=3.0, help="each combination's window")
    parser.add_argument("--json", metavar="FILE", help="also write the figures as JSON to FILE")
    add_table_arguments(parser)
    args = parser.parse_args(argv)
    claims = [c for c in args.claim.split(",") if c]
    if not claims or any(c not in CLAIMS for c in claims):
        raise SystemExit(f"error: --claim takes {', '.join(CLAIMS)} (comma-separated), not {args.claim!r}")
    if not args.storage:
        raise SystemExit("error: name a PostgreSQL server: --storage URL (or source .ci/postgres.sh)")
    if not args.storage.startswith("postgresql"):
        raise SystemExit("error: --storage must be a postgresql:// URL (the proxy delays a TCP connection)")
    if args.rows_per_worker < 20:
        raise SystemExit("error: --rows-per-worker must be >= 20, so that no worker runs dry")
    measurement = Measurement(args, [sys.argv[0], *(argv if argv is not None else sys.argv[1:])])
    results = []
    for claim in claims:
        for delay in numbers(args.delay_ms, float):
            for workers in numbers(args.workers, int):
                result = measure(args.storage, claim, workers, delay, args)
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
