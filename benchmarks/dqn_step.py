"""DQN's gradient step on its own: its time, a population's memory and CPU, and a fingerprint of its bits.

    python benchmarks/dqn_step.py step                       # us per gradient step, one seed, default preset
    python benchmarks/dqn_step.py step --seeds 100           # the same step for a population of 100
    python benchmarks/dqn_step.py memory --seeds 100 --steps 400
    python benchmarks/dqn_step.py fingerprint                # weight hashes of every DQN variant below
    python benchmarks/dqn_step.py table                      # step (1 and 100 seeds) and memory, a table

``time_to_solve.py`` and ``population.py`` measure whole runs; this script isolates what a change to
the update costs or saves, and whether it changed a bit:

- ``step``: fills each seed's replay with ``--warmup`` batched env steps (``learn()``), then times
  ``--repeats`` training rounds (``train()``: the preset's ``gradient_steps`` updates for every seed) and
  prints the median microseconds per gradient step, over ``--trials`` trials.
- ``memory``: ``--seeds`` seeds take ``--steps`` batched env steps with their updates (``learn()``, as in
  training, without evaluations or files); prints the process's peak RSS, its CPU seconds for those steps,
  and glibc's heap: its size and how much of it is in use (``mallinfo2``; where glibc has it).
- ``fingerprint``: seeds 3 and 5 as one population take ``--steps`` batched env steps under each of the
  tutorial presets, the default and variants of it (no double DQN, no target network, a dueling head,
  MSE with 1-step rows and hard target copies, gradient norms clipped to 0.5); prints a hash of each
  seed's online and target weights and its last loss. Run it at two commits: equal hashes, the same bits.
- ``table``: ``step`` for one seed and for ``--seeds`` (default 100; ``--repeats`` a tenth as many),
  and ``memory`` for ``--seeds``, each in a process of its own, as one table (``--table`` writes it).

One torch thread (``cartpole train``'s default), on the CPU.
"""

from __future__ import annotations

import argparse
import ctypes
import dataclasses
import hashlib
import json
import resource
import statistics
import subprocess
import sys
import time
from typing import Any

from cpu import describe_cpu
from table_file import Measurement, Table, add_table_arguments

FINGERPRINT_SEEDS = [3, 5]


def build(preset: str, seeds: list[int], **changes: Any) -> Any:
    """The registry's DQN population for ``seeds`` on CartPole-v1, the preset with ``changes``."""
    from cartpole.agents.registry import build_population, get_agent
    from cartpole.envs import env_info
    from cartpole.training.config import resolve_config

    spec = get_agent("dqn")
    config, _ = resolve_config("dqn", spec.config_cls, preset)
    config = dataclasses.replace(config, **changes)
    return build_population(spec, config, env_info("CartPole-v1"), seeds, "cpu")


def step_microseconds(args: argparse.Namespace) -> dict[str, Any]:
    import numpy as np

    population = build(args.preset, list(range(args.seeds)))
    for _ in range(args.warmup):
        population.learn()
    everyone = np.ones(args.seeds, dtype=bool)
    per_step = []
    for _ in range(args.trials):
        started = time.perf_counter()
        for _ in range(args.repeats):
            population.train(everyone)
        per_step.append((time.perf_counter() - started) / args.repeats / population.config.gradient_steps)
    return {
        "us_per_gradient_step": statistics.median(per_step) * 1e6,
        "trials_us": [round(t * 1e6, 1) for t in per_step],
        "batch_size": population.config.batch_size,
        "hidden_sizes": list(population.config.hidden_sizes),
    }


def heap_mb() -> tuple[float, float] | None:
    """glibc's heap (arena bytes, bytes in use) in MB; None without glibc's ``mallinfo2``."""

    fields = [
        "arena",
        "ordblks",
        "smblks",
        "hblks",
        "hblkhd",
        "usmblks",
        "fsmblks",
        "uordblks",
        "fordblks",
        "keepcost",
    ]

    class MallInfo2(ctypes.Structure):
        _fields_ = [(name, ctypes.c_size_t) for name in fields]

    try:
        mallinfo2 = ctypes.CDLL("libc.so.6").mallinfo2
    except (OSError, AttributeError):
        return None
    mallinfo2.restype = MallInfo2
    info = mallinfo2()
    return info.arena / 2**20, info.uordblks / 2**20


def memory_and_cpu(args: argparse.Namespace) -> dict[str, Any]:
    population = build(args.preset, list(range(args.seeds)))
    started = time.process_time()
    for _ in range(args.steps):
        population.learn()
    cpu = time.process_time() - started
    heap = heap_mb()
    return {
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "cpu_s": cpu,
        "heap_mb": None if heap is None else round(heap[0], 1),
        "heap_in_use_mb": None if heap is None else round(heap[1], 1),
    }


VARIANTS: dict[str, tuple[str, dict[str, Any]]] = {
    "default": ("default", {}),
    "tutorial-keras": ("tutorial-keras", {}),
    "tutorial-pytorch": ("tutorial-pytorch", {}),
    "no double DQN": ("default", {"double_dqn": False}),
    "no target network": ("default", {"target_network": False}),
    "dueling": ("default", {"dueling": True}),
    "mse, 1-step, hard target copies": (
        "default",
        {"loss": "mse", "n_step": 1, "tau": 1.0, "target_update_interval": 50},
    ),
    "gradient clipping": ("default", {"max_grad_norm": 0.5}),
}


def fingerprints(args: argparse.Namespace) -> dict[str, Any]:
    found = {}
    for name, (preset, changes) in VARIANTS.items():
        population = build(preset, FINGERPRINT_SEEDS, **changes)
        for _ in range(args.steps):
            population.learn()
        digest = hashlib.sha256()
        losses = []
        for seed in FINGERPRINT_SEEDS:
            tensors, data = population.seed_state_dict(seed, resume=True)
            for key in sorted(k for k in tensors if k.startswith(("q_net.", "target_net."))):
                digest.update(tensors[key].numpy().tobytes())
            losses.append(data["last_loss"])
        found[name] = {"hash": digest.hexdigest()[:16], "last_losses": losses}
    return found


def table(args: argparse.Namespace) -> Table:
    """``step`` for one seed and for ``args.seeds``, then ``memory`` for ``args.seeds``, each in a child
    process of its own (so the memory measure's peak is its own)."""

    def child(*options: str) -> dict[str, Any]:
        command = [sys.executable, __file__, *options, "--preset", args.preset, "--json"]
        done = subprocess.run(command, capture_output=True, text=True, check=True)
        return json.loads(done.stdout)

    timing = ["--warmup", str(args.warmup), "--trials", str(args.trials)]
    one = child("step", "--seeds", "1", "--repeats", str(args.repeats), *timing)
    many_repeats = str(max(1, args.repeats // 10))
    many = child("step", "--seeds", str(args.seeds), "--repeats", many_repeats, *timing)
    memory = child("memory", "--seeds", str(args.seeds), "--steps", str(args.steps))
    heap = (
        "-"
        if memory["heap_mb"] is None
        else f"{memory['heap_mb']:,.0f} MB ({memory['heap_in_use_mb']:,.0f} in use)"
    )
    rows = [
        ["one gradient step, 1 seed", f"{one['us_per_gradient_step']:,.0f} us"],
        [f"one gradient step, {args.seeds} seeds", f"{many['us_per_gradient_step']:,.0f} us"],
        [f"{args.seeds} seeds, {args.steps} batched env steps: peak RSS", f"{memory['peak_rss_mb']:,.0f} MB"],
        [f"{args.seeds} seeds, {args.steps} batched env steps: CPU", f"{memory['cpu_s']:.1f} s"],
        [f"{args.seeds} seeds: glibc heap", heap],
    ]
    notes = [f"Preset {args.preset!r}: batch {one['batch_size']}, hidden layers {one['hidden_sizes']}."]
    summary = {"step_1": one, f"step_{args.seeds}": many, "memory": memory}
    return Table(["measure", "figure"], rows, summary=summary, notes=notes)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("measure", choices=["step", "memory", "fingerprint", "table"])
    parser.add_argument("--preset", default="default", help="DQN preset (step, memory)")
    parser.add_argument("--seeds", type=int, help="seeds 0..N-1 (default: step 1, memory 100)")
    parser.add_argument("--steps", type=int, help="batched env steps (default: memory 400, fingerprint 300)")
    parser.add_argument("--warmup", type=int, default=300, help="step: batched env steps before timing")
    parser.add_argument("--repeats", type=int, default=200, help="step: training rounds per trial")
    parser.add_argument("--trials", type=int, default=5, help="step: timed trials (the median is printed)")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    add_table_arguments(parser)
    args = parser.parse_args(argv)
    defaults = {
        "step": (1, 0),
        "memory": (100, 400),
        "fingerprint": (len(FINGERPRINT_SEEDS), 300),
        "table": (100, 400),
    }
    seeds, steps = defaults[args.measure]
    args.seeds = seeds if args.seeds is None else args.seeds
    args.steps = steps if args.steps is None else args.steps
    for name in ("seeds", "steps", "warmup", "repeats", "trials"):
        least = 0 if name in ("steps", "warmup") else 1
        if getattr(args, name) < least:
            parser.error(f"--{name} must be at least {least}")

    if args.measure == "table":
        measurement = Measurement(args, [__file__, *(sys.argv[1:] if argv is None else argv)])
        found = table(args)
        print(found.markdown())
        measurement.finish(found)
        return 0
    import torch

    torch.set_num_threads(1)
    measure = {"step": step_microseconds, "memory": memory_and_cpu, "fingerprint": fingerprints}
    result = {"measure": args.measure, "machine": describe_cpu(), **measure[args.measure](args)}
    if args.measure != "fingerprint":
        result |= {"preset": args.preset, "seeds": args.seeds}
    if args.json:
        print(json.dumps(result))
        return 0
    for key, value in result.items():
        if isinstance(value, dict):
            print(f"{key}: {value['hash']}  last losses {value['last_losses']}")
        else:
            print(f"{key}: {round(value, 1) if isinstance(value, float) else value}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
