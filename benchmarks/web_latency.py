"""Web app latency on localhost: play round-trips and the episode API, printed as a table.

    python benchmarks/web_latency.py [--steps 2000] [--sessions 1 20] [--episodes 30] [--watch-load 4]

Starts `cartpole serve` on 127.0.0.1 (a free port) in a subprocess, on a temporary runs folder with a
small DQN run and a CEM run trained for the purpose. Play: each session resets, then sends a step
message every --pace-ms (10 ms = a human playing at 2x speed), timing each from send to reply (the
key message to new state round-trip), all sessions concurrently. Episode API: 500-step episodes
(or as long as the policy lasts) of a DQN and a linear checkpoint, timed over HTTP. Targets from
issue 6: play p99 <= 5 ms with 20 sessions, episode <= 50 ms. With --watch-load K the play sessions
are timed twice more while K Watch clients ask for episodes (a new seed each): first as the Watch page
does (an episode, then its replay at 50 frames per second before the next: a viewer who clicks "new
start" at every end), then back to back (a stress: the episode worker never rests). Issue 16's
target: play p99 <= 5 ms with 20 sessions and 4 watch clients. Everything is bounded: it stops by
itself. Run it on an otherwise idle machine: the clients share its CPUs with the server.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import httpx
import numpy as np
import websockets
from cpu import describe_cpu
from table_file import Measurement, Table, add_table_arguments

from cartpole.runs import RunDir
from cartpole.training import train


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start_server(runs_dir: Path) -> tuple[subprocess.Popen[bytes], str]:
    """`cartpole serve` in its own process (so the clients here do not share its GIL)."""
    port = free_port()
    command = [sys.executable, "-m", "cartpole", "serve", "--runs-dir", str(runs_dir), "--port", str(port)]
    server = subprocess.Popen(command, stdout=subprocess.DEVNULL)
    address = f"127.0.0.1:{port}"
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        try:
            httpx.get(f"http://{address}/api/info", timeout=1).raise_for_status()
            time.sleep(3)  # let the app's warm-up (imports, compiled kernels) finish
            return server, address
        except httpx.HTTPError:
            time.sleep(0.2)
    server.kill()
    raise RuntimeError("cartpole serve did not answer within 60 s")


def percentile(values: list[float], q: float) -> float:
    return float(np.percentile(np.asarray(values), q))


async def play_session(address: str, steps: int, seed: int, pace_ms: float) -> list[float]:
    """Round-trip times (ms) of ``steps`` step messages, one every ``pace_ms`` (0: back to back),
    resetting whenever an episode ends."""
    times: list[float] = []
    next_at = time.perf_counter()
    async with websockets.connect(f"ws://{address}/ws/play") as ws:
        await ws.send(json.dumps({"type": "reset", "seed": seed}))
        await ws.recv()
        action = 0
        for _ in range(steps):
            next_at += pace_ms / 1000
            start = time.perf_counter()
            await ws.send(json.dumps({"type": "step", "action": action}))
            reply = json.loads(await ws.recv())
            times.append((time.perf_counter() - start) * 1000)
            action = 1 - action  # alternate: long episodes, like a human wiggling
            if reply["terminated"] or reply["truncated"]:
                await ws.send(json.dumps({"type": "reset"}))
                await ws.recv()
            await asyncio.sleep(max(0.0, next_at - time.perf_counter()))
    return times


async def play_benchmark(address: str, sessions: int, steps: int, pace_ms: float) -> list[float]:
    plays = (play_session(address, steps, seed, pace_ms) for seed in range(sessions))
    results = await asyncio.gather(*plays)
    return [t for r in results for t in r]


WATCH_FPS = 50
"""Frames per second of the Watch page's replay (watch.js)."""


async def watch_client(
    address: str, run: str, first_seed: int, stop: asyncio.Event, as_the_page: bool
) -> list[float]:
    """Episode requests until ``stop``, each followed by its replay's duration (``as_the_page``) or
    by the next at once; the time of each request (ms)."""
    url = f"http://{address}/api/runs/{run}/checkpoints/best/episode"
    times: list[float] = []
    seed = first_seed
    async with httpx.AsyncClient(timeout=60) as client:
        while not stop.is_set():
            start = time.perf_counter()
            response = await client.get(url, params={"seed": seed})
            response.raise_for_status()
            times.append((time.perf_counter() - start) * 1000)
            seed += 1
            if as_the_page:
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(stop.wait(), response.json()["length"] / WATCH_FPS)
    return times


async def play_under_watch_load(
    address: str, sessions: int, steps: int, pace_ms: float, run: str, watchers: int, as_the_page: bool
) -> tuple[list[float], list[float]]:
    """Play round-trips while ``watchers`` clients ask for episodes of ``run``; (play ms, episode ms)."""
    stop = asyncio.Event()
    watches = [
        asyncio.create_task(watch_client(address, run, 1000 * i, stop, as_the_page)) for i in range(watchers)
    ]
    await asyncio.sleep(1.0)  # the watch load is on before the first step is timed
    try:
        plays = await play_benchmark(address, sessions, steps, pace_ms)
    finally:
        stop.set()
        episodes = await asyncio.gather(*watches)
    return plays, [t for w in episodes for t in w]


def episode_benchmark(address: str, run: str, checkpoint: str, episodes: int) -> tuple[list[float], str]:
    """Milliseconds per episode request (after one warm-up), and the episode lengths seen."""
    url = f"http://{address}/api/runs/{run}/checkpoints/{checkpoint}/episode"
    times, lengths = [], []
    with httpx.Client(timeout=30) as client:
        client.get(url, params={"seed": 0}).raise_for_status()  # load and cache the policy
        for seed in range(episodes):
            start = time.perf_counter()
            response = client.get(url, params={"seed": seed})
            response.raise_for_status()
            times.append((time.perf_counter() - start) * 1000)
            lengths.append(response.json()["length"])
    low, high = min(lengths), max(lengths)
    return times, f"{high}" if low == high else f"{low}-{high}"


def make_runs(runs_dir: Path) -> tuple[str, str]:
    """A solved DQN run and a solved CEM run (about 10 s together): their best checkpoints play
    500-step episodes, the longest the API serves for CartPole-v1."""
    dqn = train("dqn", "CartPole-v1", seed=0, runs_dir=runs_dir, quiet=True).run.name
    cem = train("cem", "CartPole-v1", seed=0, runs_dir=runs_dir, quiet=True).run.name
    return dqn, cem


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=2000, help="step messages per play session")
    parser.add_argument("--sessions", type=int, nargs="+", default=[1, 20], help="concurrent sessions")
    parser.add_argument("--episodes", type=int, default=30, help="episode requests per checkpoint")
    parser.add_argument(
        "--watch-load",
        type=int,
        default=0,
        metavar="K",
        help="also time the largest --sessions while K clients ask for episodes back to back (default: 0)",
    )
    parser.add_argument(
        "--pace-ms",
        type=float,
        default=10.0,
        help="ms between a session's steps: 20 is real time, 10 (default) is 2x, 0 is back to back",
    )
    add_table_arguments(parser)
    args = parser.parse_args()
    measurement = Measurement(args)

    with tempfile.TemporaryDirectory() as tmp:
        runs_dir = Path(tmp)
        dqn, cem = make_runs(runs_dir)
        server, address = start_server(runs_dir)
        try:
            rows = []
            asyncio.run(play_benchmark(address, 1, 200, 0.0))  # warm-up
            for n in args.sessions:
                times = asyncio.run(play_benchmark(address, n, args.steps, args.pace_ms))
                name = f"play round-trip, {n} session(s)"
                rows.append((name, len(times), times, 5.0 if n >= 20 else None))
            n, k = max(args.sessions), args.watch_load
            for as_the_page, how in ((True, "watching"), (False, "back to back")) if k else ():
                plays, episodes = asyncio.run(
                    play_under_watch_load(address, n, args.steps, args.pace_ms, dqn, k, as_the_page)
                )
                rows.append((f"play, {n} sessions + {k} {how}", len(plays), plays, 5.0 if n >= 20 else None))
                rows.append(("  episodes served meanwhile (dqn)", len(episodes), episodes, None))
            for run, label in ((dqn, "dqn"), (cem, "cem (linear)")):
                checkpoints = RunDir(runs_dir / run).checkpoints()
                checkpoint = "best" if "best" in checkpoints else checkpoints[0]
                times, lengths = episode_benchmark(address, run, checkpoint, args.episodes)
                rows.append((f"episode API, {label}, {lengths} steps", len(times), times, 50.0))
        finally:
            server.terminate()
            server.wait(timeout=10)
    table = table_of(rows, args.pace_ms)
    print(f"cartpole web latency on {describe_cpu()}, localhost")
    print(table.markdown())
    measurement.finish(table)


def table_of(rows: list[tuple[str, int, list[float], float | None]], pace_ms: float) -> Table:
    """A row per measure: count, p50, p99 and max milliseconds, and the target where there is one."""
    cells, summary = [], []
    for name, n, times, target in rows:
        p50, p99 = percentile(times, 50), percentile(times, 99)
        verdict = "" if target is None else f"p99 <= {target:g}: {'ok' if p99 <= target else 'MISSED'}"
        cells.append([name.strip(), f"{n:,}", f"{p50:.2f}", f"{p99:.2f}", f"{max(times):.2f}", verdict])
        summary.append({"measure": name.strip(), "n": n, "p50_ms": p50, "p99_ms": p99, "target_ms": target})
    pace = f"one step every {pace_ms:g} ms per session" if pace_ms else "steps sent back to back"
    notes = [f"Play: {pace}; the mean round-trip of 1 session {statistics.mean(rows[0][2]):.2f} ms."]
    columns = ["measure", "n", "p50 ms", "p99 ms", "max ms", "target"]
    return Table(columns, cells, summary={"rows": summary}, notes=notes)


if __name__ == "__main__":
    main()
