"""Population training vs single runs: 100 PPO seeds in one process against 20 ordinary runs.

    python benchmarks/population.py                   # 100 population seeds, 20 single runs
    python benchmarks/population.py --seeds 20 --singles 5
    python benchmarks/population.py --agent a2c       # also reinforce, cem, random-search, hill-climbing
    python benchmarks/population.py --population-threads 1
    python benchmarks/population.py --seeds 400 --device cuda --singles 0 --processes 0   # on a GPU

Each part runs in its own child process (so peak RSS and CPU are that part's alone), with the torch
threads ``cartpole train`` uses by default: one, for the population (``--seeds``) and single runs alike.
Printed:

- population: verified solves (each seed's kept best on 100 fresh episodes of Gymnasium's env), wall
  time from start to the last verdict, CPU seconds (user + system, the whole child: imports, training,
  verdicts) per seed, peak RSS, env steps/s, seeds/min (all, and verified);
- single runs: the same verdicts, and the training CPU seconds per run (``cartpole.training.train``,
  one after the other in one process, so imports are paid once and left out);
- single runs as a person runs them without ``--seeds``: one ``cartpole train AGENT --seed S`` process
  per seed, CPU seconds of the whole process (imports, training, verdict, files), as the population's;
- both CPU ratios, and the solve-step distributions (first verified solve in training, env steps) of
  the population and the in-process single runs: medians (and the population's mean) and a two-sample
  Mann-Whitney U test's p-value (scipy).
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

from cpu import describe_cpu


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
) -> dict[str, object]:
    """Run one part in its own process; its result is also kept as ``out/<part>.json``."""
    with tempfile.TemporaryDirectory() as tmp:
        command = [sys.executable, __file__, "--part", part, "--agent", agent, "--n", str(seeds)]
        command += ["--preset", preset, "--population-threads", str(threads), "--device", device]
        command += ["--first-seed", str(first)]
        done = subprocess.run([*command, "--dir", tmp], stdout=subprocess.PIPE, text=True, check=True)
    result = json.loads(done.stdout.strip().splitlines()[-1])
    (out / f"{part}.json").write_text(json.dumps(result))
    return result


def median(values: list[int]) -> float:
    import numpy as np

    return float(np.median(values)) if values else float("nan")


def mean(values: list[int]) -> float:
    return sum(values) / len(values) if values else float("nan")


def report(
    population: dict[str, object],
    singles: dict[str, object] | None,
    processes: dict[str, object] | None,
    seeds: int,
    runs: int,
) -> None:
    from scipy.stats import mannwhitneyu

    pop_cpu = float(population["cpu"]) / seeds  # type: ignore[arg-type]
    wall = float(population["wall"])  # type: ignore[arg-type]
    pop_steps = [s for s in population["solved_at"] if s is not None]  # type: ignore[attr-defined]
    print(f"cpu: {population.get('machine', 'not recorded')}")
    device = population.get("device", "cpu")
    rows = [
        ("population seeds", f"{seeds} ({population.get('threads', 1)} torch threads; single runs: 1)"),
        ("population device", f"{device}"),
        ("verified solves (population)", f"{population['verified']}/{seeds}"),
        ("wall, start to last verdict", f"{wall:.1f} s"),
        ("CPU per seed, population (whole process)", f"{pop_cpu:.2f} s"),
    ]
    single_steps: list[int] = []
    if singles is not None:
        single_cpu = median(singles["cpu_per_run"])  # type: ignore[arg-type]
        single_steps = [s for s in singles["solved_at"] if s is not None]  # type: ignore[attr-defined]
        rows += [
            ("CPU per run, single runs (median of training)", f"{single_cpu:.2f} s"),
            ("CPU ratio single / population", f"{single_cpu / pop_cpu:.1f}x"),
        ]
    if processes is not None:
        process_cpu = median(processes["cpu_per_process"])  # type: ignore[arg-type]
        count = len(processes["cpu_per_process"])  # type: ignore[arg-type]
        rows += [
            (f"CPU per run, {count} `cartpole train` processes (median)", f"{process_cpu:.2f} s"),
            ("CPU ratio process / population", f"{process_cpu / pop_cpu:.1f}x"),
        ]
    rows += [
        ("peak RSS, population process", f"{population['rss_mb']:.0f} MB"),
        ("env steps/s (all seeds)", f"{float(population['steps']) / wall:,.0f}"),  # type: ignore[arg-type]
        ("seeds/min", f"{seeds / wall * 60:.1f}"),
        ("verified seeds/min", f"{float(population['verified']) / wall * 60:.1f}"),  # type: ignore[arg-type]
        ("median solve step, population", f"{median(pop_steps):,.0f} ({len(pop_steps)} solved in training)"),
        ("mean solve step, population", f"{mean(pop_steps):,.0f} (the seeds solved in training)"),
    ]
    if singles is not None:
        p_value = mannwhitneyu(pop_steps, single_steps).pvalue if pop_steps and single_steps else float("nan")
        rows += [
            ("verified solves (single runs)", f"{singles['verified']}/{runs}"),
            (
                "median solve step, single runs",
                f"{median(single_steps):,.0f} ({len(single_steps)} solved in training)",
            ),
            ("Mann-Whitney U p-value (solve steps)", f"{p_value:.3f}"),
        ]
    width = max(len(name) for name, _ in rows)
    for name, value in rows:
        print(f"{name:<{width}}  {value}")


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
        help="any agent: ppo, a2c, reinforce, dqn, cem, random-search, hill-climbing",
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
    parser.add_argument("--report-only", action="store_true", help="print the table from --out's JSON files")
    parser.add_argument("--part", choices=["population", "singles", "processes"], help=argparse.SUPPRESS)
    parser.add_argument("--n", type=int, help=argparse.SUPPRESS)
    parser.add_argument("--dir", help=argparse.SUPPRESS)
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
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if args.report_only:
        population = json.loads((out / "population.json").read_text())
        kept_singles, kept_processes = out / "singles.json", out / "processes.json"
        singles = json.loads(kept_singles.read_text()) if kept_singles.exists() else None
        processes = json.loads(kept_processes.read_text()) if kept_processes.exists() else None
        runs = len(singles["solved_at"]) if singles else 0
        report(population, singles, processes, len(population["solved_at"]), runs)
        return
    threads = args.population_threads
    first = args.first_seed
    population = child("population", args.agent, args.seeds, args.preset, threads, out, args.device, first)
    singles = None
    if args.singles:
        singles = child("singles", args.agent, args.singles, args.preset, threads, out, first=first)
    processes = None
    if args.processes:
        processes = child("processes", args.agent, args.processes, args.preset, threads, out, first=first)
    report(population, singles, processes, args.seeds, args.singles)


if __name__ == "__main__":
    main()
