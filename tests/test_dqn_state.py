"""DQN's state is its own: nothing global changes, and a checkpoint resumes exactly on every env."""

from __future__ import annotations

import dataclasses
import json
import random
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from one_seed import one_seed

from cartpole.agents.dqn.algorithm import DQNConfig
from cartpole.agents.registry import get_agent
from cartpole.envs import env_info
from cartpole.runs import Checkpoint, load_checkpoint, save_checkpoint

DQN = get_agent("dqn")


def small_config(**changes: Any) -> DQNConfig:
    base = DQNConfig(hidden_sizes=(16, 16), num_envs=3, learning_starts=20, batch_size=8, buffer_size=500)
    return dataclasses.replace(base, **changes)


def global_state() -> tuple[int, torch.Tensor, Any, Any]:
    """Torch's thread count and the process-wide generators of torch, numpy and Python."""
    return torch.get_num_threads(), torch.get_rng_state(), np.random.get_state(), random.getstate()


def assert_same_global_state(before: tuple[int, torch.Tensor, Any, Any]) -> None:
    threads, torch_rng, numpy_rng, python_rng = global_state()
    assert threads == before[0]
    assert torch.equal(torch_rng, before[1])
    assert numpy_rng[0] == before[2][0] and np.array_equal(numpy_rng[1], before[2][1])
    assert numpy_rng[2:] == before[2][2:]
    assert python_rng == before[3]


@pytest.mark.parametrize("env_id", ["CartPole-v1", "Acrobot-v1"])
def test_building_training_and_loading_a_dqn_changes_nothing_global(env_id: str) -> None:
    torch.set_num_threads(max(2, torch.get_num_threads()))  # a thread count the old constructor overrode
    torch.manual_seed(1234), np.random.seed(1234), random.seed(1234)
    before = global_state()
    config = small_config(dropout=0.3, learning_starts=0)  # all streams: init, dropout, replay, explore
    learner = one_seed(DQN, config, env_info(env_id), 7, "cpu")
    for _ in range(30):
        learner.learn()
    tensors, data = learner.state_dict(resume=True)
    other = one_seed(DQN, config, env_info(env_id), 8, "cpu")
    other.load_state_dict(tensors, data)
    other.learn()
    other.policy().act(np.zeros((2, env_info(env_id).obs_dim), dtype=np.float32))
    assert_same_global_state(before)


def test_the_global_generators_do_not_change_what_a_dqn_learns() -> None:
    def run(global_seed: int) -> dict[str, torch.Tensor]:
        torch.manual_seed(global_seed), np.random.seed(global_seed), random.seed(global_seed)
        learner = one_seed(DQN, small_config(dropout=0.3), env_info("CartPole-v1"), 3, "cpu")
        for _ in range(40):
            learner.learn()
        return learner.state_dict(resume=False)[0]

    first, second = run(1), run(2)
    assert first.keys() == second.keys()
    assert all(torch.equal(first[k], second[k]) for k in first)


def test_a_resume_checkpoint_holds_plain_data_and_tensors_only() -> None:
    """No pickled objects: the env state is JSON-able public per-env state, not vector env internals."""

    for env_id in ("CartPole-v1", "Acrobot-v1", "MountainCar-v0"):
        for simulator in ("fast", "gymnasium"):
            learner = one_seed(DQN, small_config(simulator=simulator), env_info(env_id), 0, "cpu")
            for _ in range(5):
                learner.learn()
            tensors, data = learner.state_dict(resume=True)
            assert all(isinstance(t, torch.Tensor) for t in tensors.values())
            assert data["collector"]["env_state"] is not None, (env_id, simulator)
            assert json.loads(json.dumps(data)) == data


# ----------------------------------------------------------------------------------------------
# Resume is gap-free on every env: the episodes in progress at the checkpoint go on
# ----------------------------------------------------------------------------------------------


def episodes_of(learner: Any, calls: int) -> tuple[list[tuple[float, int]], int]:
    """The (return, length) of each episode finished in ``calls`` learn() calls, and the env steps."""
    episodes: list[tuple[float, int]] = []
    steps = 0
    for _ in range(calls):
        result = learner.learn()
        episodes += zip(result.episode_returns, result.episode_lengths, strict=True)
        steps += result.env_steps
    return episodes, steps


@pytest.mark.parametrize(
    ("env_id", "simulator", "calls", "stop_at", "learning_starts"),
    [
        # Acrobot's episodes last 500 steps untrained: the stop (call 250, 500 env steps) falls mid-way
        ("Acrobot-v1", "gymnasium", 560, 250, 900),
        ("CartPole-v1", "fast", 200, 75, 50),
        ("CartPole-v1", "gymnasium", 200, 75, 50),
    ],
)
def test_resume_mid_episode_continues_the_episodes_in_progress(
    tmp_path: Path, env_id: str, simulator: str, calls: int, stop_at: int, learning_starts: int
) -> None:
    """A learner stopped mid-episode, saved to a checkpoint file and resumed in a new learner finishes
    the very episodes of one never stopped: the same returns and lengths in the same order (so episode
    indices stay contiguous), no step lost and none counted twice."""
    config = small_config(num_envs=2, learning_starts=learning_starts, simulator=simulator)
    env = env_info(env_id)
    whole, whole_steps = episodes_of(one_seed(DQN, config, env, 2, "cpu"), calls)

    first = one_seed(DQN, config, env, 2, "cpu")
    before, before_steps = episodes_of(first, stop_at)
    tensors, data = first.state_dict(resume=True)
    lengths = data["collector"]["episode_lengths"]
    assert any(length > 0 for length in lengths), "the stop must fall mid-episode"
    path = tmp_path / "latest.pt"
    save_checkpoint(path, Checkpoint(tensors=tensors, meta={"learner": data}))
    saved = load_checkpoint(path)
    resumed = one_seed(DQN, config, env, 2, "cpu")
    resumed.load_state_dict(saved.tensors, saved.meta["learner"])
    after, after_steps = episodes_of(resumed, calls - stop_at)

    assert len(whole) > len(before) >= 1 or env_id == "Acrobot-v1"
    assert any(length > stop_at for _, length in after) or env_id == "CartPole-v1"
    assert before + after == whole
    assert before_steps + after_steps == whole_steps


def test_a_checkpoint_of_the_earlier_layout_resumes_the_same_episodes() -> None:
    """A DQN checkpoint of the earlier layout kept its envs' state at the top level of its metadata
    and its observations as ``envs.observations``; such a checkpoint resumes as one of today's does."""
    config, env = small_config(num_envs=2, learning_starts=50), env_info("CartPole-v1")
    first = one_seed(DQN, config, env, 2, "cpu")
    episodes_of(first, 75)
    tensors, data = first.state_dict(resume=True)
    earlier = {k: v for k, v in data.items() if k != "collector"} | data["collector"]
    earlier_tensors = {k: v for k, v in tensors.items() if k != "collector.observations"}
    earlier_tensors["envs.observations"] = tensors["collector.observations"]
    resumed = {}
    for name, (t, d) in {"today": (tensors, data), "earlier": (earlier_tensors, earlier)}.items():
        resumed[name] = one_seed(DQN, config, env, 2, "cpu")
        resumed[name].load_state_dict(t, d)
    assert episodes_of(resumed["earlier"], 125) == episodes_of(resumed["today"], 125)


def test_the_cli_decides_the_thread_count_and_the_global_seeds_once() -> None:
    from cartpole.cli.train import configure_process

    threads = torch.get_num_threads()
    try:
        configure_process(torch_threads=3, seed=5)
        assert torch.get_num_threads() == 3
        first = (torch.rand(2), np.random.random(), random.random())
        configure_process(torch_threads=0, seed=5)  # 0: leave the thread count as it is
        assert torch.get_num_threads() == 3
        again = (torch.rand(2), np.random.random(), random.random())
        assert torch.equal(first[0], again[0]) and first[1:] == again[1:]
    finally:
        torch.set_num_threads(threads)
