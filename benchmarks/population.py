"""Population training vs single runs: 100 seeds in one process against ordinary runs, a row per agent.

    python benchmarks/population.py                   # PPO: 100 population seeds, 20 single runs
    python benchmarks/population.py --agent ppo,dqn --seeds 100 --singles 0 --processes 10
    python benchmarks/population.py --agent a2c       # also reinforce, cem, random-search, hill-climbing
    python benchmarks/population.py --seeds 400 --device cuda --singles 0 --processes 0   # on a GPU

Each part runs in its own child process (so peak RSS and CPU are that part's alone), with the torch
threads ``cartpole train`` uses by default: one, for the population (``--seeds``) and single runs alike.
A row per agent:

- population: verified solves (each seed's kept best on 100 fresh episodes of Gymnasium's env), wall
  time from start to the last verdict, CPU seconds (user + system, the whole child: imports, training,
  verdicts) per seed, peak RSS, env steps/s, verified seeds/min, median env steps to the first verified
  solve in training;
- ``--processes N``: single runs as a person runs them without ``--seeds``, one ``cartpole train AGENT
  --seed S`` process per seed, CPU seconds of the whole process (imports, training, verdict, files),
  as the population's, and how many times the population's CPU per seed that is;
- ``--singles N``: single runs one after the other in one process (``cartpole.training.train``, so
  imports are paid once and left out): their verdicts, training CPU seconds per run, median solve
  step, and a two-sample Mann-Whitney U test's p-value (scipy) between the population's and their
  solve steps (a high p: the population learns as single runs do).
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from cpu import describe_cpu
from table_file import Measurement, Table, add_table_arguments


def cpu_seconds() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # Linux: KiB


def run_population_part(
    agent: str, seeds: int, preset: str, runs_dir: Path, device: str = "cpu", first: int = 0
) -> dict[str, object]:
    import torch

    from cartpole.training.session import train_population

    started = time.perf_counter()
    outcome = train_population(
        agent, list(range(first, first + seeds)), preset=preset, runs_dir=runs_dir, quiet=False, device=device
    )
    wall = time.perf_counter() - started
    states = outcome.states.values()
    return {
        "wall": wall,
        "cpu": cpu_seconds(),
        "rss_mb": peak_rss_mb(),
        "steps": sum(s.env_steps for s in states),
        "solved_at": [s.solved_at_step for s in states],
        "verified": sum(r.solved for r in outcome.reports.values()),
        "verdict_means": {seed: report.mean for seed, report in outcome.reports.items()},
        "threads": torch.get_num_threads(),
        "machine": describe_cpu(),
        "device": torch.cuda.get_device_name(0) if device.startswith("cuda") else "cpu",
    }


def run_singles_part(
    agent: str, seeds: int, preset: str, runs_dir: Path, first: int = 0
) -> dict[str, object]:
    import time as clock

    from cartpole.training import train

    cpu, solved_at, verified = [], [], 0
    for seed in range(first, first + seeds):
        before = clock.process_time()
        outcome = train(agent, seed=seed, preset=preset, runs_dir=runs_dir, device="cpu")
        cpu.append(clock.process_time() - before)
        solved_at.append(outcome.state.solved_at_step)
        verified += bool(outcome.report and outcome.report.solved)
        print(
            f"single seed {seed}: {cpu[-1]:.1f} CPU s, solved at {solved_at[-1]}", file=sys.stderr, flush=True
        )
    return {"cpu_per_run": cpu, "solved_at": solved_at, "verified": verified, "rss_mb": peak_rss_mb()}


def run_processes_part(
    agent: str, seeds: int, preset: str, runs_dir: Path, first: int = 0
) -> dict[str, object]:
    """Each seed as its own ``cartpole train`` process; CPU seconds of each whole child process."""
    cpu = []
    for seed in range(first, first + seeds):
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        command = [sys.executable, "-m", "cartpole", "train", agent, "--seed", str(seed), "--preset", preset]
        command += ["--quiet", "--runs-dir", str(runs_dir)]
        subprocess.run(command, check=True, stdout=subprocess.DEVNULL)
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu.append(after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime)
        print(f"process seed {seed}: {cpu[-1]:.1f} CPU s", file=sys.stderr, flush=True)
    return {"cpu_per_process": cpu}


def child(
    part: str,
    agent: str,
    seeds: int,
    preset: str,
    threads: int,
    out: Path,
    device: str = "cpu",
    first: int = 0,
) -> dict[str, Any]:
    """Run one part in its own process; its result is also kept as ``out/<agent>-<part>.json``."""
    with tempfile.TemporaryDirectory() as tmp:
        command = [sys.executable, __file__, "--part", part, "--agent", agent, "--n", str(seeds)]
        command += ["--preset", preset, "--population-threads", str(threads), "--device", device]
        command += ["--first-seed", str(first)]
        done = subprocess.run([*command, "--dir", tmp], stdout=subprocess.PIPE, text=True, check=True)
    result = json.loads(done.stdout.strip().splitlines()[-1])
    (out / f"{agent}-{part}.json").write_text(json.dumps(result))
    return result


def median(values: list[Any]) -> float:
    import numpy as np

    return float(np.median(values)) if values else float("nan")


def mean(values: list[int]) -> float:
    return sum(values) / len(values) if values else float("nan")


def summarize(
    agent: str, population: dict[str, Any], singles: dict[str, Any] | None, processes: dict[str, Any] | None
) -> dict[str, Any]:
    """One agent's figures: the population's, and its single runs' and processes' where measured."""
    from scipy.stats import mannwhitneyu

    seeds = len(population["solved_at"])
    wall = float(population["wall"])
    solved_at = [s for s in population["solved_at"] if s is not None]
    found: dict[str, Any] = {
        "agent": agent,
        "seeds": seeds,
        "device": population.get("device", "cpu"),
        "threads": population.get("threads", 1),
        "verified": population["verified"],
        "wall": wall,
        "cpu_per_seed": float(population["cpu"]) / seeds,
        "rss_mb": population["rss_mb"],
        "env_steps_per_s": float(population["steps"]) / wall,
        "verified_per_min": population["verified"] / wall * 60,
        "median_solve_step": median(solved_at),
        "mean_solve_step": mean(solved_at),
        "solved_in_training": len(solved_at),
    }
    if processes is not None:
        found["processes"] = len(processes["cpu_per_process"])
        found["process_cpu"] = median(processes["cpu_per_process"])
    if singles is not None:
        single_steps = [s for s in singles["solved_at"] if s is not None]
        found["singles"] = len(singles["solved_at"])
        found["singles_verified"] = singles["verified"]
        found["single_cpu"] = median(singles["cpu_per_run"])
        found["single_median_solve_step"] = median(single_steps)
        both = solved_at and single_steps
        found["mann_whitney_p"] = mannwhitneyu(solved_at, single_steps).pvalue if both else float("nan")
    return found


def population_cells(s: dict[str, Any]) -> list[str]:
    return [
        s["agent"],
        f"{s['device']}, {s['threads']}",
        f"{s['verified']}/{s['seeds']}",
        f"{s['wall']:.1f} s",
        f"{s['cpu_per_seed']:.2f}",
        f"{s['rss_mb']:,.0f} MB",
        f"{s['env_steps_per_s']:,.0f}",
        f"{s['verified_per_min']:,.1f}",
        f"{s['median_solve_step']:,.0f} ({s['solved_in_training']})",
    ]


def process_cells(s: dict[str, Any]) -> list[str]:
    return [f"{s['process_cpu']:.2f} (of {s['processes']})", f"{s['process_cpu'] / s['cpu_per_seed']:.1f}x"]


def single_cells(s: dict[str, Any]) -> list[str]:
    runs = (
        f"{s['singles_verified']}/{s['singles']}, {s['single_cpu']:.2f}, {s['single_median_solve_step']:,.0f}"
    )
    return [runs, f"{s['mann_whitney_p']:.3f}"]


def table_of(summaries: list[dict[str, Any]]) -> Table:
    """A row per agent; the columns of single runs and processes where they were measured."""
    columns = [
        "agent", "device, torch threads", "verified", "wall, start to last verdict",
        "CPU s per seed (whole process)", "peak RSS", "env steps/s", "verified seeds/min",
        "median solve step (solved in training)",
    ]  # fmt: skip
    processes = any("process_cpu" in s for s in summaries)
    singles = any("single_cpu" in s for s in summaries)
    if processes:
        columns += ["CPU s per `cartpole train` process (median)", "less CPU than processes"]
    if singles:
        columns += ["single runs: verified, training CPU s (median), median solve step", "Mann-Whitney p"]
    rows = []
    for s in summaries:
        row = population_cells(s)
        if processes:
            row += process_cells(s) if "process_cpu" in s else ["-", "-"]
        if singles:
            row += single_cells(s) if "single_cpu" in s else ["-", "-"]
        rows.append(row)
    return Table(columns, rows, summary={"agents": summaries})


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=100, help="population size (default 100)")
    parser.add_argument("--singles", type=int, default=20, help="single runs to compare with (default 20)")
    parser.add_argument(
        "--processes",
        type=int,
        default=10,
        help="single runs as separate `cartpole train` processes, the first N seeds (default 10; 0: none)",
    )
    parser.add_argument(
        "--agent",
        default="ppo",
        help="any agent, or several comma-separated (a row each): ppo, a2c, reinforce, dqn, cem, "
        "random-search, hill-climbing",
    )
    parser.add_argument("--preset", default="default")
    parser.add_argument("--first-seed", type=int, default=0, help="seeds FIRST..FIRST+N-1 (default 0)")
    parser.add_argument(
        "--population-threads",
        type=int,
        default=1,
        help="torch threads of the population (default 1, as `cartpole train --seeds` runs; 0: torch's "
        "own, one per core)",
    )
    parser.add_argument(
        "--device",
        default="cpu",
        help="where the population trains: cpu (default) or cuda (single runs stay on the CPU)",
    )
    parser.add_argument("--out", default="runs/population-benchmark", help="where each part's JSON is kept")
    parser.add_argument("--part", choices=["population", "singles", "processes"], help=argparse.SUPPRESS)
    parser.add_argument("--n", type=int, help=argparse.SUPPRESS)
    parser.add_argument("--dir", help=argparse.SUPPRESS)
    add_table_arguments(parser)
    args = parser.parse_args()
    if args.part:
        import torch

        if args.part == "singles" or args.population_threads:  # as `cartpole train` sets them
            torch.set_num_threads(1 if args.part == "singles" else args.population_threads)
        if args.part == "population":
            result = run_population_part(
                args.agent, args.n, args.preset, Path(args.dir), args.device, args.first_seed
            )
        else:
            run = run_singles_part if args.part == "singles" else run_processes_part
            result = run(args.agent, args.n, args.preset, Path(args.dir), args.first_seed)
        print(json.dumps(result))
        return
    measurement = Measurement(args)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    threads, first = args.population_threads, args.first_seed
    summaries, parts = [], {}
    for agent in [a.strip() for a in args.agent.split(",") if a.strip()]:
        population = child("population", agent, args.seeds, args.preset, threads, out, args.device, first)
        singles = None
        if args.singles:
            singles = child("singles", agent, args.singles, args.preset, threads, out, first=first)
        processes = None
        if args.processes:
            processes = child("processes", agent, args.processes, args.preset, threads, out, first=first)
        summaries.append(summarize(agent, population, singles, processes))
        parts[agent] = {"population": population, "singles": singles, "processes": processes}
    table = table_of(summaries)
    table.results = parts
    print(f"cpu: {describe_cpu()}")
    print(table.markdown())
    measurement.finish(table)


if __name__ == "__main__":
    main()
