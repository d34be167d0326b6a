"""Where a training run's time goes, per agent: acting, env stepping, learning, evaluations, bookkeeping.

Usage (from the repository root)::

    python benchmarks/phases.py                              # every neural agent, one seed, single runs
    python benchmarks/phases.py --agents dqn,ppo --seeds 3   # seeds 0..2, summed
    python benchmarks/phases.py --agents ppo --population 20 # also seeds 0..19 as one population (--seeds)

Each (agent, mode) runs in its own subprocess with one torch thread (``cartpole train``'s default) and
trains with the preset's own budget and stop rule, as ``cartpole train`` does. A sampling profiler
(``SIGPROF`` every ``--interval`` ms of CPU time reads the Python stack; written here because the
well-kept samplers, py-spy and pyinstrument, are not dependencies of ours) sorts each sample into one
phase by the functions on the stack, in this order:

- evaluations: anything under :mod:`cartpole.evaluation` or the engine's evaluations (the in-training
  screens and full evaluations, and the final verdicts), whatever it calls;
- env stepping: a vector env's or the population envs' ``step`` (our fast simulator or Gymnasium's);
- learning: an agent's update (losses, backward passes, optimizer steps, advantages, replay sampling);
- acting: the policy that picks the training actions (its forward pass and sampling);
- bookkeeping: the rest (the loop, metrics, checkpoints, progress, imports made during training).

Printed per agent and mode: CPU seconds (``time.process_time`` of the run), env steps, each phase's
share, and each phase's CPU microseconds per env step.
"""

from __future__ import annotations

import argparse
import json
import signal
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path
from types import FrameType
from typing import Any

from cpu import describe_cpu
from table_file import Measurement, Table, add_table_arguments

PHASES = ("evaluations", "env stepping", "learning", "acting", "bookkeeping")

EVALUATION_FUNCTIONS = {
    ("engine.py", "prepare"),
    ("engine.py", "final_verdicts"),
    ("engine.py", "play_final_episodes"),
    ("callbacks.py", "screened_evaluation"),
}
ENV_STEP_FILES = ("cartpole/envs/", "gymnasium/")
LEARNING_FUNCTIONS = {
    "update", "gradient_step", "train", "backward_and_step", "minibatch_loss", "advantages",
    "log_probs_of", "generalized_advantages", "rollout_batch", "clip_and_step", "backward_group",
    "sample", "sample_slots", "gather", "after_step", "targets", "step_optimizer", "finish_generation",
}  # fmt: skip
ACTING_FUNCTIONS = {
    "select_actions", "greedy_actions", "numpy_q_values", "greedy_q_argmax", "sample_actions",
    "sample_categorical", "scores", "q_values", "propose", "play_candidates", "numpy_actor",
}  # fmt: skip
ACTING_FILES = ("numpy_mlp.py",)


def phase_of(frame: FrameType | None) -> str:
    """The phase of one stack sample (innermost ``frame``), by the rules of the module docstring."""
    names: list[tuple[str, str]] = []
    while frame is not None:
        names.append((frame.f_code.co_filename, frame.f_code.co_name))
        frame = frame.f_back
    if any(path.endswith("cartpole/evaluation.py") or (Path(path).name, name) in EVALUATION_FUNCTIONS
           for path, name in names):  # fmt: skip
        return "evaluations"
    if any(name == "step" and any(part in path for part in ENV_STEP_FILES) for path, name in names):
        return "env stepping"
    in_agents = [(path, name) for path, name in names if "cartpole/agents/" in path]
    in_autograd = any("torch/autograd" in path for path, _ in names)
    if in_autograd or any(name in LEARNING_FUNCTIONS for _, name in in_agents):
        return "learning"
    if any(name in ACTING_FUNCTIONS or path.endswith(ACTING_FILES) for path, name in in_agents):
        return "acting"
    return "bookkeeping"


class Sampler:
    """Counts the phase of the training thread's stack at every ``interval`` seconds of the process's
    CPU time (``SIGPROF``; the handler runs in the main thread and sees its current frame)."""

    def __init__(self, interval: float):
        self.interval = interval
        self.counts: Counter[str] = Counter()

    def sample(self, signum: int, frame: FrameType | None) -> None:
        self.counts[phase_of(frame)] += 1

    def __enter__(self) -> Sampler:
        self.previous = signal.signal(signal.SIGPROF, self.sample)
        signal.setitimer(signal.ITIMER_PROF, self.interval, self.interval)
        return self

    def __exit__(self, *exc: object) -> None:
        signal.setitimer(signal.ITIMER_PROF, 0.0)
        signal.signal(signal.SIGPROF, self.previous)


def profile_run(agent: str, seeds: list[int], population: bool, interval: float) -> dict[str, Any]:
    """Train ``agent`` (seeds in one population, or a single run per seed) with sampling on."""
    import torch

    from cartpole.training import train
    from cartpole.training.session import train_population

    torch.set_num_threads(1)
    counts: Counter[str] = Counter()
    env_steps, cpu = 0, 0.0
    with tempfile.TemporaryDirectory() as runs_dir:
        train(agent, seed=10_000, budget="1k" if agent != "cem" else "1gen", runs_dir=runs_dir)  # warm up
        runs = [seeds] if population else [[seed] for seed in seeds]
        for group in runs:
            with Sampler(interval) as sampler:
                start = time.process_time()
                if population:
                    outcome = train_population(agent, group, runs_dir=runs_dir)
                    env_steps += sum(state.env_steps for state in outcome.states.values())
                else:
                    env_steps += train(agent, seed=group[0], runs_dir=runs_dir).state.env_steps
                cpu += time.process_time() - start
            counts.update(sampler.counts)
    return {"agent": agent, "mode": f"population of {len(seeds)}" if population else "single runs",
            "seeds": len(seeds), "cpu": cpu, "env_steps": env_steps, "samples": dict(counts)}  # fmt: skip


def row(result: dict[str, Any]) -> list[str]:
    samples = sum(result["samples"].values()) or 1
    shares = {phase: result["samples"].get(phase, 0) / samples for phase in PHASES}
    cpu_per_step = result["cpu"] / max(result["env_steps"], 1) * 1e6
    per_step = {phase: share * cpu_per_step for phase, share in shares.items()}
    cells = [f"{shares[p]:.0%} ({per_step[p]:.0f})" for p in PHASES]
    return [result["agent"], result["mode"], f"{result['cpu']:.1f}", f"{result['env_steps']:,}", *cells]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--agents", default="ppo,a2c,reinforce,dqn", help="comma-separated agent names")
    parser.add_argument("--seeds", type=int, default=1, help="single runs of seeds 0..N-1 (default 1)")
    parser.add_argument("--population", type=int, default=0, help="also seeds 0..N-1 as one population")
    parser.add_argument("--interval", type=float, default=1.0, help="sampling interval, ms (default 1)")
    parser.add_argument("--one", help=argparse.SUPPRESS)
    add_table_arguments(parser)
    args = parser.parse_args()
    if args.one:  # a child: one (agent, mode), its result as JSON on the last line
        agent, mode, count = args.one.split(":")
        result = profile_run(agent, list(range(int(count))), mode == "population", args.interval / 1000)
        print(json.dumps(result))
        return
    measurement = Measurement(args)
    print(f"# phases: {describe_cpu()}, python {sys.version.split()[0]}; one torch thread")
    rows, results = [], []
    for agent in args.agents.split(","):
        modes = [("single", args.seeds)] + ([("population", args.population)] if args.population else [])
        for mode, count in modes:
            command = [sys.executable, __file__, "--one", f"{agent}:{mode}:{count}"]
            child = subprocess.run(
                [*command, "--interval", str(args.interval)], capture_output=True, text=True, check=True
            )
            results.append(json.loads(child.stdout.strip().splitlines()[-1]))
            rows.append(row(results[-1]))
            print(" | ".join(rows[-1]), flush=True)
    columns = ["agent", "mode", "CPU s", "env steps", *PHASES]
    notes = ["Each phase's share of the CPU samples, and in brackets its CPU microseconds per env step."]
    table = Table(columns, rows, results=results, notes=notes)
    print(table.markdown())
    measurement.finish(table)


if __name__ == "__main__":
    main()
