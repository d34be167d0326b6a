"""evaluate(): Gymnasium's rule, exact agreement with a plain Gymnasium loop, honest verdicts."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from cartpole import EvalReport, evaluate
from cartpole.envs import UnsupportedEnvError, env_info


def reference_returns(policy, env_id: str, seeds: list[int]) -> list[float]:
    """One episode per seed with Gymnasium's single env in a plain Python loop."""
    env = gym.make(env_id)
    returns = []
    for seed in seeds:
        obs, _ = env.reset(seed=seed)
        total, done = 0.0, False
        while not done:
            action = int(policy.act(obs[None])[0])
            obs, reward, terminated, truncated, _ = env.step(action)
            total += float(reward)
            done = terminated or truncated
        returns.append(total)
    env.close()
    return returns


class Drifting:
    """A linear policy whose episodes end anywhere from 250 steps to the time limit: where a float32
    simulator's episodes drift apart from Gymnasium's float64 ones."""

    def act(self, observations: np.ndarray) -> np.ndarray:
        weights = np.array([-0.05, 0.0, 1.0, 0.15])
        return (np.asarray(observations, dtype=np.float64) @ weights > 0).astype(np.int64)


def test_an_evaluation_on_our_simulator_plays_gymnasiums_own_episodes_bit_for_bit():
    """So an in-training evaluation may run on it (the default presets' ``eval_simulator``): the same
    returns as Gymnasium's single env, on any CPU (both call the C library's sine and cosine)."""
    report = evaluate(Drifting(), "CartPole-v1", episodes=40, seed=7, simulator="fast")
    assert report.returns == reference_returns(Drifting(), "CartPole-v1", report.seeds)
    assert min(report.returns) < 300 and max(report.returns) == 500  # long episodes, not all alike


@pytest.mark.parametrize("env_id", ["CartPole-v1", "CartPole-v0"])
@pytest.mark.parametrize("simulator", ["gymnasium", "fast"])
def test_always_left_matches_a_plain_gymnasium_loop(always_left, env_id, simulator):
    report = evaluate(always_left, env_id, episodes=100, seed=1234, simulator=simulator)
    assert report.returns == reference_returns(always_left, env_id, report.seeds)
    assert report.seeds == list(range(1234, 1334))
    assert report.min >= 8 and report.max <= 12
    assert not report.solved
    assert report.verdict.startswith("NOT SOLVED")


@pytest.mark.parametrize(
    ("env_id", "limit", "threshold"), [("CartPole-v1", 500, 475), ("CartPole-v0", 200, 195)]
)
def test_balancer_is_solved_with_the_registry_threshold(balancer, env_id, limit, threshold):
    report = evaluate(balancer, env_id, episodes=100, seed=7)
    assert report.returns == [float(limit)] * 100
    assert report.lengths == [limit] * 100
    assert report.threshold == threshold == gym.spec(env_id).reward_threshold
    assert report.max_episode_steps == gym.spec(env_id).max_episode_steps
    assert report.solved
    assert report.verdict.startswith("SOLVED")
    assert (report.mean, report.std, report.min, report.max) == (limit, 0.0, limit, limit)


def test_fewer_than_100_episodes_cannot_be_called_solved(balancer):
    report = evaluate(balancer, "CartPole-v1", episodes=20, seed=0)
    assert report.mean == 500 and not report.solved
    assert report.verdict.startswith("CANNOT CALL SOLVED")


def test_episode_batches_beyond_the_batch_size(always_left, monkeypatch):
    import cartpole.evaluation as evaluation

    monkeypatch.setattr(evaluation, "MAX_ENVS_PER_BATCH", 7)
    report = evaluate(always_left, "CartPole-v1", episodes=30, seed=5)
    assert report.returns == reference_returns(always_left, "CartPole-v1", report.seeds)


def test_default_seed_is_fresh_and_above_training_seeds(always_left):
    from cartpole.core.seeding import EVAL_SEED_LOW

    first = evaluate(always_left, episodes=3)
    second = evaluate(always_left, episodes=3)
    assert min(first.seeds[0], second.seeds[0]) >= EVAL_SEED_LOW
    assert first.seeds != second.seeds


def test_report_round_trips_through_json(balancer):
    import json

    report = evaluate(balancer, episodes=100, seed=3)
    again = EvalReport.from_dict(json.loads(json.dumps(report.to_dict())))
    assert again == report
    assert report.to_dict()["verdict"] == report.verdict


def test_other_envs_are_evaluated_with_gymnasium():
    class Zero:
        def act(self, observations: np.ndarray) -> np.ndarray:
            return np.zeros(len(observations), dtype=np.int64)

    report = evaluate(Zero(), "Acrobot-v1", episodes=2, seed=0, simulator="fast")
    assert report.simulator == "gymnasium"
    assert report.lengths == [500, 500]


@pytest.mark.parametrize(
    ("env_id", "message"),
    [
        ("NoSuchEnv-v0", "unknown environment"),
        ("Pendulum-v1", "Discrete actions"),
        ("CarRacing-v3", "CarRacing-v3"),
    ],
)
def test_unsupported_envs_get_a_clear_error(env_id, message):
    with pytest.raises(UnsupportedEnvError, match=message):
        env_info(env_id)


def test_env_info_comes_from_the_registry():
    info = env_info("CartPole-v1")
    assert (info.obs_dim, info.n_actions, info.reward_threshold, info.max_episode_steps) == (4, 2, 475, 500)
    assert env_info("CartPole-v0").reward_threshold == 195


@pytest.mark.parametrize("simulator", ["gymnasium", "fast"])
def test_blocks_of_episodes_are_each_played_as_alone_and_ended_blocks_leave(always_left, balancer, simulator):
    """Four policies in blocks of 5 episodes: each block gets the returns its policy gets alone, and
    once the short-lived blocks (always left) have ended, the actor is asked only for the others."""
    from cartpole.evaluation import play_greedy_blocks, play_greedy_episodes

    policies = [always_left, balancer, always_left, balancer]
    seeds = list(range(50, 70))
    asked: list[list[int]] = []

    def act(observations: np.ndarray, blocks: np.ndarray) -> np.ndarray:
        asked.append(blocks.tolist())
        rows = np.split(observations, len(blocks))
        return np.concatenate([policies[b].act(mine) for b, mine in zip(blocks, rows, strict=True)])

    returns, lengths = play_greedy_blocks(act, "CartPole-v1", seeds, simulator, 5)
    for b, policy in enumerate(policies):
        alone, alone_lengths = play_greedy_episodes(
            policy.act, "CartPole-v1", seeds[5 * b : 5 * b + 5], simulator
        )
        np.testing.assert_array_equal(returns[5 * b : 5 * b + 5], alone)
        np.testing.assert_array_equal(lengths[5 * b : 5 * b + 5], alone_lengths)
    assert asked[0] == [0, 1, 2, 3] and asked[-1] == [1, 3]
    assert len(asked) == lengths.max()


def test_episodes_that_do_not_fill_their_blocks_are_refused(always_left):
    from cartpole.evaluation import play_greedy_blocks

    with pytest.raises(ValueError, match="blocks of 3"):
        play_greedy_blocks(lambda o, b: always_left.act(o), "CartPole-v1", list(range(10)), "fast", 3)


def test_envs_whose_episode_ended_stand_still_while_the_others_play(monkeypatch):
    """Gymnasium's envs of an evaluation (here MountainCar, one by one in a SyncVectorEnv) are
    stepped only while their episode counts: an ended one costs nothing more (a pixel verdict's
    steps cost a picture each). The returns are those of a plain loop over the single env."""
    from gymnasium.envs.classic_control.mountain_car import MountainCarEnv

    class PushWithTheSpeed:
        def act(self, observations: np.ndarray) -> np.ndarray:
            return np.where(observations[:, 1] >= 0, 2, 0)  # pumps energy: the flag in < 200 steps

    policy, seeds = PushWithTheSpeed(), [0, 1, 2]
    expected = reference_returns(policy, "MountainCar-v0", seeds)
    steps = 0
    original = MountainCarEnv.step

    def counted(self, action):
        nonlocal steps
        steps += 1
        return original(self, action)

    monkeypatch.setattr(MountainCarEnv, "step", counted)
    report = evaluate(policy, "MountainCar-v0", episodes=3, seed=0)
    assert report.returns == expected
    assert len(set(report.lengths)) > 1 and max(report.lengths) < 200
    assert steps == sum(report.lengths)


class PixelHash:
    """A deterministic policy of pixel frames, with episodes of varied lengths."""

    def act(self, observations: np.ndarray) -> np.ndarray:
        return (observations[:, -1].sum(axis=(1, 2), dtype=np.int64) // 7) % 2


def test_worker_processes_draw_gymnasiums_pictures_with_the_same_results(monkeypatch):
    """workers=3 has three processes draw Gymnasium's pictures of a pixel env (none is drawn here),
    and every episode comes out as it does in this process alone."""
    from gymnasium.envs.classic_control.cartpole import CartPoleEnv

    drawn_here = 0
    original = CartPoleEnv.render

    def render(self):
        nonlocal drawn_here
        drawn_here += 1
        return original(self)

    monkeypatch.setattr(CartPoleEnv, "render", render)
    env_id = "cartpole/CartPolePixels-v1"
    alone = evaluate(PixelHash(), env_id, episodes=7, seed=3, simulator="gymnasium")
    assert drawn_here == 7 + sum(alone.lengths) and len(set(alone.lengths)) > 1  # a reset and each step
    drawn_here = 0
    shared = evaluate(PixelHash(), env_id, episodes=7, seed=3, simulator="gymnasium", workers=3)
    assert drawn_here == 0
    assert shared.returns == alone.returns and shared.lengths == alone.lengths
    with pytest.raises(ValueError, match="workers must be >= 1"):
        evaluate(PixelHash(), env_id, episodes=7, seed=3, simulator="gymnasium", workers=0)


class ThreadCounting(PixelHash):
    """:class:`PixelHash` that notes torch's thread count at each call."""

    def __init__(self) -> None:
        self.threads: set[int] = set()

    def act(self, observations: np.ndarray) -> np.ndarray:
        import torch

        self.threads.add(torch.get_num_threads())
        return super().act(observations)


def test_the_policy_acts_on_one_torch_thread_while_worker_processes_draw():
    """The workers hold the cores: the policy's forward passes take one thread meanwhile, and the
    process gets its thread count back; with no workers it keeps its threads."""
    import torch

    env_id, threads = "cartpole/CartPolePixels-v1", torch.get_num_threads()
    try:
        torch.set_num_threads(2)
        sharded, alone = ThreadCounting(), ThreadCounting()
        report = evaluate(sharded, env_id, episodes=4, seed=3, simulator="gymnasium", workers=2)
        assert sharded.threads == {1} and torch.get_num_threads() == 2
        assert evaluate(alone, env_id, episodes=4, seed=3, simulator="gymnasium").returns == report.returns
        assert alone.threads == {2}
    finally:
        torch.set_num_threads(threads)


def test_an_evaluation_interrupted_while_its_workers_draw_leaves_no_worker_and_no_traceback(
    monkeypatch, capfd
):
    """Ctrl-C while the workers send their pictures (larger than a pipe holds): the evaluation
    stops, the workers end, and none of them prints a traceback."""
    import multiprocessing
    from multiprocessing.connection import Connection

    original = Connection.recv
    answers = 0

    def interrupted(self: Connection) -> object:
        nonlocal answers
        answers += 1
        if answers == 3:  # the two workers' resets came; the first step's pictures are on their way
            raise KeyboardInterrupt
        return original(self)

    monkeypatch.setattr(Connection, "recv", interrupted)
    with pytest.raises(KeyboardInterrupt):
        evaluate(
            PixelHash(), "cartpole/CartPolePixels-v1", episodes=64, seed=0, simulator="gymnasium", workers=2
        )
    assert multiprocessing.active_children() == []
    assert "Traceback" not in capfd.readouterr().err
