"""Crash safety: kill -9 training runs at random moments, resume each, and measure the work lost.

Usage (from the repository root)::

    python benchmarks/kill_resume.py                 # 5 trials for every agent, alone and as a population
    python benchmarks/kill_resume.py --agents dqn,ppo-population --trials 4
    python benchmarks/kill_resume.py --trials 6 --jobs 3 --device cpu

Each trial starts ``cartpole train AGENT --seed N --quiet`` (an ``AGENT-population`` entry:
``--seeds N-N+3``, four seeds in one process) with default settings (the preset's budget and checkpoint
cadence) in a fresh runs folder, waits until its ``config.json`` exists, sleeps a random time (uniform
over the agent's measured training time, so a kill can land anywhere from the first step to the final
verdict), sends SIGKILL, then runs ``cartpole train --resume RUN`` to the end (for a population, the
resume of one member continues them all; its loss is the largest of its seeds').

Work lost = the env steps the killed process had recorded on disk (``status.json``, ``metrics.jsonl``)
minus the steps in ``checkpoints/latest.pt`` (0 when there was none yet): a lower bound of the true
loss by at most the metrics flush interval (1 s; 5 s in a population). A trial passes when every resumed
run exits 0 with status "finished" and a final verdict (``eval.json``) and the loss is at most one
checkpoint interval (5% of the budget or 30 s of training, whichever is less).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import random
import signal
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from table_file import Measurement, Table, add_table_arguments

SINGLE = ("dqn", "ppo", "a2c", "reinforce", "cem", "hill-climbing", "random-search")
POPULATION = "-population"
"""An entry ``AGENT-population`` trains :data:`POPULATION_SEEDS` seeds of AGENT in one process."""
AGENTS = SINGLE + tuple(agent + POPULATION for agent in SINGLE)
POPULATION_SEEDS = 4


@dataclass
class Trial:
    index: int
    agent: str
    seed: int
    kill_after: float
    """Seconds after config.json appeared."""
    status_at_kill: str = ""
    steps_at_kill: int = 0
    steps_in_latest: int = 0
    interval_steps: float = 0.0
    """One checkpoint interval, in env steps, as the run went (5% of budget or 30 s of training)."""
    resume_rc: int | None = None
    finished: bool = False
    verdict: str | None = None
    final_steps: int = 0
    stop_detail: str | None = None

    @property
    def lost(self) -> int:
        return max(0, self.steps_at_kill - self.steps_in_latest)

    @property
    def passed(self) -> bool:
        return (
            self.resume_rc == 0
            and self.finished
            and self.verdict is not None
            and self.lost <= self.interval_steps
        )


def cartpole(*args: str) -> list[str]:
    return [sys.executable, "-m", "cartpole", *args]


def train_args(entry: str, seed: int, runs_dir: Path, device: str | None) -> list[str]:
    agent = entry.removesuffix(POPULATION)
    seeds = ["--seeds", f"{seed}-{seed + POPULATION_SEEDS - 1}"] if entry.endswith(POPULATION) else []
    args = ["train", agent, *(seeds or ["--seed", str(seed)]), "--quiet", "--runs-dir", str(runs_dir)]
    return args + (["--device", device] if device else [])


def wait_for_config(runs_dir: Path, process: subprocess.Popen[bytes], timeout: float = 300) -> Path | None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and process.poll() is None:
        found = list(runs_dir.glob("*/config.json"))
        if found:
            return found[0].parent
        time.sleep(0.01)
    found = list(runs_dir.glob("*/config.json"))
    return found[0].parent if found else None


def read_json(path: Path) -> dict[str, Any]:
    try:
        return json.loads(path.read_text())
    except (OSError, json.JSONDecodeError):
        return {}


def steps_on_disk(run: Path) -> int:
    """The most env steps the run's files show: status.json's counter or the last metrics row."""
    steps = int(read_json(run / "status.json").get("env_steps") or 0)
    try:
        lines = (run / "metrics.jsonl").read_text().split("\n")[:-1]
    except OSError:
        lines = []
    for line in reversed(lines):
        try:
            return max(steps, int(json.loads(line)["step"]))
        except (json.JSONDecodeError, KeyError, TypeError, ValueError):
            continue
    return steps


def latest_steps(run: Path) -> tuple[int, dict[str, Any]]:
    from cartpole.runs import load_checkpoint

    path = run / "checkpoints" / "latest.pt"
    if not path.exists():
        return 0, {}
    meta = load_checkpoint(path).meta
    return int(meta["step"]), meta["loop"]


def checkpoint_interval_steps(run: Path) -> float:
    """One checkpoint interval in env steps: 5% of the budget, or 30 s at the run's speed if sooner,
    from the run's status.json once it has finished (its steps, time and generations)."""
    config = read_json(run / "config.json")
    settings, budget = config["settings"], config["budget"]
    status = read_json(run / "status.json")
    steps, elapsed = status.get("env_steps") or 0, status.get("elapsed") or 0.0
    per_second = steps / elapsed if elapsed else float("inf")
    by_time = settings.get("checkpoint_seconds", 30.0) * per_second
    fraction = settings.get("checkpoint_fraction", 0.05)
    if "env_steps" in budget:
        by_budget = fraction * budget["env_steps"]
    else:  # generations: a generation's steps vary; use the run's mean steps per generation
        iterations = status.get("iterations") or 1
        by_budget = fraction * budget.get("iterations", iterations) * steps / iterations
    return min(by_budget, by_time)


def measure_duration(agent: str, device: str | None) -> float:
    """Seconds from config.json to the process's exit, for one uninterrupted run (seed 1000)."""
    with tempfile.TemporaryDirectory() as tmp:
        process = subprocess.Popen(cartpole(*train_args(agent, 1000, Path(tmp), device)))
        if wait_for_config(Path(tmp), process) is None:
            raise SystemExit(f"{agent}: the calibration run made no run folder")
        start = time.monotonic()
        process.wait()
        return time.monotonic() - start


def run_trial(trial: Trial, base: Path, device: str | None) -> Trial:
    runs_dir = base / f"trial-{trial.index:02d}"
    process = subprocess.Popen(cartpole(*train_args(trial.agent, trial.seed, runs_dir, device)))
    run = wait_for_config(runs_dir, process)
    time.sleep(trial.kill_after)
    process.send_signal(signal.SIGKILL)
    process.wait()
    if run is None:
        raise RuntimeError(f"trial {trial.index}: no run folder")
    runs = sorted(p.parent for p in runs_dir.glob("*/config.json"))  # a population: every seed's
    trial.status_at_kill = read_json(run / "status.json").get("state", "none")
    worst = max(runs, key=lambda r: steps_on_disk(r) - latest_steps(r)[0])
    trial.steps_at_kill = steps_on_disk(worst)
    trial.steps_in_latest, _ = latest_steps(worst)
    resumed = subprocess.run(
        cartpole("train", "--resume", str(run), "--quiet"), capture_output=True, text=True
    )
    trial.resume_rc = resumed.returncode
    # From the finished run's status: a kill before the first status with steps left none to go by.
    trial.interval_steps = checkpoint_interval_steps(worst)
    statuses = [read_json(r / "status.json") for r in runs]
    verdicts = [read_json(r / "eval.json").get("verdict") for r in runs]
    trial.finished = all(s.get("state") == "finished" for s in statuses)
    trial.verdict = verdicts[0] if all(verdicts) else None
    trial.final_steps = min(int(s.get("env_steps") or 0) for s in statuses)
    trial.stop_detail = statuses[0].get("stop_detail")
    if resumed.returncode != 0:
        print(f"trial {trial.index}: resume failed:\n{resumed.stdout}{resumed.stderr}", file=sys.stderr)
    return trial


def table_of(done: list[Trial], durations: dict[str, float]) -> Table:
    """A row per agent: its kills (when, and its whole run's length), how many resumed to a verdict,
    the largest loss and one checkpoint interval, in env steps."""
    rows, per_agent = [], []
    for agent, duration in durations.items():
        trials = [t for t in done if t.agent == agent]
        if not trials:
            continue
        worst = max(trials, key=lambda t: t.lost)
        kills = min(t.kill_after for t in trials), max(t.kill_after for t in trials)
        resumed = sum(t.finished and t.verdict is not None for t in trials)
        name = agent.replace(POPULATION, f", {POPULATION_SEEDS}-seed population")
        count = len(trials)
        rows.append([
            name, f"{count} ({kills[0]:.1f}-{kills[1]:.1f}; {duration:.1f} s)", f"{resumed}/{count}",
            f"{worst.lost:,}", f"{worst.interval_steps:,.0f}", f"{sum(t.passed for t in trials)}/{count}",
        ])  # fmt: skip
        per_agent.append(
            {"agent": agent, "trials": len(trials), "resumed": resumed, "largest_loss": worst.lost}
        )
    worst = max(done, key=lambda t: t.lost)
    summary = {
        "trials": len(done),
        "resumed": sum(t.finished and t.verdict is not None for t in done),
        "passed": sum(t.passed for t in done),
        "largest_loss": worst.lost,
        "largest_loss_interval": worst.interval_steps,
        "largest_loss_agent": worst.agent,
        "agents": per_agent,
    }
    columns = [
        "agent", "kills (at, s after start; whole run)", "resumed to a verdict", "largest loss, env steps",
        "one checkpoint interval, env steps", "passed",
    ]  # fmt: skip
    return Table(columns, rows, summary=summary, results=[asdict(t) | {"lost": t.lost} for t in done])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--trials", type=int, default=5 * len(AGENTS), help="kills, spread over --agents")
    parser.add_argument("--agents", default=",".join(AGENTS), help="comma-separated; AGENT-population too")
    parser.add_argument("--jobs", type=int, default=1, help="trials at once (default 1)")
    parser.add_argument("--seed", type=int, default=0, help="seeds the kill times")
    parser.add_argument("--device", default=None, help="passed to `cartpole train` (default: its own)")
    parser.add_argument("--json", metavar="FILE", help="also write every trial as JSON")
    add_table_arguments(parser)
    args = parser.parse_args()
    measurement = Measurement(args)

    agents = args.agents.split(",")
    durations = {agent: measure_duration(agent, args.device) for agent in agents}
    rng = random.Random(args.seed)
    trials = [
        Trial(i, agents[i % len(agents)], i, rng.uniform(0.0, durations[agents[i % len(agents)]]))
        for i in range(args.trials)
    ]
    with tempfile.TemporaryDirectory() as tmp, ThreadPoolExecutor(args.jobs) as pool:
        done = list(pool.map(lambda t: run_trial(t, Path(tmp), args.device), trials))

    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, jobs {args.jobs}")
    print(
        "uninterrupted run (config.json to exit): "
        + ", ".join(f"{a} {d:.1f} s" for a, d in durations.items())
    )
    header = f"{'#':>2} {'agent':18} {'kill at':>8} {'status at kill':>14} {'on disk':>8} {'latest':>8} "
    header += f"{'lost':>6} {'interval':>8} {'resume':>6} {'final':>8}  end"
    print(header)
    for t in done:
        end = f"{'finished' if t.finished else 'NOT finished'}, {t.stop_detail}; {t.verdict}"
        print(
            f"{t.index:>2} {t.agent:18} {t.kill_after:7.1f}s {t.status_at_kill:>14} {t.steps_at_kill:>8} "
            f"{t.steps_in_latest:>8} {t.lost:>6} {t.interval_steps:>8.0f} {t.resume_rc!s:>6} "
            f"{t.final_steps:>8}  {end}"
        )
    worst = max(done, key=lambda t: t.lost)
    passed = sum(t.passed for t in done)
    verdicts = sum(t.finished and t.verdict is not None for t in done)
    print(
        f"largest loss: {worst.lost} env steps (trial {worst.index}, {worst.agent}; interval "
        f"{worst.interval_steps:.0f}); resumed to a verdict: {verdicts}/{len(done)}; "
        f"passed: {passed}/{len(done)}"
    )
    table = table_of(done, durations)
    if args.json:
        Path(args.json).write_text(json.dumps(table.results, indent=2))
    print(table.markdown())
    measurement.finish(table)
    return 0 if passed == len(done) else 1


if __name__ == "__main__":
    raise SystemExit(main())
