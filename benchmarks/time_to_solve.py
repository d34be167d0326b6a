"""Time to solve CartPole-v1: each agent/preset over several seeds, next to Stable-Baselines3's agents.

Usage (from the repository root)::

    python benchmarks/time_to_solve.py                                  # all our agents, default presets
    python benchmarks/time_to_solve.py --agents dqn --presets default,tutorial-keras,tutorial-pytorch \\
        --seeds 10 --sb3 dqn --max-seconds-per-run 600
    python benchmarks/time_to_solve.py --agents ppo,a2c,reinforce --seeds 10 --sb3 ppo,a2c
    python benchmarks/time_to_solve.py --agents ppo,dqn --seeds 3 --sb3 ppo,dqn --tianshou ppo,dqn
    python benchmarks/time_to_solve.py --env Acrobot-v1 --agents cem,ppo:acrobot --seeds 5

Each run is one fresh subprocess (so torch thread settings and imports of one run cannot speed up or
slow down another) that calls :func:`cartpole.training.train` with the preset's own budget. Per run we
record the CPU time (``time.process_time``, all threads) and wall time from the start of training to
the in-training verified solve (the default presets' rule: a full 100-episode evaluation with mean >=
the threshold, confirmed by the next 100 episodes, both played on our float64 simulator, which plays
Gymnasium's episodes bit for bit), the env steps at that moment, and the final verdict: the kept best
checkpoint re-judged by ``evaluate`` on 100 fresh episodes of Gymnasium's own env. SB3's DQN, PPO and
A2C (RL Zoo's CartPole-v1 hyperparameters) are judged by the same ``screened_evaluation`` with our
agent's default preset's settings (cadence, screen, confirmation, simulator), with the same stop
rule. Tianshou's DQN and PPO (the settings of its own CartPole test scripts) are judged the same way,
after each of its trainer's collect-and-update steps. Every run uses one torch thread (our CLI's
default; SB3's and Tianshou's runs are set the same way).
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

from cpu import describe_cpu
from table_file import Measurement, Table, add_table_arguments

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
# The zoo's settings for other envs, where it has them (its "LunarLander-v2", on Gymnasium's v3).
SB3_ZOO_ON_POLICY_BY_ENV: dict[str, dict[str, tuple[int, int, dict[str, Any]]]] = {
    "LunarLander-v3": {
        "ppo": (16, 1_000_000, {
            "n_steps": 1024, "batch_size": 64, "gae_lambda": 0.98, "gamma": 0.999, "n_epochs": 4,
            "ent_coef": 0.01,
        }),
    },
}  # fmt: skip


def sb3_zoo_on_policy(algo: str, env_id: str) -> tuple[int, int, dict[str, Any]]:
    """The RL Zoo's settings of SB3's ``algo`` for ``env_id`` (its CartPole-v1 ones where it lists none)."""
    return SB3_ZOO_ON_POLICY_BY_ENV.get(env_id, {}).get(algo) or SB3_ZOO_ON_POLICY[algo]


TIANSHOU_AGENTS = ("dqn", "ppo")
TIANSHOU_PRESET = "test-0.5.1"
"""The preset column of Tianshou's rows: its own test scripts' settings, release 0.5.1."""

# Tianshou 0.5.1 (the newest release that installs beside requirements.lock), test/discrete/test_dqn.py and
# test/discrete/test_ppo.py, get_args() defaults: the library's own discrete CartPole scripts (its
# examples/ has none for CartPole). Written for CartPole-v0 (--task), run here on CartPole-v1 unchanged.
# The budget is epoch x step_per_epoch env steps.
TIANSHOU_CARTPOLE: dict[str, dict[str, Any]] = {
    "dqn": {
        "hidden_sizes": [128, 128, 128, 128], "lr": 1e-3, "gamma": 0.9, "n_step": 3,
        "target_update_freq": 320, "buffer_size": 20_000, "training_num": 10, "batch_size": 64,
        "step_per_collect": 10, "update_per_step": 0.1, "eps_train": 0.1, "epoch": 20,
        "step_per_epoch": 10_000,
    },
    "ppo": {
        "hidden_sizes": [64, 64], "lr": 3e-4, "gamma": 0.99, "buffer_size": 20_000, "training_num": 20,
        "step_per_collect": 2000, "repeat_per_collect": 10, "batch_size": 64, "epoch": 10,
        "step_per_epoch": 50_000, "vf_coef": 0.5, "ent_coef": 0.0, "eps_clip": 0.2, "max_grad_norm": 0.5,
        "gae_lambda": 0.95, "rew_norm": 0, "norm_adv": 0, "recompute_adv": 0, "dual_clip": None,
        "value_clip": 0,
    },
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
    # Our greedy MLP policies' compiled forward pass and episode loop (agents/nn/greedy_play.py).
    from torch import nn

    from cartpole.agents.nn.numpy_mlp import NumpyMLP

    class Network:
        def __init__(self) -> None:
            self.network = NumpyMLP([nn.Linear(4, 2)])

        def act(self, observations: np.ndarray) -> np.ndarray:
            return self.network(observations).argmax(axis=1)

        def play_cartpole(self, *args: Any) -> Any:
            return self.network.play_cartpole(*args)

    if env_id in ("CartPole-v1", "CartPole-v0"):
        evaluate(Network(), env_id, 2, seed=0, simulator="fast")
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

    from cartpole.agents.dqn.config import DQNConfig
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
    """SB3 PPO or A2C with the RL Zoo's hyperparameters for the env (:func:`sb3_zoo_on_policy`), judged
    exactly like our agents (with our agent's preset for the env: its cadence, screen and rule)."""
    import dataclasses

    import numpy as np
    import stable_baselines3
    import torch
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.env_util import make_vec_env

    from cartpole.agents.presets import env_preset
    from cartpole.agents.registry import get_agent
    from cartpole.envs import env_info
    from cartpole.evaluation import evaluate
    from cartpole.training.callbacks import report_rank, screened_evaluation
    from cartpole.training.config import resolve_config

    torch.set_num_threads(1)
    _, settings = resolve_config(algo, get_agent(algo).config_cls, env_preset(algo, env_id))
    settings = dataclasses.replace(settings, eval_every=eval_every, eval_screen_episodes=screen)
    env = env_info(env_id)
    n_envs, zoo_steps, zoo = sb3_zoo_on_policy(algo, env_id)
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


def run_tianshou(algo: str, seed: int, max_seconds: float | None, env_id: str, eval_every: int,
                 screen: int, total_steps: int | None) -> dict[str, Any]:  # fmt: skip
    """Tianshou's DQN or PPO with its CartPole test scripts' settings, judged exactly like our agents.

    Tianshou's own trainer runs the script's loop (its test collector left out); after each of the
    trainer's collect-and-update steps the judge evaluates when ``eval_every`` env steps have passed.
    """
    import dataclasses

    import torch
    from tianshou.trainer import OffpolicyTrainer, OnpolicyTrainer

    from cartpole.agents.registry import get_agent
    from cartpole.envs import env_info
    from cartpole.evaluation import evaluate
    from cartpole.training.config import resolve_config

    torch.set_num_threads(1)
    _, settings = resolve_config(algo, get_agent(algo).config_cls, "default")
    settings = dataclasses.replace(settings, eval_every=eval_every, eval_screen_episodes=screen)
    settings_ts = TIANSHOU_CARTPOLE[algo]
    epochs = -(-total_steps // settings_ts["step_per_epoch"]) if total_steps else settings_ts["epoch"]
    judge = TianshouJudge(env_info(env_id), seed, settings, max_seconds)
    warm_up(env_id)
    judge.start_clock()
    build = {"dqn": _tianshou_dqn, "ppo": _tianshou_ppo}[algo]
    policy, collector, prefill, trainer_kwargs = build(env_id, seed, settings_ts)
    trainer_cls = {"dqn": OffpolicyTrainer, "ppo": OnpolicyTrainer}[algo]
    trainer = _judged_trainer(trainer_cls, judge, prefill)(
        policy=policy, train_collector=collector, test_collector=None, max_epoch=epochs,
        step_per_epoch=settings_ts["step_per_epoch"], step_per_collect=settings_ts["step_per_collect"],
        batch_size=settings_ts["batch_size"], episode_per_test=0, verbose=False, show_progress=False,
        **trainer_kwargs,
    )  # fmt: skip
    trainer.run()
    cpu_total, elapsed = judge.clock()
    if judge.best_params is not None:
        policy.load_state_dict(judge.best_params)
    policy.eval()
    report = evaluate(TianshouGreedy(policy), env_id, 100)
    return {
        "agent": f"tianshou-{algo}", "preset": TIANSHOU_PRESET, "seed": seed,
        "solved_in_training": bool(judge.solve), "solve_steps": judge.solve.get("steps"),
        "solve_cpu": judge.solve.get("cpu"), "solve_wall": judge.solve.get("wall"),
        "env_steps": prefill + trainer.env_step, "episodes": None, "cpu_total": cpu_total,
        "elapsed": elapsed, "gradient_steps": float(trainer.gradient_step), "final_mean": report.mean,
        "final_solved": report.solved, "stop_reason": "solved" if judge.solve else "budget",
    }  # fmt: skip


class TianshouGreedy:
    """Tianshou policy -> our Policy: its greedy action (DQN's argmax Q, PPO's deterministic_eval)."""

    def __init__(self, policy: Any):
        self.policy = policy

    def act(self, observations: Any) -> Any:
        import torch
        from tianshou.data import Batch, to_numpy

        with torch.no_grad():
            return to_numpy(self.policy(Batch(obs=observations, info=Batch())).act)


class TianshouJudge:
    """The SB3 callbacks' judge for a Tianshou policy: ``screened_evaluation`` every ``eval_every`` env
    steps, the best parameters kept (``report_rank``), the clock read at the first verified solve."""

    def __init__(self, env: Any, seed: int, settings: Any, max_seconds: float | None):
        self.env, self.seed, self.settings, self.max_seconds = env, seed, settings, max_seconds
        self.last, self.evals = 0, 0
        self.best: Any = None
        self.best_params: dict[str, Any] | None = None
        self.solve: dict[str, float] = {}
        self.cpu_start = self.wall_start = 0.0

    def start_clock(self) -> None:
        self.cpu_start, self.wall_start = time.process_time(), time.perf_counter()

    def clock(self) -> tuple[float, float]:
        """CPU and wall seconds since ``start_clock``."""
        return time.process_time() - self.cpu_start, time.perf_counter() - self.wall_start

    def should_stop(self, policy: Any, env_steps: int) -> bool:
        """Judge the policy if ``eval_every`` env steps passed since the last evaluation."""
        from cartpole.training.callbacks import report_rank

        if env_steps - self.last < self.settings.eval_every:
            return False
        self.last = env_steps
        report = self.evaluate(policy)
        self.evals += 1
        if self.best is None or report_rank(report) > report_rank(self.best):
            self.best = report
            self.best_params = {k: v.clone() for k, v in policy.state_dict().items()}
        if report.solved:
            cpu, wall = self.clock()
            self.solve = {"cpu": cpu, "wall": wall, "steps": env_steps}
            return True
        return bool(self.max_seconds and self.clock()[1] > self.max_seconds)

    def evaluate(self, policy: Any) -> Any:
        """Our in-training evaluation of the greedy policy (Tianshou's train mode restored after)."""
        from cartpole.training.callbacks import screened_evaluation

        training = policy.training
        policy.eval()
        try:
            return screened_evaluation(TianshouGreedy(policy), self.env, self.seed, self.evals, self.settings)
        finally:
            policy.train(training)


def _judged_trainer(trainer_cls: Any, judge: TianshouJudge, prefill: int) -> Any:
    """``trainer_cls`` whose every collect-and-update step ends with the judge (which may stop it)."""

    class JudgedTrainer(trainer_cls):
        def policy_update_fn(self, data: dict[str, Any], result: dict[str, Any]) -> None:
            super().policy_update_fn(data, result)
            if judge.should_stop(self.policy, prefill + self.env_step):
                self.stop_fn_flag = True  # Tianshou's own flag: the epoch ends, then training

    return JudgedTrainer


def _tianshou_seeded_envs(env_id: str, seed: int, count: int) -> Any:
    """test_*.py's seeding: NumPy's and torch's global seeds, then the training envs (seed + i)."""
    import gymnasium as gym
    import numpy as np
    import torch
    from tianshou.env import DummyVectorEnv

    envs = DummyVectorEnv([lambda: gym.make(env_id) for _ in range(count)])
    np.random.seed(seed)
    torch.manual_seed(seed)
    envs.seed(seed)
    return envs


def _tianshou_dqn(env_id: str, seed: int, s: dict[str, Any]) -> tuple[Any, Any, int, dict[str, Any]]:
    """test_dqn.py's policy and collector, its buffer prefilled as there; the trainer's extra arguments."""
    import gymnasium as gym
    import torch
    from tianshou.data import Collector, VectorReplayBuffer
    from tianshou.policy import DQNPolicy
    from tianshou.utils.net.common import Net

    space: Any = gym.make(env_id)  # its spaces, as the script reads them
    envs = _tianshou_seeded_envs(env_id, seed, s["training_num"])
    net = Net(
        space.observation_space.shape, space.action_space.n, hidden_sizes=s["hidden_sizes"], device="cpu"
    )
    optim = torch.optim.Adam(net.parameters(), lr=s["lr"])
    policy = DQNPolicy(net, optim, s["gamma"], s["n_step"], target_update_freq=s["target_update_freq"])
    buffer = VectorReplayBuffer(s["buffer_size"], buffer_num=len(envs))
    collector = Collector(policy, envs, buffer, exploration_noise=True)
    prefill = s["batch_size"] * s["training_num"]
    collector.collect(n_step=prefill)
    train_fn = _tianshou_dqn_epsilon(policy, s["eps_train"])
    return policy, collector, prefill, {"update_per_step": s["update_per_step"], "train_fn": train_fn}


def _tianshou_dqn_epsilon(policy: Any, eps_train: float) -> Any:
    """test_dqn.py's train_fn: epsilon eps_train to 10k env steps, then linear to a tenth of it at 50k."""

    def train_fn(epoch: int, env_step: int) -> None:
        if env_step <= 10_000:
            policy.set_eps(eps_train)
        elif env_step <= 50_000:
            policy.set_eps(eps_train - (env_step - 10_000) / 40_000 * (0.9 * eps_train))
        else:
            policy.set_eps(0.1 * eps_train)

    return train_fn


def _tianshou_ppo(env_id: str, seed: int, s: dict[str, Any]) -> tuple[Any, Any, int, dict[str, Any]]:
    """test_ppo.py's policy (CPU branch: shared trunk, orthogonal init) and collector; the trainer's extra
    arguments."""
    import gymnasium as gym
    import torch
    from tianshou.data import Collector, VectorReplayBuffer
    from tianshou.policy import PPOPolicy
    from tianshou.utils.net.common import ActorCritic, Net
    from tianshou.utils.net.discrete import Actor, Critic

    space: Any = gym.make(env_id)  # its spaces, as the script reads them
    envs = _tianshou_seeded_envs(env_id, seed, s["training_num"])
    net = Net(space.observation_space.shape, hidden_sizes=s["hidden_sizes"], device="cpu")
    actor = Actor(net, space.action_space.n, device="cpu")
    critic = Critic(net, device="cpu")
    actor_critic = ActorCritic(actor, critic)
    for module in actor_critic.modules():
        if isinstance(module, torch.nn.Linear):
            torch.nn.init.orthogonal_(module.weight)
            torch.nn.init.zeros_(module.bias)
    optim = torch.optim.Adam(actor_critic.parameters(), lr=s["lr"])
    policy = PPOPolicy(
        actor, critic, optim, torch.distributions.Categorical, discount_factor=s["gamma"],
        max_grad_norm=s["max_grad_norm"], eps_clip=s["eps_clip"], vf_coef=s["vf_coef"],
        ent_coef=s["ent_coef"], gae_lambda=s["gae_lambda"], reward_normalization=s["rew_norm"],
        dual_clip=s["dual_clip"], value_clip=s["value_clip"], action_space=space.action_space,
        deterministic_eval=True, advantage_normalization=s["norm_adv"],
        recompute_advantage=s["recompute_adv"],
    )  # fmt: skip
    collector = Collector(policy, envs, VectorReplayBuffer(s["buffer_size"], len(envs)))
    return policy, collector, 0, {"repeat_per_collect": s["repeat_per_collect"]}


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


COLUMNS = [
    "agent", "preset", "verified solves (final)", "solved in training", "median CPU s to solve",
    "worst CPU s", "median wall s", "median env steps to solve", "worst env steps",
    "final eval mean: min / median", "env steps/s", "gradient steps/s",
]  # fmt: skip


def table_of(groups: dict[tuple[str, str], list[dict[str, Any]]], env_id: str, jobs: int) -> Table:
    """A row per (agent, preset); the summary keeps each group's figures for the README."""

    def num(value: float, spec: str) -> str:
        if value == float("inf"):
            return "never"
        if spec == ".1f" and value < 1:  # sub-second solves (the linear agents) need two digits
            spec = ".2f"
        return format(value, spec)

    rows, summaries = [], []
    for (agent, preset), runs in groups.items():
        s = summarize(runs)
        summaries.append({"agent": agent, "preset": preset, **s})
        rows.append([
            agent, preset, f"{s['final_solved']}/{s['seeds']}", f"{s['train_solved']}/{s['seeds']}",
            num(s["median_cpu"], ".1f"), num(s["worst_cpu"], ".1f"), num(s["median_wall"], ".1f"),
            num(s["median_steps"], ",.0f"), num(s["worst_steps"], ",.0f"),
            f"{s['final_min']:.2f} / {s['final_median']:.2f}", f"{s['sps']:,.0f}", _fmt(s["gps"], ",.0f"),
        ])  # fmt: skip
    notes = []
    if jobs > 1:
        notes.append(f"{jobs} runs at once, one torch thread each: CPU seconds include their contention.")
    return Table(COLUMNS, rows, summary={"env": env_id, "groups": summaries}, notes=notes)


# ----------------------------------------------------------------------------------------------
# Driver
# ----------------------------------------------------------------------------------------------


def print_run(result: dict[str, Any]) -> None:
    print(
        f"  {result['agent']:>14} {result['preset']:<17} seed {result['seed']:>2}: "
        f"solve at {_fmt(result['solve_steps'], ',')} steps, {_fmt(result['solve_cpu'], '.1f')} s CPU; "
        f"final {result['final_mean']:.2f} ({'verified' if result['final_solved'] else 'NOT solved'}; "
        f"training stopped: {result['stop_reason']})",
        file=sys.stderr, flush=True,
    )  # fmt: skip


def run_in_subprocess(task: dict[str, Any]) -> dict[str, Any]:
    """Run one measurement in a fresh interpreter; return its JSON result.

    One torch thread, as ``cartpole train`` sets by default (``--torch-threads 1``); SB3's runs set it too.
    """
    env = os.environ | {"PYTHONHASHSEED": "0", "OMP_NUM_THREADS": "1"}
    proc = subprocess.run(
        [sys.executable, __file__, "--one", json.dumps(task)],
        capture_output=True, text=True, env=env, check=False,
    )  # fmt: skip
    if proc.returncode != 0:
        raise RuntimeError(f"run {task} failed:\n{proc.stderr[-3000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def tianshou_tasks(
    parser: argparse.ArgumentParser, args: argparse.Namespace, seeds: range
) -> list[dict[str, Any]]:
    """--tianshou's runs, at our default preset's evaluation cadence (none if Tianshou is missing)."""
    from cartpole.agents.registry import get_agent
    from cartpole.training.config import resolve_config

    try:
        import tianshou  # noqa: F401
    except ImportError:
        print("Tianshou is not installed (pip install -e '.[bench]'); skipping it", file=sys.stderr)
        return []
    tasks: list[dict[str, Any]] = []
    for algo in [a.strip() for a in args.tianshou.split(",") if a.strip()]:
        if algo not in TIANSHOU_AGENTS:
            parser.error(f"--tianshou takes {', '.join(TIANSHOU_AGENTS)}; got {algo!r}")
        _, settings = resolve_config(algo, get_agent(algo).config_cls, "default")
        base = {"agent": f"tianshou-{algo}", "preset": TIANSHOU_PRESET, "env": args.env,
                "max_seconds": args.max_seconds_per_run, "eval_every": settings.eval_every,
                "screen": settings.eval_screen_episodes, "total_steps": args.tianshou_steps}  # fmt: skip
        tasks += [base | {"seed": s} for s in seeds]
    return tasks


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--agents", default=",".join(ALL_AGENTS),
                        help="comma-separated agent names; AGENT:PRESET runs that preset only")  # fmt: skip
    parser.add_argument("--presets", default="default",
                        help="comma-separated presets; each agent runs those it has (a .toml preset "
                             "file runs for every agent)")  # fmt: skip
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
    parser.add_argument("--tianshou", nargs="?", const="dqn,ppo", default=None, metavar="AGENTS",
                        help="also measure Tianshou with its CartPole test scripts' settings: "
                             "comma-separated dqn, ppo (--tianshou alone: both)")  # fmt: skip
    parser.add_argument("--tianshou-steps", type=int, default=None,
                        help="Tianshou's env-step budget, rounded up to whole epochs "
                             "(default: its scripts' epoch x step-per-epoch)")  # fmt: skip
    parser.add_argument("--jobs", type=int, default=1,
                        help="runs at once (one torch thread each); CPU s include contention")  # fmt: skip
    parser.add_argument("--json", default=None,
                        help="also write every run's measurements here (after each run)")  # fmt: skip
    parser.add_argument("--one", default=None, help=argparse.SUPPRESS)
    add_table_arguments(parser)
    args = parser.parse_args(argv)

    if args.one:  # child process: one measurement, printed as JSON
        task = json.loads(args.one)
        if task["agent"] == "sb3-dqn":
            result = run_sb3(task["seed"], task["max_seconds"], task["env"], task["eval_every"],
                             task["screen"], task["total_steps"] or 100_000)  # fmt: skip
        elif task["agent"].startswith("tianshou-"):
            algo = task["agent"].removeprefix("tianshou-")
            result = run_tianshou(algo, task["seed"], task["max_seconds"], task["env"], task["eval_every"],
                                  task["screen"], task["total_steps"])  # fmt: skip
        elif task["agent"].startswith("sb3-"):
            algo = task["agent"].removeprefix("sb3-")
            result = run_sb3_on_policy(algo, task["seed"], task["max_seconds"], task["env"],
                                       task["eval_every"], task["screen"], task["total_steps"])  # fmt: skip
        else:
            result = run_ours(task["agent"], task["preset"], task["seed"], task["max_seconds"], task["env"],
                              task.get("budget"))  # fmt: skip
        print(json.dumps(result))
        return 0

    from cartpole.agents.presets import env_preset, is_preset_file, preset_names
    from cartpole.agents.registry import get_agent
    from cartpole.training.config import resolve_config

    measurement = Measurement(args, [__file__, *(sys.argv[1:] if argv is None else argv)])
    tasks: list[dict[str, Any]] = []
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    for entry in [a.strip() for a in args.agents.split(",") if a.strip()]:
        agent, _, own_preset = entry.partition(":")  # AGENT:PRESET runs that preset alone
        get_agent(agent)
        for preset in (
            [own_preset] if own_preset else [p.strip() for p in args.presets.split(",") if p.strip()]
        ):
            if not is_preset_file(preset) and preset not in preset_names(agent):
                if own_preset:
                    parser.error(f"{agent} has no preset {preset!r} (cartpole presets lists them)")
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
                preset = env_preset(sb3_agent, args.env)  # our agent's cadence and rule on this env
                _, settings = resolve_config(sb3_agent, get_agent(sb3_agent).config_cls, preset)
                every = args.sb3_eval_every or settings.eval_every
                base = {"agent": f"sb3-{sb3_agent}", "preset": "rl-zoo", "env": args.env,
                        "max_seconds": args.max_seconds_per_run, "eval_every": every,
                        "screen": settings.eval_screen_episodes, "total_steps": args.sb3_steps}  # fmt: skip
                tasks += [base | {"seed": s} for s in seeds]
    if args.tianshou:
        tasks += tianshou_tasks(parser, args, seeds)

    print(f"# time_to_solve: {args.env}, {len(tasks)} runs, {describe_cpu()}, python "
          f"{platform.python_version()}", file=sys.stderr)  # fmt: skip
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
    table = table_of(groups, args.env, args.jobs)
    table.results = results
    print(table.markdown())
    measurement.finish(table)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
