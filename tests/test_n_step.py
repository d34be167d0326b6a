"""n-step returns for DQN (``agents/dqn/n_step.py``): which rows a run of transitions becomes."""

from __future__ import annotations

import numpy as np
import pytest

from cartpole.agents.dqn.n_step import NStepWindows

GAMMA = 0.5


def play(windows: NStepWindows, steps: list[dict[str, list]]) -> list[tuple[int, float, float, float, float]]:
    """Feed ``steps`` (per env: reward, terminated, truncated, valid) to ``windows``; every stored row
    as (env, obs, n-step return, bootstrap obs, terminated), in the order the replay gets them. An
    env's observation at step t is 10 * t + env (its next one 10 * (t + 1) + env)."""
    envs = len(windows.count)
    rows = []
    for t, step in enumerate(steps):
        observations = np.array([[10.0 * t + e] for e in range(envs)], dtype=np.float32)
        for emitted, (obs, _, returns, next_obs, terminated) in windows.step(
            np.array(step.get("valid", [True] * envs)),
            observations,
            np.zeros(envs, dtype=np.int64),
            np.array(step["reward"], dtype=np.float32),
            observations + 10.0,
            np.array(step.get("terminated", [False] * envs)),
            np.array(step.get("truncated", [False] * envs)),
        ):
            for e in np.flatnonzero(emitted):
                rows.append(
                    (int(e), float(obs[e, 0]), float(returns[e]), float(next_obs[e, 0]), float(terminated[e]))
                )
    return rows


def test_a_full_window_stores_its_oldest_transition_with_n_discounted_rewards():
    windows = NStepWindows(1, 1, 3, GAMMA, (1,), np.float32)
    rows = play(windows, [{"reward": [r]} for r in (1.0, 2.0, 4.0, 8.0)])
    # s0: 1 + 0.5 * 2 + 0.25 * 4, bootstrapping from s3; s1: 2 + 0.5 * 4 + 0.25 * 8, from s4
    assert rows == [(0, 0.0, 3.0, 30.0, 0.0), (0, 10.0, 6.0, 40.0, 0.0)]


def test_a_terminated_episode_stores_its_last_transitions_without_bootstrap():
    windows = NStepWindows(1, 1, 3, GAMMA, (1,), np.float32)
    steps = [{"reward": [1.0]}, {"reward": [2.0]}, {"reward": [4.0]}, {"reward": [8.0], "terminated": [True]}]
    assert play(windows, steps) == [
        (0, 0.0, 3.0, 30.0, 0.0),
        (0, 10.0, 6.0, 40.0, 1.0),  # s1 .. s3, the episode's end: no bootstrap
        (0, 20.0, 8.0, 40.0, 1.0),  # s2: 4 + 0.5 * 8
        (0, 30.0, 8.0, 40.0, 1.0),  # s3: 8
    ]
    assert windows.count[0] == 0


def test_a_truncated_episode_drops_the_windows_shorter_than_n():
    windows = NStepWindows(1, 1, 3, GAMMA, (1,), np.float32)
    steps = [{"reward": [1.0]}, {"reward": [2.0]}, {"reward": [4.0]}, {"reward": [8.0], "truncated": [True]}]
    rows = play(windows, steps)
    assert rows == [(0, 0.0, 3.0, 30.0, 0.0), (0, 10.0, 6.0, 40.0, 0.0)]  # s2, s3 would bootstrap early
    assert windows.count[0] == 0


def test_envs_keep_their_own_windows_and_skip_autoreset_steps():
    windows = NStepWindows(2, 2, 2, GAMMA, (1,), np.float32)
    steps = [
        {"reward": [1.0, 1.0], "terminated": [True, False]},
        {"reward": [0.0, 2.0], "valid": [False, True]},  # env 0's autoreset step: no transition
        {"reward": [4.0, 4.0]},
        {"reward": [8.0, 8.0]},
    ]
    assert play(windows, steps) == [
        (0, 0.0, 1.0, 10.0, 1.0),  # env 0's one-step episode
        (1, 1.0, 2.0, 21.0, 0.0),  # env 1: 1 + 0.5 * 2
        (1, 11.0, 4.0, 31.0, 0.0),  # env 1: 2 + 0.5 * 4
        (0, 20.0, 8.0, 40.0, 0.0),  # env 0 from its new episode: 4 + 0.5 * 8
        (1, 21.0, 8.0, 41.0, 0.0),
    ]


@pytest.mark.parametrize("n", [1, 2, 5])
def test_every_transition_of_a_terminated_episode_is_stored_once(n):
    windows = NStepWindows(1, 1, n, 1.0, (1,), np.float32)
    steps = [{"reward": [1.0]} for _ in range(6)] + [{"reward": [1.0], "terminated": [True]}]
    rows = play(windows, steps)
    assert [obs for _, obs, _, _, _ in rows] == [10.0 * t for t in range(7)]
    # gamma 1: each return counts the steps to the end, at most n
    assert [ret for _, _, ret, _, _ in rows] == [float(min(n, 7 - t)) for t in range(7)]
