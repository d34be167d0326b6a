"""Steps per second of our fast CartPole vs Gymnasium's, side by side, on one CPU core.

    python benchmarks/env_throughput.py                 # the full table (about a minute)
    python benchmarks/env_throughput.py --sizes 1,4096 --seconds 0.2 --no-compile-check

Random actions (pre-drawn, the same pool for every simulator), autoreset included: the vector envs
autoreset themselves; the single envs are reset by the loop when an episode ends, as a user would.
The process is pinned to one CPU and numba to one thread before numpy or numba are imported.

Time is this thread's CPU time (``time.thread_time``: user + system, page faults included), so the
figures are steps per second *of one core* even on a shared machine where other processes take
turns on it; ``--wall`` uses wall-clock time instead (the same on an idle machine). Each cell is the
best of ``--repeats`` interleaved runs, so what other processes do to caches hurts every simulator
alike and the best run is the least disturbed one.
"""

from __future__ import annotations

import argparse
import os
import platform
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

# Before numpy/numba are imported, or their thread pools would already be sized.
for _var in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402
from cpu import describe_cpu, pin_to_one_cpu  # noqa: E402
from table_file import Measurement, Table, add_table_arguments  # noqa: E402

TARGET_STEPS_PER_S = 1e8  # at 65,536 envs, float32
TARGET_SPEEDUP = 3.0  # over Gymnasium's CartPoleVectorEnv at 4,096 envs
ENV_ID = "CartPole-v1"


CLOCK: Callable[[], float] = time.thread_time  # see the module docstring; --wall changes it


def steps_per_second(
    step: Callable[[Any], Any], actions: Sequence[Any], n_envs: int, seconds: float
) -> float:
    """Env steps per second of ``step`` cycling through ``actions`` for at least ``seconds``."""
    calls = 0
    start = CLOCK()
    while True:
        for a in actions:
            step(a)
        calls += len(actions)
        elapsed = CLOCK() - start
        if elapsed >= seconds:
            return calls * n_envs / elapsed


@dataclass
class Contender:
    """One simulator in one table row: how to build it, and its best rate so far."""

    name: str
    make: Callable[[], Any]
    single: bool = False
    best: float = 0.0


def vector_contenders(n: int) -> list[Contender]:
    from cartpole.envs.fast import register_fast_envs

    register_fast_envs()

    def make(env_id: str, **kwargs: Any) -> Callable[[], Any]:
        return lambda: gym.make_vec(env_id, num_envs=n, vectorization_mode="vector_entry_point", **kwargs)

    return [
        Contender("gymnasium", make(ENV_ID)),
        Contender("fast float32", make("cartpole/" + ENV_ID, dtype=np.float32)),
        Contender("fast float64", make("cartpole/" + ENV_ID, dtype=np.float64)),
    ]


def single_contenders() -> list[Contender]:
    from cartpole.envs.fast import register_fast_envs

    register_fast_envs()
    return [
        Contender("gymnasium", lambda: gym.make(ENV_ID), single=True),
        Contender("fast float64", lambda: gym.make("cartpole/" + ENV_ID), single=True),
        Contender("fast float32", lambda: gym.make("cartpole/" + ENV_ID, dtype=np.float32), single=True),
    ]


def measure(contenders: list[Contender], n: int, seconds: float, repeats: int) -> None:
    """Fill each contender's ``best`` with its best of ``repeats`` interleaved runs."""
    rng = np.random.default_rng(0)
    envs = [c.make() for c in contenders]
    steppers: list[Callable[[Any], Any]] = []
    for c, env in zip(contenders, envs, strict=True):
        env.reset(seed=0)
        if c.single:

            def step(a: int, env: Any = env) -> None:
                _, _, terminated, truncated, _ = env.step(a)
                if terminated or truncated:
                    env.reset()

            steppers.append(step)
        else:
            steppers.append(env.step)
    if contenders[0].single:
        actions: list[Any] = [int(a) for a in rng.integers(0, 2, 1024)]
    else:
        actions = list(rng.integers(0, 2, (64, n)))
    for stepper in steppers:  # warm-up: compile or load kernels, fill caches
        steps_per_second(stepper, actions[:8], n, 0.0)
    for _ in range(repeats):
        for c, stepper in zip(contenders, steppers, strict=True):
            c.best = max(c.best, steps_per_second(stepper, actions, n, seconds))
    for env in envs:
        env.close()


STARTUP_PROBE = """
import time
t0 = time.perf_counter()
import numpy as np
import cartpole.envs.fast as fast
t1 = time.perf_counter()
import sys
numba_at_import = "numba" in sys.modules
out = [f"import {t1 - t0:.3f} s (numba imported: {numba_at_import})"]
for dtype in (np.float32, np.float64):
    t, c = time.perf_counter(), time.process_time()
    env = fast.CartPoleVectorEnv(num_envs=4, dtype=dtype)
    env.reset(seed=0)
    env.step(np.zeros(4, dtype=np.int64))
    single = fast.CartPoleEnv(dtype=dtype)
    single.reset(seed=0)
    single.step(0)
    wall, cpu = time.perf_counter() - t, time.process_time() - c
    out.append(f"{np.dtype(dtype).name} first steps: {wall:.2f} s ({cpu:.2f} s CPU)")
print("; ".join(out))
"""


def startup_costs() -> list[tuple[str, str]]:
    """Import time and first-step time, with numba's on-disk cache empty (cold) and filled (warm)."""
    rows = []
    with tempfile.TemporaryDirectory() as cache:
        env = {**os.environ, "NUMBA_CACHE_DIR": cache}
        for label in ("cold cache (compiles)", "warm cache (loads)"):
            result = subprocess.run(
                [sys.executable, "-c", STARTUP_PROBE],
                env=env,
                capture_output=True,
                text=True,
                check=False,
            )
            text = result.stdout.strip() or result.stderr.strip().splitlines()[-1]
            rows.append((label, text))
    return rows


def fmt(rate: float) -> str:
    return f"{rate:.3g}"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", default="1,16,256,4096,65536", help="comma-separated num_envs")
    parser.add_argument("--seconds", type=float, default=0.5, help="length of one timed run")
    parser.add_argument("--repeats", type=int, default=3, help="interleaved runs per cell (best)")
    parser.add_argument("--cpu", type=int, default=None, help="CPU to pin to (default: first)")
    parser.add_argument("--no-compile-check", action="store_true", help="skip the start-up probe")
    parser.add_argument("--wall", action="store_true", help="time by wall clock, not CPU time")
    add_table_arguments(parser)
    args = parser.parse_args(argv)
    measurement = Measurement(args, [__file__, *(sys.argv[1:] if argv is None else argv)])
    global CLOCK
    CLOCK = time.perf_counter if args.wall else time.thread_time
    sizes = [int(s) for s in args.sizes.split(",")]

    pinned = pin_to_one_cpu(args.cpu)
    import numba

    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    clock = "wall-clock time" if args.wall else "CPU time of this thread"
    print(
        f"CPU: {describe_cpu()}, load average {load:.1f}; pinned to CPU "
        f"{pinned}; NUMBA_NUM_THREADS=1 (one core); timed by {clock}"
    )
    print(
        f"python {platform.python_version()}, numpy {np.__version__}, numba {numba.__version__}, "
        f"gymnasium {gym.__version__}; {ENV_ID}, random actions, autoreset included; "
        f"best of {args.repeats} x {args.seconds} s"
    )

    rows = []
    rates: dict[str, dict[str, float]] = {}
    for n in sizes:
        contenders = vector_contenders(n)
        measure(contenders, n, args.seconds, args.repeats)
        rates[str(n)] = {c.name: c.best for c in contenders}
        rows.append([f"{n:,}", *cells(contenders)])
    singles = single_contenders()
    measure(singles, 1, args.seconds, args.repeats)
    rates["single"] = {c.name: c.best for c in singles}
    rows.append(["1, a single env (`gymnasium.make`, wrappers included)", *cells(singles)])
    notes = target_checks(rates)
    if not args.no_compile_check:
        notes.append("")
        notes.append("Start-up (fresh process; first reset+step of a vector and a single env per dtype):")
        notes += [f"- {label}: {text}" for label, text in startup_costs()]
    columns = ["num_envs", "Gymnasium's CartPole", "fast float32 (speed-up)", "fast float64 (speed-up)"]
    table = Table(columns, rows, summary={"steps_per_s": rates}, notes=notes)
    print(table.markdown())
    measurement.finish(table)
    return 0


def cells(contenders: list[Contender]) -> list[str]:
    """Gymnasium's rate, then each fast simulator's with its speed-up over it (float32 first)."""
    by_name = {c.name: c.best for c in contenders}
    base = by_name["gymnasium"]
    return [fmt(base)] + [
        f"{fmt(by_name[name])} ({by_name[name] / base:.1f}x)" for name in ("fast float32", "fast float64")
    ]


def target_checks(rates: dict[str, dict[str, float]]) -> list[str]:
    checks = []
    if "65536" in rates:
        r = rates["65536"]["fast float32"]
        ok = "met" if r >= TARGET_STEPS_PER_S else "NOT met"
        checks.append(f">= {TARGET_STEPS_PER_S:.0e} steps/s at 65,536 envs: {fmt(r)} ({ok})")
    if "4096" in rates:
        x = rates["4096"]["fast float32"] / rates["4096"]["gymnasium"]
        ok = "met" if x >= TARGET_SPEEDUP else "NOT met"
        checks.append(f">= {TARGET_SPEEDUP:g}x Gymnasium at 4,096 envs: {x:.1f}x ({ok})")
    if "1" in rates:
        x = rates["1"]["fast float32"] / rates["single"]["gymnasium"]
        ok = "met" if x >= 1 else "NOT met"
        checks.append(f"vector env at N=1 vs Gymnasium's single env: {x:.2f}x ({ok})")
    return ["Targets: " + "; ".join(checks) + "."] if checks else []


if __name__ == "__main__":
    sys.exit(main())
