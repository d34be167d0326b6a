"""Frames per second of the pixel renderer on one CPU core, beside the state simulator's steps.

    python benchmarks/renderer.py                      # the table (about a minute)
    python benchmarks/renderer.py --sizes 30x100 --envs 1,1024 --seconds 0.2
    python benchmarks/renderer.py --probe              # which frame size a small CNN learns from fastest

For each frame size and batch size N: frames/s of ``PixelRenderer.render`` on N pre-drawn states
(random, within the termination bounds), env steps/s of ``CartPolePixelsVectorEnv`` (physics,
autoreset, one frame per env, the 4-deep stack gathered into a new observation), and env steps/s of
the state simulator ``CartPoleVectorEnv`` alone (random actions, autoreset included). One row gives
Gymnasium's own path for scale: ``env.render()`` of CartPole-v1 (pygame, 600x400 RGB) then
``preprocess_frames``, one frame at a time.

The process is pinned to one CPU, numba and torch to one thread, before numpy, numba or torch are
imported. Time is this thread's CPU time (``time.thread_time``), so the figures are per core even on
a shared machine; each cell is the best of ``--repeats`` interleaved runs.

``--probe`` trains the same small CNN (three strided convolutions, one hidden layer) for the same
CPU time (``--probe-seconds``, one thread) to read the state (x, x_dot, theta, theta_dot of the
newest frame) from two stacked frames, at each frame size, on the same states; it prints the Adam
steps it took and the validation R^2 of each component. A proxy for "which size does an agent
learn from fastest": the policy needs exactly these four numbers, and larger frames cost more per
step.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from collections.abc import Callable
from typing import Any

# Before numpy/numba/torch are imported, or their thread pools would already be sized.
for _var in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"
os.environ.setdefault("SDL_VIDEODRIVER", "dummy")  # pygame without a display
os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402
from cpu import describe_cpu, pin_to_one_cpu  # noqa: E402
from table_file import Measurement, Table, add_table_arguments  # noqa: E402

from cartpole.envs.fast import CartPoleVectorEnv  # noqa: E402
from cartpole.envs.pixels import (  # noqa: E402
    DEFAULT_FRAME_SIZE,
    CartPolePixelsVectorEnv,
    PixelRenderer,
    preprocess_frames,
)

TARGET_FRAMES_PER_S = 1e5  # per core, at the default size, batched


def rate(call: Callable[[], Any], items: int, seconds: float) -> float:
    """Items per CPU-second of ``call`` (``items`` per call), repeated for at least ``seconds``."""
    calls = 0
    start = time.thread_time()
    while True:
        call()
        calls += 1
        elapsed = time.thread_time() - start
        if elapsed >= seconds:
            return calls * items / elapsed


def random_states(n: int, rng: np.random.Generator) -> np.ndarray:
    return np.column_stack(
        [rng.uniform(-2.4, 2.4, n), rng.normal(0, 1, n), rng.uniform(-0.21, 0.21, n), rng.normal(0, 1, n)]
    )


def measure(size: tuple[int, int], n: int, seconds: float, repeats: int) -> dict[str, float]:
    """Best rates of the renderer, the pixel vector env and the state simulator at ``size`` and ``n``."""
    rng = np.random.default_rng(0)
    renderer = PixelRenderer(size)
    batches = [random_states(n, rng) for _ in range(8)]
    out = np.empty((n, *size), dtype=np.uint8)
    cycle = iter(range(1 << 62))

    def render() -> None:
        renderer.render(batches[next(cycle) % len(batches)], out=out)

    pixels = CartPolePixelsVectorEnv(n, frame_size=size, dtype=np.float32)  # as training steps them
    states = CartPoleVectorEnv(n, dtype=np.float32)
    pixels.reset(seed=0)
    states.reset(seed=0)
    actions = list(rng.integers(0, 2, (64, n)))

    def stepper(env: Any) -> Callable[[], None]:
        def step() -> None:
            env.step(actions[next(cycle) % len(actions)])

        return step

    calls = {"render": render, "pixel env": stepper(pixels), "state env": stepper(states)}
    for call in calls.values():  # warm-up: load or compile the kernels
        call()
    best = dict.fromkeys(calls, 0.0)
    for _ in range(repeats):
        for name, call in calls.items():
            best[name] = max(best[name], rate(call, n, seconds))
    pixels.close()
    states.close()
    return best


def gymnasium_rate(size: tuple[int, int], seconds: float, repeats: int) -> float:
    """Frames/s of Gymnasium's render (pygame, 600x400 RGB) then preprocess_frames, one at a time."""
    env = gym.make("CartPole-v1", render_mode="rgb_array")
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    states = random_states(64, rng)
    cycle = iter(range(1 << 62))
    unwrapped: Any = env.unwrapped

    def frame() -> None:
        unwrapped.state = states[next(cycle) % len(states)]
        preprocess_frames(np.asarray(env.render())[None], size)

    frame()
    best = max(rate(frame, 1, seconds) for _ in range(repeats))
    env.close()
    return best


def parse_size(text: str) -> tuple[int, int]:
    height, width = text.lower().split("x")
    return int(height), int(width)


def table(args: argparse.Namespace) -> Table:
    sizes = [parse_size(s) for s in args.sizes.split(",")]
    envs = [int(n) for n in args.envs.split(",")]
    rows, rates = [], []
    best_default = 0.0
    for size in sizes:
        for n in envs:
            r = measure(size, n, args.seconds, args.repeats)
            rates.append({"size": list(size), "envs": n, **r})
            if size == DEFAULT_FRAME_SIZE:
                best_default = max(best_default, r["render"])
            label = f"{size[0]}x{size[1]}" + (" (default)" if size == DEFAULT_FRAME_SIZE else "")
            rows.append(
                [label, f"{n:,}", f"{r['render']:.3g}", f"{r['pixel env']:.3g}", f"{r['state env']:.3g}"]
            )
            print(" | ".join(rows[-1]), flush=True)
    size = sizes[0]
    gymnasium = gymnasium_rate(size, args.seconds, args.repeats)
    notes = [
        f"Gymnasium's CartPole-v1 `render()` + `preprocess_frames` at {size[0]}x{size[1]}, one frame at a "
        f"time: {gymnasium:.3g} frames/s."
    ]
    if best_default:
        verdict = "met" if best_default >= TARGET_FRAMES_PER_S else "NOT met"
        notes.append(
            f"Target >= {TARGET_FRAMES_PER_S:.0e} frames/s per core at {DEFAULT_FRAME_SIZE[0]}x"
            f"{DEFAULT_FRAME_SIZE[1]}: {best_default:.3g} ({verdict})."
        )
    columns = ["frame size", "N envs", "renderer frames/s", "pixel vector env steps/s (stack 4)",
               "state simulator steps/s"]  # fmt: skip
    return Table(columns, rows, summary={"rates": rates, "gymnasium_frames_per_s": gymnasium}, notes=notes)


def probe(args: argparse.Namespace) -> Table:
    """Train one small CNN per frame size to read the state from two stacked frames."""
    import torch
    from torch import nn

    torch.set_num_threads(1)
    sizes = [parse_size(s) for s in args.probe_sizes.split(",")]
    # States from a noisy balancing controller: long episodes, the angles and speeds an agent sees.
    rng = np.random.default_rng(0)
    sim = CartPoleVectorEnv(256, dtype=np.float64)
    sim.reset(seed=0)
    previous: list[np.ndarray] = []
    current: list[np.ndarray] = []
    state = sim.get_state()
    while sum(len(p) for p in previous) < args.probe_samples:
        x, x_dot, theta, theta_dot = state.T
        push = 10 * theta + 2 * theta_dot + 0.3 * x + 0.6 * x_dot + rng.normal(0, 1.5, len(x))
        _, _, terminated, truncated, _ = sim.step((push > 0).astype(np.int64))
        following = sim.get_state()
        kept = ~(terminated | truncated)  # a pair within one episode
        previous.append(state[kept])
        current.append(following[kept])
        state = following
    before, after = np.concatenate(previous), np.concatenate(current)
    order = rng.permutation(len(before))[: args.probe_samples]
    before, after = before[order], after[order]
    scale = np.array([2.4, 1.5, 0.21, 1.5])
    targets = torch.tensor(after / scale, dtype=torch.float32)
    n_val = len(after) // 5
    notes = [
        f"{len(after)} state pairs ({n_val} held out); a CNN per size, Adam on batches of 64 for "
        f"{args.probe_seconds:g} CPU s; validation R^2 of x, x_dot, theta, theta_dot."
    ]
    rows = []
    for size in sizes:
        renderer = PixelRenderer(size)
        frames = np.stack([renderer.render(before), renderer.render(after)], axis=1)
        inputs = torch.tensor(frames, dtype=torch.float32) / 255.0
        torch.manual_seed(0)
        net = nn.Sequential(
            nn.Conv2d(2, 16, 5, stride=2, padding=2),
            nn.ReLU(),
            nn.Conv2d(16, 32, 3, stride=2, padding=1),
            nn.ReLU(),
            nn.Conv2d(32, 32, 3, stride=2, padding=1),
            nn.ReLU(),
            nn.Flatten(),
            nn.LazyLinear(128),
            nn.ReLU(),
            nn.Linear(128, 4),
        )
        net(inputs[:1])
        optimizer = torch.optim.Adam(net.parameters(), lr=1e-3)
        train_x, train_y = inputs[n_val:], targets[n_val:]
        generator = torch.Generator().manual_seed(0)
        start, steps = time.process_time(), 0
        while time.process_time() - start < args.probe_seconds:
            batch = torch.randint(len(train_x), (64,), generator=generator)
            loss = ((net(train_x[batch]) - train_y[batch]) ** 2).mean()
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
            steps += 1
        with torch.no_grad():
            predicted = net(inputs[:n_val])
        truth = targets[:n_val]
        r2 = 1 - ((predicted - truth) ** 2).mean(0) / truth.var(0)
        rows.append([f"{size[0]}x{size[1]}", f"{size[0] * size[1]:,}", f"{steps:,}"])
        rows[-1] += [f"{v:.3f}" for v in r2.tolist()]
        print(" | ".join(rows[-1]), flush=True)
    columns = ["frame size", "pixels", "Adam steps", "R^2 x", "R^2 x_dot", "R^2 theta", "R^2 theta_dot"]
    return Table(columns, rows, notes=notes)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    parser.add_argument("--sizes", default="30x100,48x72,60x200", help="comma-separated HxW")
    parser.add_argument("--envs", default="1,64,1024", help="comma-separated numbers of envs")
    parser.add_argument("--seconds", type=float, default=0.5, help="length of one timed run")
    parser.add_argument("--repeats", type=int, default=3, help="interleaved runs per cell (best)")
    parser.add_argument("--cpu", type=int, default=None, help="CPU to pin to (default: first)")
    parser.add_argument("--probe", action="store_true", help="compare frame sizes with a small CNN")
    parser.add_argument("--probe-sizes", default="30x100,24x80,20x80,40x60,48x72")
    parser.add_argument("--probe-samples", type=int, default=20000)
    parser.add_argument("--probe-seconds", type=float, default=60.0, help="CPU seconds per size")
    add_table_arguments(parser)
    args = parser.parse_args(argv)
    measurement = Measurement(args, [__file__, *(sys.argv[1:] if argv is None else argv)])

    pinned = pin_to_one_cpu(args.cpu)
    import numba

    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(
        f"CPU: {describe_cpu()}, load average {load:.1f}; pinned to CPU {pinned}; one thread; "
        f"python {platform.python_version()}, numpy {np.__version__}, numba {numba.__version__}, "
        f"gymnasium {gym.__version__}; best of {args.repeats} x {args.seconds} s of CPU time\n"
    )
    result = probe(args) if args.probe else table(args)
    print(result.markdown())
    measurement.finish(result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
