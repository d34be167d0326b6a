"""Time to solve CartPole-v1: each agent/preset over several seeds, next to Stable-Baselines3's agents.

Usage (from the repository root)::

    python benchmarks/time_to_solve.py                                  # all our agents, default presets
    python benchmarks/time_to_solve.py --agents dqn --presets default,tutorial-keras,tutorial-pytorch \\
        --seeds 10 --sb3 dqn --max-seconds-per-run 600
    python benchmarks/time_to_solve.py --agents ppo,a2c,reinforce --seeds 10 --sb3 ppo,a2c

Each run is one fresh subprocess (so torch thread settings and imports of one run cannot speed up or
slow down another) that calls :func:`cartpole.training.train` with the preset's own budget. Per run we
record the CPU time (``time.process_time``, all threads) and wall time from the start of training to
the in-training verified solve (the first full 100-episode evaluation on Gymnasium's env with mean >=
the threshold), the env steps at that moment, and the final verdict: the kept best checkpoint re-judged
by ``evaluate`` on 100 fresh episodes. SB3's DQN, PPO and A2C (RL Zoo's CartPole-v1 hyperparameters)
are judged by the same ``screened_evaluation`` at the cadence of our agent's default preset, with the
same stop rule. Every run uses one torch thread (our CLI's default; SB3 runs are set the same way).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from typing import Any

ALL_AGENTS = ("random-search", "hill-climbing", "cem", "dqn", "reinforce", "a2c", "ppo")
SB3_AGENTS = ("dqn", "ppo", "a2c")

# rl-baselines3-zoo, hyperparams/dqn.yml, "CartPole-v1" (marked "Almost Tuned" there).
SB3_ZOO_CARTPOLE = {
    "learning_rate": 2.3e-3,
    "batch_size": 64,
    "buffer_size": 100_000,
    "learning_starts": 1000,
    "gamma": 0.99,
    "target_update_interval": 10,
    "train_freq": 256,
    "gradient_steps": 128,
    "exploration_fraction": 0.16,
    "exploration_final_eps": 0.04,
    "policy_kwargs": {"net_arch": [256, 256]},
}
SB3_ZOO_STEPS = 50_000
"""The zoo's n_timesteps for CartPole-v1 (exploration_fraction is a share of this)."""

# rl-baselines3-zoo, hyperparams/ppo.yml and a2c.yml, "CartPole-v1" (n_envs, n_timesteps, then the
# algorithm's keyword arguments; "lin_X" is X times SB3's progress_remaining).
SB3_ZOO_ON_POLICY: dict[str, tuple[int, int, dict[str, Any]]] = {
    "ppo": (8, 100_000, {
        "n_steps": 32, "batch_size": 256, "gae_lambda": 0.8, "gamma": 0.98, "n_epochs": 20,
        "ent_coef": 0.0, "learning_rate": "lin_0.001", "clip_range": "lin_0.2",
    }),
    "a2c": (8, 500_000, {"ent_coef": 0.0}),
}  # fmt: skip


# ----------------------------------------------------------------------------------------------
# One run (in a subprocess)
# ----------------------------------------------------------------------------------------------


def warm_up(env_id: str) -> None:
    """Load what a first use loads (numba's cached kernels, Gymnasium's env modules) before timing.

    Like imports, this is paid once per process, not per training run.
    """
    import numpy as np

    from cartpole.evaluation import evaluate

    class Left:
        def act(self, observations: np.ndarray) -> np.ndarray:
            return np.zeros(len(observations), dtype=np.int64)

    for simulator in ("fast", "gymnasium"):
        evaluate(Left(), env_id, 2, seed=0, simulator=simulator)
    # Constructing any torch.optim optimizer imports torch._dynamo once per process (1.5-1.8 s of CPU
    # here): an import, paid before timing by every run, ours and SB3's alike.
    import torch

    torch.optim.Adam([torch.zeros(1, requires_grad=True)])


def run_ours(agent: str, preset: str, seed: int, max_seconds: float | None, env_id: str,
             budget_text: str | None = None) -> dict[str, Any]:  # fmt: skip
    """Train one seed of one of our agents (with the preset's budget unless ``budget_text``)."""
    import dataclasses

    import torch

    from cartpole.agents.registry import get_agent
    from cartpole.training import loop as loop_module
    from cartpole.training import train
    from cartpole.training.budget import parse_budget
    from cartpole.training.config import resolve_config

    torch.set_num_threads(1)  # what `cartpole train` sets by default (--torch-threads 1), once per process
    spec = get_agent(agent)
    _, settings = resolve_config(agent, spec.config_cls, preset)
    budget = parse_budget(budget_text or settings.budget)
    if max_seconds:
        budget = dataclasses.replace(budget, seconds=max_seconds)

    solve: dict[str, float] = {}
    record_eval = loop_module.TrainingLoop.record_eval

    def timed_record_eval(self: Any, report: Any) -> bool:  # note the CPU clock at the first solve
        if report.solved and "cpu" not in solve:
            solve["cpu"] = time.process_time() - cpu_start
            solve["wall"] = time.perf_counter() - wall_start
        return record_eval(self, report)

    loop_module.TrainingLoop.record_eval = timed_record_eval  # type: ignore[method-assign]
    warm_up(env_id)
    with tempfile.TemporaryDirectory() as runs_dir:
        cpu_start, wall_start = time.process_time(), time.perf_counter()
        outcome = train(agent, env_id, seed=seed, preset=preset, budget=budget, runs_dir=runs_dir,
                        device="cpu", quiet=True)  # fmt: skip
        cpu_total = time.process_time() - cpu_start
    state, report = outcome.state, outcome.report
    assert report is not None
    return {
        "agent": agent, "preset": preset, "seed": seed,
        "solved_in_training": state.solved, "solve_steps": state.solved_at_step,
        "solve_cpu": solve.get("cpu"), "solve_wall": solve.get("wall"),
        "env_steps": state.env_steps, "episodes": state.episodes, "cpu_total": cpu_total,
        "elapsed": state.elapsed, "gradient_steps": state.scalars.get("train/gradient_steps"),
        "final_mean": report.mean, "final_solved": report.solved, "stop_reason": state.stop_reason,
    }  # fmt: skip


def run_sb3(seed: int, max_seconds: float | None, env_id: str, eval_every: int, screen: int,
            total_steps: int) -> dict[str, Any]:  # fmt: skip
    """SB3 DQN with the RL Zoo's CartPole-v1 hyperparameters, judged exactly like our agents."""
    import dataclasses

    import gymnasium as gym
    import numpy as np
    import torch
    from stable_baselines3 import DQN
    from stable_baselines3.common.callbacks import BaseCallback

    from cartpole.agents.dqn import DQNConfig
    from cartpole.envs import env_info
    from cartpole.evaluation import evaluate
    from cartpole.training.callbacks import report_rank, screened_evaluation
    from cartpole.training.config import resolve_config

    torch.set_num_threads(1)  # the same thread setting as ours (`cartpole train --torch-threads 1`)
    # Judged exactly as our runs are (the same function), at our default preset's cadence.
    _, settings = resolve_config("dqn", DQNConfig, "default")
    settings = dataclasses.replace(settings, eval_every=eval_every, eval_screen_episodes=screen)
    env = env_info(env_id)

    class Adapter:
        """SB3 model -> our Policy (greedy actions)."""

        def __init__(self, model: Any):
            self.model = model

        def act(self, observations: np.ndarray) -> np.ndarray:
            return self.model.predict(observations, deterministic=True)[0]

    class Judge(BaseCallback):
        def __init__(self) -> None:
            super().__init__()
            self.last, self.evals, self.best, self.best_params = 0, 0, None, None
            self.solve: dict[str, float] = {}

        def _on_step(self) -> bool:
            if self.num_timesteps - self.last < eval_every:
                return True
            self.last = self.num_timesteps
            report = screened_evaluation(Adapter(self.model), env, seed, self.evals, settings)
            self.evals += 1
            if self.best is None or report_rank(report) > report_rank(self.best):
                self.best = report
                self.best_params = {k: v.clone() for k, v in self.model.policy.state_dict().items()}
            if report.solved:
                self.solve = {
                    "cpu": time.process_time() - cpu_start,
                    "wall": time.perf_counter() - wall_start,
                    "steps": self.num_timesteps,
                }
                return False
            return not (max_seconds and time.perf_counter() - wall_start > max_seconds)

    judge = Judge()
    warm_up(env_id)
    cpu_start, wall_start = time.process_time(), time.perf_counter()
    model = DQN("MlpPolicy", gym.make(env_id), seed=seed, device="cpu", verbose=0, **SB3_ZOO_CARTPOLE)
    # exploration_fraction is a share of the zoo's 50k steps, whatever total_steps we allow.
    model.exploration_schedule = _sb3_linear_schedule(SB3_ZOO_CARTPOLE, total_steps)
    model.learn(total_timesteps=total_steps, callback=judge)
    cpu_total = time.process_time() - cpu_start
    elapsed = time.perf_counter() - wall_start
    if judge.best_params is not None:
        model.policy.load_state_dict(judge.best_params)
    report = evaluate(Adapter(model), env_id, 100)
    return {
        "agent": "sb3-dqn", "preset": "rl-zoo", "seed": seed,
        "solved_in_training": bool(judge.solve), "solve_steps": judge.solve.get("steps"),
        "solve_cpu": judge.solve.get("cpu"), "solve_wall": judge.solve.get("wall"),
        "env_steps": model.num_timesteps, "episodes": None, "cpu_total": cpu_total, "elapsed": elapsed,
        "gradient_steps": float(model._n_updates), "final_mean": report.mean, "final_solved": report.solved,
        "stop_reason": "solved" if judge.solve else "budget",
    }  # fmt: skip


def run_sb3_on_policy(algo: str, seed: int, max_seconds: float | None, env_id: str, eval_every: int,
                      screen: int, total_steps: int | None) -> dict[str, Any]:  # fmt: skip
    """SB3 PPO or A2C with the RL Zoo's CartPole-v1 hyperparameters, judged exactly like our agents."""
    import dataclasses

    import numpy as np
    import stable_baselines3
    import torch
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.env_util import make_vec_env

    from cartpole.agents.registry import get_agent
    from cartpole.envs import env_info
    from cartpole.evaluation import evaluate
    from cartpole.training.callbacks import report_rank, screened_evaluation
    from cartpole.training.config import resolve_config

    torch.set_num_threads(1)
    _, settings = resolve_config(algo, get_agent(algo).config_cls, "default")
    settings = dataclasses.replace(settings, eval_every=eval_every, eval_screen_episodes=screen)
    env = env_info(env_id)
    n_envs, zoo_steps, zoo = SB3_ZOO_ON_POLICY[algo]
    total_steps = total_steps or zoo_steps
    kwargs = {k: _sb3_zoo_value(v) for k, v in zoo.items()}

    class Adapter:
        def __init__(self, model: Any):
            self.model = model

        def act(self, observations: np.ndarray) -> np.ndarray:
            return self.model.predict(observations, deterministic=True)[0]

    class Judge(BaseCallback):
        def __init__(self) -> None:
            super().__init__()
            self.last, self.evals, self.best, self.best_params = 0, 0, None, None
            self.solve: dict[str, float] = {}

        def _on_step(self) -> bool:
            if self.num_timesteps - self.last < eval_every:
                return True
            self.last = self.num_timesteps
            report = screened_evaluation(Adapter(self.model), env, seed, self.evals, settings)
            self.evals += 1
            if self.best is None or report_rank(report) > report_rank(self.best):
                self.best = report
                self.best_params = {k: v.clone() for k, v in self.model.policy.state_dict().items()}
            if report.solved:
                cpu, wall = time.process_time() - cpu_start, time.perf_counter() - wall_start
                self.solve = {"cpu": cpu, "wall": wall, "steps": self.num_timesteps}
                return False
            return not (max_seconds and time.perf_counter() - wall_start > max_seconds)

    judge = Judge()
    warm_up(env_id)
    cpu_start, wall_start = time.process_time(), time.perf_counter()
    algo_cls = {"ppo": stable_baselines3.PPO, "a2c": stable_baselines3.A2C}[algo]
    vec_env = make_vec_env(env_id, n_envs=n_envs, seed=seed)
    model = algo_cls("MlpPolicy", vec_env, seed=seed, device="cpu", verbose=0, **kwargs)
    model.learn(total_timesteps=total_steps, callback=judge)
    cpu_total = time.process_time() - cpu_start
    elapsed = time.perf_counter() - wall_start
    if judge.best_params is not None:
        model.policy.load_state_dict(judge.best_params)
    report = evaluate(Adapter(model), env_id, 100)
    return {
        "agent": f"sb3-{algo}", "preset": "rl-zoo", "seed": seed,
        "solved_in_training": bool(judge.solve), "solve_steps": judge.solve.get("steps"),
        "solve_cpu": judge.solve.get("cpu"), "solve_wall": judge.solve.get("wall"),
        "env_steps": model.num_timesteps, "episodes": None, "cpu_total": cpu_total, "elapsed": elapsed,
        "gradient_steps": float(model._n_updates), "final_mean": report.mean, "final_solved": report.solved,
        "stop_reason": "solved" if judge.solve else "budget",
    }  # fmt: skip


def _sb3_zoo_value(value: Any) -> Any:
    """The zoo's "lin_X" as SB3's schedule (X * progress_remaining); other values as they are."""
    if isinstance(value, str) and value.startswith("lin_"):
        start = float(value.removeprefix("lin_"))
        return lambda progress_remaining: start * progress_remaining
    return value


def _sb3_linear_schedule(zoo: dict[str, Any], total_steps: int) -> Any:
    """SB3's epsilon schedule expressed in the zoo's 50k steps, evaluated on our total_steps."""
    from stable_baselines3.common.utils import LinearSchedule

    fraction = zoo["exploration_fraction"] * SB3_ZOO_STEPS / total_steps
    return LinearSchedule(1.0, zoo["exploration_final_eps"], fraction)


# ----------------------------------------------------------------------------------------------
# The table
# ----------------------------------------------------------------------------------------------


def _fmt(value: float | None, spec: str) -> str:
    return "-" if value is None else format(value, spec)


def summarize(rows: list[dict[str, Any]]) -> dict[str, Any]:
    solved = [r for r in rows if r["solve_cpu"] is not None]
    # A seed that never solved counts as infinitely slow in the median.
    inf = float("inf")
    cpu = sorted(r["solve_cpu"] if r["solve_cpu"] is not None else inf for r in rows)
    steps = sorted(r["solve_steps"] if r["solve_steps"] is not None else inf for r in rows)
    wall = sorted(r["solve_wall"] if r["solve_wall"] is not None else inf for r in rows)
    elapsed = sum(r["elapsed"] for r in rows)
    grads = [r["gradient_steps"] for r in rows if r["gradient_steps"] is not None]
    return {
        "seeds": len(rows),
        "final_solved": sum(r["final_solved"] for r in rows),
        "train_solved": len(solved),
        "median_cpu": statistics.median(cpu), "worst_cpu": max(cpu),
        "median_wall": statistics.median(wall),
        "median_steps": statistics.median(steps), "worst_steps": max(steps),
        "final_min": min(r["final_mean"] for r in rows),
        "final_median": statistics.median(r["final_mean"] for r in rows),
        "sps": sum(r["env_steps"] for r in rows) / max(elapsed, 1e-9),
        "gps": sum(grads) / max(elapsed, 1e-9) if grads else None,
    }  # fmt: skip


def print_table(groups: dict[tuple[str, str], list[dict[str, Any]]], file: Any = sys.stdout) -> None:
    def num(value: float, spec: str) -> str:
        if value == float("inf"):
            return "never"
        if spec == ".1f" and value < 1:  # sub-second solves (the linear agents) need two digits
            spec = ".2f"
        return format(value, spec)

    header = ("| agent | preset | verified solves (final) | solved in training | median CPU s to solve "
              "| worst CPU s | median wall s | median env steps to solve | worst env steps "
              "| final eval mean: min / median | env steps/s | gradient steps/s |")  # fmt: skip
    print(header, file=file)
    print("|" + "---|" * (header.count("|") - 1), file=file)
    for (agent, preset), rows in groups.items():
        s = summarize(rows)
        cells = [
            agent, preset, f"{s['final_solved']}/{s['seeds']}", f"{s['train_solved']}/{s['seeds']}",
            num(s["median_cpu"], ".1f"), num(s["worst_cpu"], ".1f"), num(s["median_wall"], ".1f"),
            num(s["median_steps"], ",.0f"), num(s["worst_steps"], ",.0f"),
            f"{s['final_min']:.1f} / {s['final_median']:.1f}", f"{s['sps']:,.0f}", _fmt(s["gps"], ",.0f"),
        ]  # fmt: skip
        print("| " + " | ".join(cells) + " |", file=file)


# ----------------------------------------------------------------------------------------------
# Driver
# ----------------------------------------------------------------------------------------------


def print_run(result: dict[str, Any]) -> None:
    print(
        f"  {result['agent']:>14} {result['preset']:<17} seed {result['seed']:>2}: "
        f"solve at {_fmt(result['solve_steps'], ',')} steps, {_fmt(result['solve_cpu'], '.1f')} s CPU; "
        f"final {result['final_mean']:.1f} ({result['stop_reason']})",
        file=sys.stderr, flush=True,
    )  # fmt: skip


def run_in_subprocess(task: dict[str, Any]) -> dict[str, Any]:
    """Run one measurement in a fresh interpreter; return its JSON result.

    One torch thread, as ``cartpole train`` sets by default (``--threads 1``); SB3's runs set it too.
    """
    env = os.environ | {"PYTHONHASHSEED": "0", "OMP_NUM_THREADS": "1"}
    proc = subprocess.run(
        [sys.executable, __file__, "--one", json.dumps(task)],
        capture_output=True, text=True, env=env, check=False,
    )  # fmt: skip
    if proc.returncode != 0:
        raise RuntimeError(f"run {task} failed:\n{proc.stderr[-3000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--agents", default=",".join(ALL_AGENTS), help="comma-separated agent names")
    parser.add_argument("--presets", default="default",
                        help="comma-separated presets; each agent runs those it has")  # fmt: skip
    parser.add_argument("--seeds", type=int, default=10, help="seeds 0..N-1 per agent/preset")
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--env", default="CartPole-v1")
    parser.add_argument("--budget", default=None, help="our budget, e.g. 300k (default: the preset's)")
    parser.add_argument("--max-seconds-per-run", type=float, default=None,
                        help="wall-clock cap added to each run's budget")  # fmt: skip
    parser.add_argument("--sb3", nargs="?", const="dqn", default=None, metavar="AGENTS",
                        help="also measure SB3 with the RL Zoo's hyperparameters: "
                             "comma-separated dqn, ppo, a2c (--sb3 alone: dqn)")  # fmt: skip
    parser.add_argument("--sb3-steps", type=int, default=None,
                        help="SB3's env-step budget (default: DQN 100k, PPO/A2C the zoo's)")  # fmt: skip
    parser.add_argument("--sb3-eval-every", type=int, default=None,
                        help="SB3 evaluation cadence in env steps (default: ours)")  # fmt: skip
    parser.add_argument("--jobs", type=int, default=1,
                        help="runs at once (one torch thread each); CPU s include contention")  # fmt: skip
    parser.add_argument("--json", default=None,
                        help="also write every run's measurements here (after each run)")  # fmt: skip
    parser.add_argument("--one", default=None, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)

    if args.one:  # child process: one measurement, printed as JSON
        task = json.loads(args.one)
        if task["agent"] == "sb3-dqn":
            result = run_sb3(task["seed"], task["max_seconds"], task["env"], task["eval_every"],
                             task["screen"], task["total_steps"] or 100_000)  # fmt: skip
        elif task["agent"].startswith("sb3-"):
            algo = task["agent"].removeprefix("sb3-")
            result = run_sb3_on_policy(algo, task["seed"], task["max_seconds"], task["env"],
                                       task["eval_every"], task["screen"], task["total_steps"])  # fmt: skip
        else:
            result = run_ours(task["agent"], task["preset"], task["seed"], task["max_seconds"], task["env"],
                              task.get("budget"))  # fmt: skip
        print(json.dumps(result))
        return 0

    from cartpole.agents.presets import preset_names
    from cartpole.agents.registry import get_agent
    from cartpole.training.config import resolve_config

    tasks: list[dict[str, Any]] = []
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    for agent in [a.strip() for a in args.agents.split(",") if a.strip()]:
        get_agent(agent)
        for preset in [p.strip() for p in args.presets.split(",") if p.strip()]:
            if preset not in preset_names(agent):
                continue
            tasks += [{"agent": agent, "preset": preset, "seed": s, "max_seconds": args.max_seconds_per_run,
                       "env": args.env, "budget": args.budget} for s in seeds]  # fmt: skip
    if args.sb3:
        try:
            import stable_baselines3  # noqa: F401
        except ImportError:
            print("SB3 is not installed (pip install -e '.[bench]'); skipping it", file=sys.stderr)
        else:
            for sb3_agent in [a.strip() for a in args.sb3.split(",") if a.strip()]:
                if sb3_agent not in SB3_AGENTS:
                    parser.error(f"--sb3 takes {', '.join(SB3_AGENTS)}; got {sb3_agent!r}")
                _, settings = resolve_config(sb3_agent, get_agent(sb3_agent).config_cls, "default")
                every = args.sb3_eval_every or settings.eval_every
                base = {"agent": f"sb3-{sb3_agent}", "preset": "rl-zoo", "env": args.env,
                        "max_seconds": args.max_seconds_per_run, "eval_every": every,
                        "screen": settings.eval_screen_episodes, "total_steps": args.sb3_steps}  # fmt: skip
                tasks += [base | {"seed": s} for s in seeds]

    print(f"# time_to_solve: {args.env}, {len(tasks)} runs, {platform.processor() or platform.machine()}, "
          f"{os.cpu_count()} CPUs, python {platform.python_version()}", file=sys.stderr)  # fmt: skip
    if args.jobs > 1:
        print(f"# {args.jobs} runs at once, one torch thread each: CPU seconds include their contention",
              file=sys.stderr)  # fmt: skip
    groups: dict[tuple[str, str], list[dict[str, Any]]] = {}
    results = []
    with ThreadPoolExecutor(max_workers=max(1, args.jobs)) as pool:
        futures = [pool.submit(run_in_subprocess, task) for task in tasks]
        for future in futures:  # in task order, so the table's rows do not depend on timing
            result = future.result()
            results.append(result)
            groups.setdefault((result["agent"], result["preset"]), []).append(result)
            print_run(result)
            if args.json:
                with open(args.json, "w") as handle:
                    json.dump(results, handle, indent=1)
    print_table(groups)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
