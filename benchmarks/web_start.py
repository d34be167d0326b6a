"""A run started from the web app against the same run started from the CLI: how long until it trains.

    python benchmarks/web_start.py [--trials 5] [--agent cem] [--budget 5gen] [--seed 0]

The same run, ``cartpole train AGENT --seed S --budget B``, started two ways, alternately, --trials times
each (after --warmup untimed pairs): from the CLI, a ``python -m cartpole train ...`` process started
here; from the web app, ``POST /api/trainings`` (with the server's token) to one ``cartpole serve``
started once and warmed up before any timing (its start is not counted), which runs the same command as a
process of its own (on the CPU time nothing else wants, SCHED_IDLE). Each is timed from its start (the
Popen, the request's send) to its run folder's ``status.json`` first appearing: the run has started
training. Also timed: to the CLI process's end, to the POST's answer (it answers once the run folders are
named), and to the training's end as ``GET /api/trainings`` shows it. Issue's target: a run started from
the page starts in no more than 1 s longer than the same run started from the CLI (median against
median).

Both runs of each pair must be the same run: their ``metrics.jsonl`` rows equal apart from the
time-like keys (``time``, ``time/sps``, any key naming time, sps, cpu or wall) and their ``eval.json``
verdicts equal (mean, std, episodes); the script exits 1 otherwise. Run it on an otherwise idle
machine: each start is mostly the child's imports, which contend for the CPUs with whatever else runs.
"""

from __future__ import annotations

import argparse
import json
import secrets
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import httpx
from cpu import describe_cpu
from table_file import Measurement, Table, add_table_arguments
from web_latency import start_server

TARGET_SECONDS = 1.0
"""The page's start may be at most this much longer than the CLI's (medians)."""
POLL_SECONDS = 0.002
"""How often a runs folder is looked at for the new run's status.json."""
RUN_SECONDS = 600.0
"""The longest a trial's run may take, start to end, before the script gives up."""
TIME_LIKE = ("time", "sps", "cpu", "wall")
"""A metrics key naming one of these is a clock's reading, not the run's: left out of the comparison."""
VERDICT_KEYS = ("mean", "std", "episodes")
ENDED = ("finished", "stopped", "failed")


def new_run(runs_dir: Path, before: set[str], deadline: float) -> tuple[Path, float]:
    """The first run folder in ``runs_dir`` not in ``before`` that holds a ``status.json``, and the
    ``time.perf_counter()`` it was seen at."""
    while time.perf_counter() < deadline:
        for entry in runs_dir.iterdir() if runs_dir.is_dir() else ():
            if entry.name not in before and (entry / "status.json").is_file():
                return entry, time.perf_counter()
        time.sleep(POLL_SECONDS)
    raise RuntimeError(f"no new run folder with a status.json in {runs_dir} in time")


def folders(runs_dir: Path) -> set[str]:
    return {entry.name for entry in runs_dir.iterdir()} if runs_dir.is_dir() else set()


def train_args(args: argparse.Namespace) -> list[str]:
    """``cartpole train``'s arguments for the run both ways start (its runs folder aside)."""
    seed = [] if args.seed == 0 else ["--seed", str(args.seed)]
    return [args.agent, *seed, "--budget", args.budget]


def cli_trial(args: argparse.Namespace, runs_dir: Path, cwd: Path) -> dict[str, Any]:
    """``python -m cartpole train ...`` started here: seconds to its status.json, and to its end."""
    before = folders(runs_dir)
    command = [sys.executable, "-m", "cartpole", "train", *train_args(args), "--runs-dir", str(runs_dir)]
    with open(cwd / "cli.log", "ab") as log:
        start = time.perf_counter()
        process = subprocess.Popen(command, cwd=cwd, stdin=subprocess.DEVNULL, stdout=log, stderr=log)
        try:
            run, seen = new_run(runs_dir, before, start + RUN_SECONDS)
            code = process.wait(timeout=RUN_SECONDS)
            ended = time.perf_counter()
        finally:
            if process.poll() is None:
                process.kill()
                process.wait()
    if code != 0:
        raise RuntimeError(f"{' '.join(command)} exited {code}; its output is in {cwd / 'cli.log'}")
    return {"run": str(run), "to_status_s": seen - start, "to_end_s": ended - start, "command": command}


class WebServer:
    """One ``cartpole serve --token T`` on its own runs folder, started and warmed up before timing."""

    def __init__(self, runs_dir: Path, cwd: Path):
        self.runs_dir = runs_dir
        self.token = secrets.token_hex(16)
        self.server, address = start_server(runs_dir, (f"--token={self.token}", "--max-trainings", "2"), cwd)
        self.base = f"http://{address}/api/trainings"
        self.client = httpx.Client(timeout=120, headers={"Authorization": f"Bearer {self.token}"})

    def body(self, args: argparse.Namespace) -> dict[str, Any]:
        return {"agent": args.agent, "env_id": "CartPole-v1", "seeds": [args.seed], "budget": args.budget}

    def warm_up(self, args: argparse.Namespace) -> None:
        """What a first request pays once (the checks' imports): a dry run of the same training."""
        answer = self.client.post(self.base, json={**self.body(args), "dry_run": True})
        if answer.status_code != 200:
            raise RuntimeError(f"POST /api/trainings (dry run) answered {answer.status_code}: {answer.text}")
        self.client.get(self.base).raise_for_status()

    def trial(self, args: argparse.Namespace) -> dict[str, Any]:
        """``POST /api/trainings``: seconds to its run's status.json, to its answer, and to the
        training's end (``GET /api/trainings``)."""
        before = folders(self.runs_dir)
        answered: dict[str, Any] = {}

        def post() -> None:
            try:
                answer = self.client.post(self.base, json=self.body(args))
                answered["at"] = time.perf_counter()
                answered["status"] = answer.status_code
                answered["body"] = answer.json() if answer.status_code == 201 else answer.text
            except Exception as err:  # reported below, in this thread
                answered["error"] = repr(err)

        start = time.perf_counter()
        sender = threading.Thread(target=post)
        sender.start()
        try:
            run, seen = new_run(self.runs_dir, before, start + RUN_SECONDS)
        finally:
            sender.join(timeout=RUN_SECONDS)
        if answered.get("status") != 201:
            raise RuntimeError(
                f"POST /api/trainings {json.dumps(self.body(args))} answered "
                f"{answered.get('status')}: {answered.get('body') or answered.get('error')}"
            )
        started = answered["body"]
        if started["runs"] != [run.name]:
            raise RuntimeError(
                f"POST /api/trainings answered runs {started['runs']}, but the new run folder is {run.name}"
            )
        row = self.wait_for_end(started["name"], start + RUN_SECONDS)
        ended = time.perf_counter()
        if row["state"] != "finished":
            raise RuntimeError(f"training {started['name']} ended {row['state']}: {row.get('problem')}")
        return {
            "run": str(run),
            "to_status_s": seen - start,
            "to_answer_s": answered["at"] - start,
            "to_end_s": ended - start,
            "command": started["command"],
            "name": started["name"],
        }

    def wait_for_end(self, name: str, deadline: float) -> dict[str, Any]:
        while time.perf_counter() < deadline:
            rows = {row["name"]: row for row in self.client.get(self.base).json()}
            if rows[name]["state"] in ENDED:
                return rows[name]
            time.sleep(0.02)
        raise RuntimeError(f"training {name} did not end within {RUN_SECONDS:g} s")

    def close(self) -> None:
        self.client.close()
        self.server.terminate()
        self.server.wait(timeout=90)


def kept_metrics(run: Path) -> list[dict[str, Any]]:
    """``metrics.jsonl``'s rows without their time-like keys."""
    rows = []
    for line in (run / "metrics.jsonl").read_text(encoding="utf-8").splitlines():
        if line.strip():
            row = json.loads(line)
            rows.append({k: v for k, v in row.items() if not any(word in k.lower() for word in TIME_LIKE)})
    return rows


def verdict(run: Path) -> dict[str, Any]:
    report = json.loads((run / "eval.json").read_text(encoding="utf-8"))
    return {key: report[key] for key in VERDICT_KEYS}


def median(values: list[float]) -> float:
    return statistics.median(values)


def table_of(cli: list[dict[str, Any]], web: list[dict[str, Any]], args: argparse.Namespace) -> Table:
    """Medians of each way's times, the difference against the target, and whether the runs agree."""
    cli_start, web_start = median([t["to_status_s"] for t in cli]), median([t["to_status_s"] for t in web])
    difference = web_start - cli_start
    met = difference <= TARGET_SECONDS
    cli_end, web_end = median([t["to_end_s"] for t in cli]), median([t["to_end_s"] for t in web])
    reference = Path(cli[0]["run"])
    metrics, judged = kept_metrics(reference), verdict(reference)
    same_metrics = [kept_metrics(Path(t["run"])) == metrics for t in cli + web]
    same_verdict = [verdict(Path(t["run"])) == judged for t in cli + web]

    def each(trials: list[dict[str, Any]], key: str) -> str:
        return ", ".join(f"{t[key]:.2f}" for t in trials)

    n = len(cli)
    rows = [
        [
            f"start to status.json (training started), median of {n}",
            f"{cli_start:.2f} s",
            f"{web_start:.2f} s",
            f"{difference:+.2f} s",
            f"<= {TARGET_SECONDS:g} s longer: {'met' if met else 'MISSED'}",
        ],
        ["  each trial, s", each(cli, "to_status_s"), each(web, "to_status_s"), "", ""],
        [
            f"start to the POST's answer (201), median of {n}",
            "-",
            f"{median([t['to_answer_s'] for t in web]):.2f} s",
            "",
            "",
        ],
        [
            f"start to the run's end (CLI: its process; web: GET /api/trainings), median of {n}",
            f"{cli_end:.2f} s",
            f"{web_end:.2f} s",
            f"{web_end - cli_end:+.2f} s",
            "",
        ],
        [
            "metrics.jsonl rows equal to the first CLI run's, time-like keys aside",
            f"{sum(same_metrics[:n])}/{n} ({len(metrics)} rows)",
            f"{sum(same_metrics[n:])}/{n}",
            "",
            "all equal: " + ("yes" if all(same_metrics) else "NO"),
        ],
        [
            "eval.json verdict (mean, std, episodes) equal to the first CLI run's",
            f"{sum(same_verdict[:n])}/{n} ({judged['mean']:.2f} ± {judged['std']:.2f}, "
            f"{judged['episodes']} episodes)",
            f"{sum(same_verdict[n:])}/{n}",
            "",
            "all equal: " + ("yes" if all(same_verdict) else "NO"),
        ],
    ]
    run = " ".join(["cartpole", "train", *train_args(args)])
    notes = [
        f"The run: `{run}` on CartPole-v1, started alternately {n} times each way after {args.warmup} "
        "untimed pair(s): by `python -m cartpole train ... --runs-dir D` (nice 0), and by `POST "
        "/api/trainings` to a `cartpole serve --token T` started and warmed up before any timing (its "
        "process on the CPU time nothing else wants: SCHED_IDLE).",
        f"Target: a run started from the page starts in no more than {TARGET_SECONDS:g} s longer than from "
        f"the CLI: {difference:+.2f} s ({'met' if met else 'MISSED'}).",
    ]
    columns = ["measure", "CLI (`cartpole train`)", "web (`POST /api/trainings`)", "web - CLI", "target"]
    summary = {
        "cli_to_status_s": cli_start,
        "web_to_status_s": web_start,
        "difference_s": difference,
        "target_s": TARGET_SECONDS,
        "met": met,
        "cli_to_end_s": cli_end,
        "web_to_end_s": web_end,
        "web_to_answer_s": median([t["to_answer_s"] for t in web]),
        "metrics_equal": all(same_metrics),
        "verdicts_equal": all(same_verdict),
        "metrics_rows": len(metrics),
        "verdict": judged,
    }
    return Table(columns, rows, summary=summary, results={"cli": cli, "web": web}, notes=notes)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--trials", type=int, default=5, help="timed starts each way, alternately (default: 5)"
    )
    parser.add_argument("--warmup", type=int, default=1, help="untimed pairs first (default: 1)")
    parser.add_argument("--agent", default="cem", help="the agent both start (default: cem)")
    parser.add_argument("--budget", default="5gen", help="its budget, as --budget takes it (default: 5gen)")
    parser.add_argument("--seed", type=int, default=0, help="its seed (default: 0)")
    add_table_arguments(parser)
    args = parser.parse_args()
    if args.trials < 1:
        parser.error(f"--trials must be at least 1, got {args.trials}")
    if args.warmup < 0:
        parser.error(f"--warmup must be 0 or more, got {args.warmup}")
    measurement = Measurement(args)

    cli: list[dict[str, Any]] = []
    web: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        server = WebServer(folder / "web-runs", folder)
        try:
            server.warm_up(args)
            for trial in range(args.warmup + args.trials):
                timed = trial >= args.warmup
                pair = (cli_trial(args, folder / "cli-runs", folder), server.trial(args))
                print(
                    f"{'trial' if timed else 'warm-up'} {trial - args.warmup + 1 if timed else trial + 1}: "
                    f"status.json after {pair[0]['to_status_s']:.2f} s (CLI), "
                    f"{pair[1]['to_status_s']:.2f} s (web)",
                    file=sys.stderr,
                )
                if timed:
                    cli.append(pair[0])
                    web.append(pair[1])
            table = table_of(cli, web, args)
        finally:
            server.close()
    print(f"cartpole web start against CLI start on {describe_cpu()}")
    print(table.markdown())
    measurement.finish(table)
    summary = table.summary
    return 0 if summary["metrics_equal"] and summary["verdicts_equal"] else 1


if __name__ == "__main__":
    sys.exit(main())
